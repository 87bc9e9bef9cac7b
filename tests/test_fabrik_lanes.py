"""FABRIK with joint limits as SIMD lanes (kernels/fabrik_limited_lanes.py) against the one-character kernel.

Same statuses, the same iteration count for >= 99 % of characters, poses within 1e-4 m for >= 99 % (float32
rounding in a different order grows where a limb is nearly straight: its swivel is ill-conditioned there,
and the one-character kernel is as far from the float64 twin), batch == one at a time, and the dispatch
only where the lanes reproduce the request.
"""

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.crowd import Status
from crowd_ik.solvers import fabrik as adapter
from crowd_ik.solvers import settings


@pytest.fixture(autouse=True)
def limited_lanes_on(monkeypatch):
    """The lane kernel is off by default (settings.limited_lanes); these tests switch it on."""
    monkeypatch.setenv("CROWD_IK_LIMITED_LANES", "1")
    if settings.lanes() == 1:  # CUDA: one character per thread, so there is no lane kernel to compare
        pytest.skip("lane width 1 (CUDA)")
    assert settings.limited_lanes() > 1


def _solve_both(monkeypatch, crowd_factory, frames, orientations=None):
    """Run the frames (targets, max_iterations, tolerance[, poles]) on two crowds: the lane kernel and the general
    one, with the orientation targets (or none) in every frame."""
    orig = adapter.lane_active
    out = []
    for lanes in (True, False):
        monkeypatch.setattr(adapter, "lane_active", orig if lanes else (lambda crowd, req: None))
        crowd = crowd_factory()
        got = []
        for targets, iterations, tolerance, *poles in frames:
            rep = crowd.solve(targets, method="fabrik", max_iterations=iterations, tolerance=tolerance,
                              poles=poles[0] if poles else None, orientations=orientations)
            got.append((rep, crowd.joint_positions(), crowd.rotations()))
        out.append(got)
    monkeypatch.setattr(adapter, "lane_active", orig)
    return out


def _check_same(a_frames, b_frames, pose_atol=1e-4, pose_max=5e-3, plateau_swaps=0.0, same_iterations=0.99,
                close_share=0.99):
    """plateau_swaps: the share of characters allowed STALLED in one and MAX_ITERATIONS in the other (a character
    pinned on its limits improves by about the stall threshold, one part in a million, per iteration)."""
    for (a, pa, qa), (b, pb, qb) in zip(a_frames, b_frames):
        differ = a.status != b.status
        plateau = np.isin(a.status, (Status.STALLED, Status.MAX_ITERATIONS)) & np.isin(
            b.status, (Status.STALLED, Status.MAX_ITERATIONS))
        assert np.all(plateau[differ]) and np.mean(differ) <= plateau_swaps, (a.status[differ], b.status[differ])
        assert np.mean(a.iterations == b.iterations) >= same_iterations
        converged = (a.status == Status.CONVERGED) & (b.status == Status.CONVERGED)
        assert not converged.any() or np.mean((a.iterations == b.iterations)[converged]) >= 0.99
        d = np.abs(pa - pb).max(axis=(1, 2))
        assert np.mean(d <= pose_atol) >= close_share and d.max() <= pose_max, (np.quantile(d, 0.99), d.max())
        np.testing.assert_allclose(a.error, b.error, atol=pose_max)


@pytest.mark.parametrize("poles,flat_feet", [(False, False), (True, False), (True, True)],
                         ids=["plain", "arm_poles", "arm_poles_flat_feet"])
def test_limited_humanoid_game_frames_equal_the_per_character_kernel(monkeypatch, poles, flat_feet):
    """The bench's game cell in small: a cold solve, then warm 4-iteration frames with hands and head moving; with
    the game's elbow poles (game/arm_poles.py) as the game passes them; with the game's orientation targets (the
    soles kept flat: game/body.py's orient on the ankles, universal joints) as well."""
    from crowd_ik.bench import workloads as w
    from crowd_ik.game.arm_poles import ArmPoles
    from crowd_ik.game.body import Body

    n = 203  # not a multiple of any lane width
    wl = w.game_workload(n)
    assert not wl.rig.constraint_free
    feet = np.array([name.startswith("foot") for name in wl.rig.effector_names])
    offsets = w._smooth_offsets(n, wl.rig.n_effectors, w.SEED + 2)
    extra = ()
    if poles:
        crowd = cik.Crowd(wl.rig, n, spacing=w.SPACING)
        extra = (ArmPoles(Body(wl.rig), n).update(crowd.roots()[0], crowd.roots()[1]).copy(),)
    frames = [(wl.targets, 100, wl.tolerance, *extra)] + [
        (wl.targets + np.where(feet[None, :, None], 0.0, offsets((f + 1) / 60.0)), 4, wl.tolerance, *extra)
        for f in range(3)]
    orient = None
    if flat_feet:
        orient = np.ascontiguousarray(np.broadcast_to(Body(wl.rig).orient, (n, wl.rig.n_effectors, 3)))
        assert np.count_nonzero(orient.any(axis=2)[0]) == 2
    a, b = _solve_both(monkeypatch, lambda: cik.Crowd(wl.rig, n, spacing=w.SPACING), frames, orient)
    _check_same(a, b)
    if flat_feet:  # a converged character's soles are flat: 1 - cos(ankle axis, up) within the 1e-6 it stops at
        from crowd_ik.geometry.fk import forward_kinematics
        from crowd_ik.geometry.quat import qrot

        rep, _, rot = a[-1]
        on = orient.any(axis=2)[0]
        roots, yaw = cik.Crowd(wl.rig, n, spacing=w.SPACING).roots()
        _, wrot = forward_kinematics(wl.rig, roots.astype(np.float64), yaw, rot.astype(np.float64))
        axis = qrot(wrot[:, wl.rig.arrays["eff_joint"][on]],
                    np.broadcast_to(wl.rig.arrays["eff_axis"][on].astype(np.float64), (n, 2, 3)))
        turn = (1.0 - np.sum(axis * orient[:, on], axis=-1)).max(axis=1)
        done = rep.status == Status.CONVERGED
        assert done.sum() > n // 4 and turn[done].max() < 2e-6
    rep = a[0][0]
    assert np.mean(rep.status == Status.CONVERGED) > 0.95
    assert np.any(a[-1][0].iterations == 4) and np.any(a[-1][0].iterations < 4)


@pytest.mark.parametrize("limits", ["box", "cone", "cone_and_box"])
def test_limited_chain_equals_the_per_character_kernel(monkeypatch, limits):
    """Ball joints with box limits, a cone, or both (the bisection of quat.cone_within_box), targets in and out of
    reach, some characters starting on their target."""
    lo, hi, cone = {"box": (-0.6, 0.6, None), "cone": (None, None, 0.7), "cone_and_box": (-0.8, 0.8, 0.6)}[limits]
    rig = cik.Rig.chain(6, 0.2, dim=3, lo=lo, hi=hi, cone=cone)
    assert not rig.constraint_free
    n = 150
    rng = np.random.default_rng(3)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    targets = (d * rng.uniform(0.2, 1.3, (n, 1))).astype(np.float32)[:, None, :]
    targets[0, 0] = (1.2, 0.0, 0.0)  # the tip where it stands: no iterations

    def factory():
        crowd = cik.Crowd(rig, n)
        crowd.set_angles(np.tile(np.r_[0.1, 0.05, 0.0] * np.ones((6, 1)), 1).ravel())
        return crowd

    frames = [(targets, 30, 1e-3), (targets * 0.9, 3, 1e-3)]
    a, b = _solve_both(monkeypatch, factory, frames)
    # 150 characters, many pinned on limits (cone and box: 2 of 150 at 1.6e-4 m)
    _check_same(a, b, plateau_swaps=0.01, same_iterations=0.97, close_share=0.97)
    assert a[0][0].iterations[0] == 0 or np.any(a[0][0].status == Status.UNREACHABLE)


def test_limited_lanes_batch_equals_one_at_a_time():
    """A character alone in a padded packet gets what it gets among lane-mates, to 1e-5 m (on the AVX-512 machine
    bit for bit since the hinge and limb trigonometry is lane_trig's element-wise code; with libm's calls up to
    2.3e-6 m, 21 game characters at 4, 30 and 100 iterations)."""
    from crowd_ik.bench import workloads as w

    n = 21
    wl = w.game_workload(n)
    crowd = cik.Crowd(wl.rig, n, spacing=w.SPACING)
    batch = crowd.solve(wl.targets, method="fabrik", max_iterations=30, tolerance=wl.tolerance)
    pos = crowd.joint_positions()
    roots, yaw = crowd.roots()
    for i in range(0, n, 4):
        one = cik.Crowd(wl.rig, n=1)
        one.set_roots(roots[i:i + 1], yaw[i:i + 1])
        rep = one.solve(wl.targets[i:i + 1], method="fabrik", max_iterations=30, tolerance=wl.tolerance)
        assert rep.iterations[0] == batch.iterations[i] and rep.status[0] == batch.status[i]
        np.testing.assert_allclose(one.joint_positions()[0], pos[i], atol=1e-5)


def test_limited_lanes_a_character_does_not_depend_on_its_lane_mates():
    """The crowd solved in another order (so each character shares its packet with other characters, in another
    lane) gives every character the same warm 4-iteration solve bit for bit. Until stop 47 the chest's pass-up
    recomputed the joint's position in every lane of a packet where some lane's clamp moved it, and fast math
    may round that second computation differently: here 151 of the 37,800 joint coordinates differed, by up
    to 1.1e-6 m."""
    from crowd_ik.bench import workloads as w

    n = 600
    wl = w.game_workload(n)
    feet = np.array([name.startswith("foot") for name in wl.rig.effector_names])
    offsets = w._smooth_offsets(n, wl.rig.n_effectors, 7)
    frames = [(wl.targets + np.where(feet[None, :, None], 0.0, offsets(t))).astype(np.float32) for t in (0.3, 0.5, 0.7)]
    out = []
    for order in (np.arange(n), np.roll(np.arange(n), 1), np.roll(np.arange(n), settings.limited_lanes())):
        crowd = cik.Crowd(wl.rig, n, spacing=w.SPACING)
        roots, yaw = crowd.roots()
        crowd.set_roots(roots[order], yaw[order])
        crowd.solve(wl.targets[order], method="fabrik", max_iterations=100, tolerance=wl.tolerance)
        back = np.argsort(order)
        got = []
        for targets in frames:
            rep = crowd.solve(targets[order], method="fabrik", max_iterations=4, tolerance=wl.tolerance)
            got.append((rep.iterations[back], crowd.joint_positions()[back]))
        out.append(got)
    for got in out[1:]:
        for (iterations, pos), (iterations0, pos0) in zip(got, out[0]):
            np.testing.assert_array_equal(iterations, iterations0)
            np.testing.assert_array_equal(pos, pos0)


@pytest.mark.xfail(strict=False, reason="CPU-dependent: bit for bit on the AMD EPYC of sessions 24-25; on an EPYC "
                   "with AVX-512 IFMA/VBMI some lanes round differently (1 ulp, growing to 1.7 mm for one of the "
                   "three characters in 8 iterations) - one reason the limited lanes stay off by default")
def test_limited_lanes_identical_characters_get_identical_poses_in_every_lane():
    """The same character in every lane of two packets (20 m from the origin, turned, 8 iterations: longer solves
    run in windows on the one-character kernel): every lane
    gives lane 0's pose bit for bit, as the one-character kernel does. (Before the chest's pass-up, f840326, LLVM
    compiled some lanes' float32 rounding differently under fast math and this failed; a strict xfail recorded it.)"""
    from crowd_ik.bench import workloads as w

    n = 2 * settings.limited_lanes()
    wl = w.game_workload(40)
    for k, yaw in ((7, 1.3), (2, -0.4), (5, 2.9)):  # k < n: r is this crowd's grid
        crowd = cik.Crowd(wl.rig, n, spacing=w.SPACING)
        r, _ = crowd.roots()
        root = r[k] + np.float32(20.0)
        crowd.set_roots(np.tile(root, (n, 1)), np.full(n, yaw, np.float32))
        targets = np.tile(wl.targets[k:k + 1] - r[k] + root, (n, 1, 1))
        crowd.solve(targets, method="fabrik", max_iterations=8, tolerance=wl.tolerance)
        p = crowd.joint_positions()
        np.testing.assert_array_equal(p, np.broadcast_to(p[:1], p.shape), err_msg=f"character {k}, yaw {yaw}")


def test_limited_lanes_dispatch_only_where_they_reproduce_the_request():
    """Lanes for position targets with one weight pattern for every character that weights any, with or without
    poles or orientation targets; the general kernel for rotation targets or weights that switch an effector off
    for some characters only."""
    h = cik.Rig.humanoid()
    crowd = cik.Crowd(h, 8)
    targets = crowd.joint_positions()[:, h.arrays["eff_joint"]] + 0.01
    seen = []
    orig = adapter.lane_active

    def spy(c, req):
        seen.append(orig(c, req))
        return seen[-1]

    lane_solves = []
    orig_limited = adapter.solve_limited
    adapter.lane_active = spy
    adapter.solve_limited = lambda *a: (lane_solves.append(1), orig_limited(*a))
    try:
        crowd.solve(targets, method="fabrik", max_iterations=2)
        w = np.ones((8, h.n_effectors), np.float32)
        w[:, 0] = 0.0  # the head off for everyone: still lanes, the head's chain inactive
        crowd.solve(targets, method="fabrik", max_iterations=2, weights=w)
        w[5] = 0.0  # one character weights nothing (a restart window's finished character): still lanes
        crowd.solve(targets, method="fabrik", max_iterations=2, weights=w)
        poles = np.full((8, h.n_effectors, 3), np.nan, np.float32)
        poles[:, 1] = crowd.joint_positions()[:, h.arrays["eff_joint"][1]] + (0.3, -0.3, 0.0)
        crowd.solve(targets, method="fabrik", max_iterations=2, poles=poles)  # poles: still lanes
        w[3, 1] = 0.0  # one character's hand off as well: a different pattern, the general kernel
        crowd.solve(targets, method="fabrik", max_iterations=2, weights=w)
        orient = np.full((8, h.n_effectors, 3), np.nan, np.float32)
        orient[:, 3] = (0.0, 1.0, 0.0)
        crowd.solve(targets, method="fabrik", max_iterations=2, orientations=orient)  # orientations: still lanes
        turned = crowd.world_rotations()[:, h.arrays["eff_joint"][3]].copy()
        rots = np.full((8, h.n_effectors, 4), np.nan, np.float32)
        rots[:, 3] = (0.0, 0.0, 0.0, 1.0)
        before = len(lane_solves)
        crowd.solve(targets, method="fabrik", max_iterations=2, rotations=rots)  # rotation targets: general
        assert len(lane_solves) == before
    finally:
        adapter.lane_active = orig
        adapter.solve_limited = orig_limited
    assert seen[0] is not None and seen[0].sum() == h.n_joints - 2  # all but the toes, below the ankle effectors
    assert seen[1] is not None and seen[1][h.arrays["eff_joint"][0]] == 0 and seen[1][0] == 1
    assert seen[2] is not None and np.array_equal(seen[2], seen[1]) and seen[3] is not None
    assert seen[4] is None and seen[5] is not None and len(lane_solves) == 5
    from crowd_ik.geometry.quat import qrot

    up = qrot(turned.astype(np.float64), np.broadcast_to(h.arrays["eff_axis"][3].astype(np.float64), (8, 3)))
    assert np.all(up[:, 1] > 0.9), up  # the orientation targets were applied
