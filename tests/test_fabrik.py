"""Batched FABRIK: convergence, exact bone lengths, limits, sub-bases, unreachable targets, batch == single, twin."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st, HealthCheck

import crowd_ik as cik
from crowd_ik.crowd import Status
from crowd_ik.reference.fabrik import fabrik_solve
from rig_cases import free_tree


def ball_targets(n, radius, dim, seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, dim))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (d * radius * rng.uniform(0, 1, (n, 1)) ** (1 / dim)).astype(np.float32)


def bone_lengths(crowd):
    rig = crowd.rig
    pos = crowd.joint_positions()
    parents = np.array([j.parent for j in rig.joints[1:]])
    return np.linalg.norm(pos[:, 1:] - pos[:, parents], axis=-1), rig.bone_lengths[1:]


@pytest.mark.parametrize("dim", [3, 2])
def test_chain16_reaches_99_percent_of_reachable_targets(dim):
    rig = cik.Rig.chain(16, 0.1, dim=dim)
    n = 1000
    crowd = cik.Crowd(rig, n=n, spacing=0.0)
    targets = ball_targets(n, 0.9 * 1.6, dim, seed=dim)
    rep = crowd.solve(targets[:, None], method="fabrik", max_iterations=50, tolerance=1e-3)
    assert np.mean(rep.error <= 1e-3) >= 0.99
    assert np.all(rep.status[rep.error <= 1e-3] == Status.CONVERGED)
    assert np.all(rep.iterations <= 50) and rep.iterations.dtype == np.int32 and rep.status.dtype == np.int8
    got, want = bone_lengths(crowd)
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), atol=2e-6)
    # the report's error is the distance of the final pose's effector
    np.testing.assert_allclose(rep.error, np.linalg.norm(crowd.effector_positions()[:, 0] - targets, axis=1), atol=1e-6)


def test_unreachable_targets_end_stretched_toward_the_target():
    rig = cik.Rig.chain(8, 0.25, dim=3)
    crowd = cik.Crowd(rig, n=50, spacing=0.0)
    rng = np.random.default_rng(5)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    targets = d * rng.uniform(2.1, 10.0, (50, 1))
    rep = crowd.solve(targets[:, None].astype(np.float32), max_iterations=30, tolerance=1e-3)
    assert np.all(rep.status == Status.UNREACHABLE)
    pos = crowd.joint_positions()
    bones = np.diff(pos, axis=1)
    dirs = bones / np.linalg.norm(bones, axis=-1, keepdims=True)
    assert np.min(np.sum(dirs * d[:, None], axis=-1)) > math.cos(2e-3)  # 2 mrad: float32 directions
    np.testing.assert_allclose(rep.error, np.linalg.norm(targets, axis=1) - 2.0, atol=1e-5)
    assert np.median(rep.iterations) < 15  # stretched early, then stopped by the stall counter


def test_target_already_reached_needs_no_update():
    crowd = cik.Crowd(cik.Rig.chain(4, 0.5, dim=3), n=3)
    rep = crowd.solve(crowd.effector_positions(), tolerance=1e-4)
    assert np.all(rep.iterations == 0) and np.all(rep.status == Status.CONVERGED)


def _reachable_humanoid_targets(rig, n, seed, scale=0.5):
    rng = np.random.default_rng(seed)
    lo, hi = rig.angle_limits()
    a = (rng.uniform(lo, hi, (n, rig.n_dof)) * scale).astype(np.float32)
    c = cik.Crowd(rig, n=n, spacing=2.0)
    c.set_angles(a)
    return c.effector_positions().copy()


def test_humanoid_sub_bases_reach_every_effector_without_limits():
    h = cik.Rig.humanoid()
    free = cik.Rig(tuple(dataclasses.replace(j, lo=None, hi=None) for j in h.joints), h.effectors)
    targets = _reachable_humanoid_targets(h, 200, 1)
    crowd = cik.Crowd(free, n=200, spacing=2.0)
    rep = crowd.solve(targets, max_iterations=100, tolerance=5e-3)
    assert np.mean(rep.converged) >= 0.97


def test_humanoid_limits_always_hold_and_most_targets_are_reached():
    h = cik.Rig.humanoid()
    targets = _reachable_humanoid_targets(h, 300, 2)
    crowd = cik.Crowd(h, n=300, spacing=2.0)
    lo, hi = h.angle_limits()
    for iterations in (1, 5, 100):
        crowd.set_angles(np.zeros(h.n_dof))
        rep = crowd.solve(targets, max_iterations=iterations, tolerance=5e-3)
        a = crowd.angles()
        assert np.all(a >= lo - 1e-5) and np.all(a <= hi + 1e-5)
    assert np.mean(rep.converged) >= 0.95  # 1.00 with the two-bone limbs, hands included (0.69 without)
    # one effector at a time is easy for a limited humanoid too
    crowd.set_angles(np.zeros(h.n_dof))
    rep = crowd.solve(targets, weights=[0, 1, 0, 0, 0], max_iterations=100, tolerance=5e-3)
    assert np.mean(rep.converged) >= 0.9


def test_legs_are_solved_as_two_bone_limbs():
    """Feet on in-limit poses, from rest: hip-knee-ankle is solved in closed form, so nearly all land in a few
    iterations (without the two-bone step FABRIK reached 45 % in 10 iterations and 72 % in 100)."""
    h = cik.Rig.humanoid()
    targets = _reachable_humanoid_targets(h, 300, 3)
    crowd = cik.Crowd(h, n=300, spacing=2.0)
    rep = crowd.solve(targets, weights=[0, 0, 0, 1, 1], max_iterations=10, tolerance=2e-3)
    assert np.mean(rep.converged) >= 0.95
    lo, hi = h.angle_limits()
    a = crowd.angles()
    assert np.all(a >= lo - 1e-5) and np.all(a <= hi + 1e-5)  # knees included: they never bend backward


def test_warm_started_frames_move_limbs_smoothly():
    """The benchmark's game frames (head and hands drift a few cm, feet planted, 4 iterations per frame): no limb
    flips. Before the two-bone step a leg or arm could swing 0.8 m in one frame; now no joint moves 0.5 m, and a
    character moves a joint more than 10 cm in under 1 % of its frames (an arm stretching as its target leaves
    reach)."""
    from crowd_ik.bench import options, workloads
    n = 400
    wl = workloads.game_workload(n)
    crowd = cik.Crowd(wl.rig, n=n, spacing=options.SPACING)
    crowd.solve(wl.targets, max_iterations=100, tolerance=wl.tolerance)
    drift = workloads._smooth_offsets(n, wl.rig.n_effectors, 7)
    feet = np.array([name.startswith("foot") for name in wl.rig.effector_names])
    before = crowd.joint_positions()
    jumps = 0
    for f in range(30):
        targets = wl.targets + np.where(feet[None, :, None], 0.0, drift((f + 1) / 60.0))
        crowd.solve(targets, max_iterations=4, tolerance=wl.tolerance)
        now = crowd.joint_positions()
        step = np.linalg.norm(now - before, axis=2).max(axis=1)
        assert step.max() < 0.5, f"frame {f}"
        jumps += int(np.count_nonzero(step > 0.1))
        before = now
        planted = np.linalg.norm(crowd.effector_positions()[:, feet] - targets[:, feet], axis=2)
        assert np.mean(planted <= wl.tolerance) >= 0.98 and planted.max() < 0.05  # feet stay planted
    assert jumps < 0.01 * n * 30


@pytest.mark.parametrize("k", range(1, 5))
def test_moving_one_limb_keeps_the_held_effectors(k):
    """Dragging one hand or foot 5 cm from rest, the other effectors held where they are, reaches all of them."""
    h = cik.Rig.humanoid()
    crowd = cik.Crowd(h, n=1)
    targets = crowd.effector_positions().copy()
    targets[0, k] += (0.0, 0.05, 0.05)
    rep = crowd.solve(targets, max_iterations=50, tolerance=2e-3)
    assert rep.status[0] == Status.CONVERGED
    assert np.all(np.linalg.norm(crowd.effector_positions()[0] - targets[0], axis=1) <= 2e-3)


def test_orientation_target_turns_the_sole_flat():
    h = cik.Rig.humanoid()
    crowd = cik.Crowd(h, n=20, spacing=2.0)
    rng = np.random.default_rng(4)
    lo, hi = h.angle_limits()
    crowd.set_angles((rng.uniform(lo, hi, (20, h.n_dof)) * 0.1).astype(np.float32))  # within the ankle's reach
    targets = crowd.effector_positions().copy()
    orient = np.zeros((20, 5, 3), np.float32)
    orient[:, 3] = (0, 1, 0)
    crowd.solve(targets, weights=[0, 0, 0, 1, 0], orientations=orient, max_iterations=10, tolerance=1e-6)
    ankle = h.arrays["eff_joint"][3]
    from crowd_ik.geometry.quat import qrot
    up = qrot(crowd.world_rotations()[:, ankle].astype(np.float64), np.array([0.0, 1.0, 0.0]))
    assert np.all(up[:, 1] > math.cos(math.radians(2)))


def _free_case(rig, n, seed=21):
    """n characters of a constraint-free rig with targets that start on the target, leave reach, or are near."""
    rng = np.random.default_rng(seed)
    crowd = cik.Crowd(rig, n=n, spacing=2.0)
    start = crowd.effector_positions().copy()
    targets = start + rng.normal(size=start.shape).astype(np.float32) * 0.4
    targets[0] = start[0]  # already there: no iteration
    targets[1, 0] += (5.0, 0.0, 0.0)  # out of reach
    weights = np.ones((n, rig.n_effectors), np.float32)
    if rig.n_effectors > 1:
        weights[2::3, 0] = 0.0  # some characters drive one branch of the tree only
        weights[3::3, 1] = 2.5
    return crowd, targets, weights


@pytest.mark.parametrize("lanes", [4, None])  # a small width and this machine's (16 with AVX-512, 8 with AVX2)
def test_lane_packed_free_kernel_equals_the_per_character_kernel(monkeypatch, lanes):
    """The lane-packed kernels (L characters per thread, streams that refill their lanes) give what fabrik_solve
    gives one character per thread with the same deferred recovery, for a crowd that is not a multiple of L, with
    characters that start on their target, converge, run out of iterations, or reach for an unreachable target,
    with per-character weights, on a chain and on a tree."""
    from crowd_ik.kernels import fabrik
    from crowd_ik.solvers import bundles, settings
    from crowd_ik.solvers import fabrik as adapter

    L = lanes or settings.lanes()
    monkeypatch.setattr(settings, "lanes", lambda: L)
    for rig in (cik.Rig.chain(7, 0.2, dim=3), free_tree()):
        assert rig.constraint_free
        n = 3 * L + 5
        crowd, targets, weights = _free_case(rig, n)

        def per_character(crowd, max_iterations, tolerance):
            fabrik.fabrik_solve(*bundles.limited_rig(crowd), *bundles.pose(crowd), *bundles.goal(crowd),
                                crowd.scratch("t_pos", crowd.ti.math.vec3, (n, rig.n_joints)),
                                crowd.scratch("t_w", crowd.ti.f32, (n, rig.n_joints)), max_iterations, tolerance,
                                0, 0, *bundles.rotation_goal(crowd), np.full((rig.n_effectors, 2), -1, np.int32),
                                0.0, 0, *bundles.result(crowd))

        lane_packed = adapter.solve_free
        for iterations in (2, 50):
            got = []
            for kernel in (lane_packed, per_character):
                monkeypatch.setattr(adapter, "solve_free", kernel)
                crowd.set_angles(np.zeros(rig.n_dof))
                rep = crowd.solve(targets, weights=weights, max_iterations=iterations, tolerance=1e-4)
                got.append((rep, crowd.joint_positions(), crowd.rotations()))
            (a, pa, qa), (b, pb, qb) = got
            reachable = a.status != Status.UNREACHABLE  # a plateau far from the target: stalls on round-off
            same = a.iterations == b.iterations
            assert np.mean(same[reachable]) >= 0.95 and same[0]
            np.testing.assert_array_equal(a.status[reachable], b.status[reachable])
            # the same operations up to the lanes' reciprocal multiplies (an ulp per component)
            np.testing.assert_allclose(a.error[same], b.error[same], atol=1e-4)
            np.testing.assert_allclose(pa[same], pb[same], atol=1e-4)
            np.testing.assert_allclose(qa[same], qb[same], atol=1e-4)
        assert a.iterations[0] == 0 and a.status[1] == Status.UNREACHABLE and np.any(a.status == Status.CONVERGED)


def test_lane_packed_free_kernel_batch_equals_one_at_a_time():
    """A character alone in a padded packet gets what it gets among lane-mates (lanes are independent)."""
    rig = free_tree()
    crowd, targets, weights = _free_case(rig, 21, seed=5)
    batch = crowd.solve(targets, weights=weights, max_iterations=30, tolerance=1e-4)
    pos = crowd.joint_positions()
    roots, _ = crowd.roots()
    for i in (0, 1, 2, 3, 7, 20):
        one = cik.Crowd(rig, n=1)
        one.set_roots(roots[i:i + 1])
        rep = one.solve(targets[i:i + 1], weights=weights[i:i + 1], max_iterations=30, tolerance=1e-4)
        assert rep.iterations[0] == batch.iterations[i] and rep.status[0] == batch.status[i]
        np.testing.assert_allclose(one.joint_positions()[0], pos[i], atol=1e-5)


def test_batch_equals_one_at_a_time_wherever_characters_stand():
    h = cik.Rig.humanoid()
    n = 40
    rng = np.random.default_rng(9)
    roots = rng.normal(size=(n, 3)).astype(np.float32) * 20
    roots[:, 1] = 0
    yaw = rng.uniform(-3, 3, n).astype(np.float32)
    local = _reachable_humanoid_targets(h, n, 3) - cik.Crowd(h, n=n, spacing=2.0).joint_positions()[:, :1, :] * [1, 0, 1]
    batch = cik.Crowd(h, n=n)
    batch.set_roots(roots, yaw)
    # express the targets around each character: rotate by its yaw and move to its root
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.stack([np.stack([c, 0 * c, s], -1), np.tile([0, 1, 0], (n, 1)), np.stack([-s, 0 * c, c], -1)], 1)
    targets = (np.einsum("nij,nej->nei", rot, local) + roots[:, None]).astype(np.float32)
    rep = batch.solve(targets, max_iterations=30, tolerance=1e-3)
    one = cik.Crowd(h, n=1)
    for i in range(0, n, 7):
        one.set_roots(roots[i : i + 1], yaw[i : i + 1])
        one.set_angles(np.zeros(h.n_dof))
        r1 = one.solve(targets[i : i + 1], max_iterations=30, tolerance=1e-3)
        assert r1.iterations[0] == rep.iterations[i]
        np.testing.assert_allclose(one.joint_positions()[0] - roots[i], batch.joint_positions()[i] - roots[i], atol=1e-5)


def test_kernel_matches_numpy_twin():
    for rig in (cik.Rig.chain(6, 0.3, dim=3, lo=-0.8, hi=0.8), cik.Rig.humanoid()):
        n = 32
        rng = np.random.default_rng(12)
        crowd = cik.Crowd(rig, n=n, spacing=2.0)
        lo, hi = np.clip(rig.angle_limits()[0], -1, 1), np.clip(rig.angle_limits()[1], -1, 1)
        crowd.set_angles((rng.uniform(lo, hi, (n, rig.n_dof)) * 0.5).astype(np.float32))
        targets = crowd.effector_positions() + rng.normal(size=(n, rig.n_effectors, 3)).astype(np.float32) * 0.05
        crowd.set_angles((rng.uniform(lo, hi, (n, rig.n_dof)) * 0.2).astype(np.float32))
        rot0 = crowd.rotations()
        roots, yaw = crowd.roots()
        rep = crowd.solve(targets, max_iterations=3, tolerance=1e-3)
        rot, pos, err, iters, _ = fabrik_solve(rig, roots, yaw, rot0, targets, max_iterations=3, tolerance=1e-3)
        np.testing.assert_array_equal(iters, rep.iterations)
        np.testing.assert_allclose(crowd.joint_positions(), pos, atol=2e-4)
        np.testing.assert_allclose(rep.error, err, atol=2e-4)


def test_2d_crowd_solution_is_a_planar_chain_pose():
    planar = pytest.importorskip("crowd_ik.planar")
    rig = cik.Rig.chain(4, dim=2)
    crowd = cik.Crowd(rig, n=100, spacing=0.0)
    targets = ball_targets(100, 3.6, 2, seed=8)
    rep = crowd.solve(targets[:, None], max_iterations=100, tolerance=1e-4)
    a = crowd.angles().astype(np.float64)
    for i in range(0, 100, 9):
        np.testing.assert_allclose(planar.chain(a[i]), crowd.effector_positions()[i, 0], atol=2e-5)
    assert np.mean(rep.converged) >= 0.98


def test_solve_is_deterministic_bitwise():
    rig = cik.Rig.chain(16, 0.1, dim=3)
    targets = ball_targets(500, 1.4, 3, seed=1)[:, None]
    out = []
    for _ in range(2):
        crowd = cik.Crowd(rig, n=500, spacing=0.0)
        crowd.solve(targets, max_iterations=20)
        out.append(crowd.rotations())
    assert np.array_equal(out[0], out[1])


@pytest.mark.parametrize("kwargs, match", [
    (dict(method="newton"), "method"),
    (dict(max_iterations=0), "max_iterations"),
    (dict(max_iterations=2.5), "max_iterations"),
    (dict(tolerance=0.0), "tolerance"),
    (dict(tolerance=-1.0), "tolerance"),
    (dict(weights=[-1.0]), "weights"),
    (dict(weights=[0.0]), "weights"),
    (dict(rest_weight=-1.0), "rest_weight"),
    (dict(orientations=[[[np.nan, 0.0, 1.0]], [[0.0, 0.0, 1.0]]]), "orientations: row \\[0, 0\\] is partly NaN"),
    (dict(orientations=np.ones((2, 1, 3))), "no local axis"),
    (dict(max_iterations=2**31), r"max_iterations: expected an integer in \[1, 10,000\]"),  # wrapped to 0 before
    (dict(max_iterations=10_001), "max_iterations"),
    (dict(weights=[1j]), "real numbers"),
])
def test_bad_arguments_raise_naming_the_argument(kwargs, match):
    crowd = cik.Crowd(cik.Rig.chain(3, dim=3), n=2)
    with pytest.raises(ValueError, match=match):
        crowd.solve(np.zeros((2, 1, 3), np.float32), **kwargs)


@pytest.mark.parametrize("targets, match", [
    (np.full((2, 1, 3), np.nan), "finite"), (np.full((2, 1, 3), np.inf), "finite"), (np.zeros((2, 2, 3)), "shape"),
    (np.zeros((3, 1, 3)), "shape"),
    (np.full((2, 1, 3), 2e19), r"within \+-10000"),  # the report's error was inf
    (np.zeros((2, 1, 3), np.complex64) + 1j, "real numbers"),  # was truncated to its real part
])
def test_bad_targets_raise(targets, match):
    crowd = cik.Crowd(cik.Rig.chain(3, dim=3), n=2)
    with pytest.raises(ValueError, match=f"targets.*{match}|{match}"):
        crowd.solve(targets)


def test_numpy_scalars_are_accepted_wherever_numbers_are():
    crowd = cik.Crowd(cik.Rig.chain(3, np.float32(0.5), dim=3), n=np.int64(2), spacing=np.float32(1.5))
    rep = crowd.solve(crowd.effector_positions() + np.float32([-0.2, 0.3, 0.1]), max_iterations=np.int32(30),
                      tolerance=np.float32(1e-3), rest_weight=np.float64(0.0))
    assert np.all(rep.converged)
    with pytest.raises(ValueError, match="spacing"):
        cik.Crowd(cik.Rig.chain(3, dim=3), n=4, spacing=1e300)
    with pytest.raises(ValueError, match="positions"):
        crowd.set_roots(np.full((2, 3), 1e5, np.float32))


@st.composite
def random_rigs(draw):
    n_bones = draw(st.integers(1, 12))
    dim = draw(st.sampled_from([2, 3]))
    length = draw(st.floats(0.05, 2.0))
    limited = draw(st.booleans())
    lim = draw(st.floats(0.1, 3.0)) if limited else None
    return cik.Rig.chain(n_bones, length, dim=dim, lo=None if lim is None else -lim, hi=lim)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rig=random_rigs(), seed=st.integers(0, 10_000), where=st.sampled_from(["inside", "root", "far", "surface"]))
def test_property_never_nan_lengths_and_limits_kept(rig, seed, where):
    rng = np.random.default_rng(seed)
    n = 8
    reach = rig.reach[0]
    d = rng.normal(size=(n, rig.dim))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    far = min(1e3 * reach, 5e3)  # (targets stay within the library's +-1e4 m)
    radius = {"inside": rng.uniform(0, reach, (n, 1)), "root": np.zeros((n, 1)), "far": np.full((n, 1), far),
              "surface": np.full((n, 1), reach)}[where]
    crowd = cik.Crowd(rig, n=n, spacing=0.0)
    rep = crowd.solve((d * radius)[:, None].astype(np.float32), max_iterations=20, tolerance=1e-3 * reach)
    pos = crowd.joint_positions()
    assert np.all(np.isfinite(pos)) and np.all(np.isfinite(rep.error))
    got, want = bone_lengths(crowd)
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=1e-5, atol=1e-6)
    lo, hi = rig.angle_limits()
    a = crowd.angles()
    assert np.all(a >= lo - 1e-5) and np.all(a <= hi + 1e-5)
    if where == "far":
        assert np.all(rep.status == Status.UNREACHABLE)
