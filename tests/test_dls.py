"""Batched damped least squares: convergence, LM monotonicity, limits, objectives, batch == single, NumPy twin."""

import math

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik import planar
from crowd_ik.crowd import Status
from crowd_ik.reference.dls import (
    dls_settings, dls_solve, qexp, qlog, swing_vector,
)
from crowd_ik.geometry.quat import qconj, qmul, qrot
from solve_checks import assert_each_alone_gives_the_same_bits

CHAIN16 = dict(n_bones=16, bone_length=0.1, dim=3)


def ball_targets(n, radius, dim, seed):
    """Uniform in the ball of ``radius`` around the origin."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, dim))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (d * radius * rng.uniform(0, 1, (n, 1)) ** (1 / dim)).astype(np.float32)


def far_targets(n, reach, seed):
    """(targets (n, 3), unit directions (n, 3)) between 1.1 and 2.5 reaches away."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (d * rng.uniform(1.1, 2.5, (n, 1)) * reach).astype(np.float32), d


def humanoid_targets(rig, n, seed, scale=0.5):
    """Effector positions of random in-limit poses (scale times the range), so every target set is reachable."""
    rng = np.random.default_rng(seed)
    lo, hi = rig.angle_limits()
    c = cik.Crowd(rig, n=n, spacing=2.0)
    c.set_angles((rng.uniform(lo, hi, (n, rig.n_dof)) * scale).astype(np.float32))
    return c.effector_positions().copy()


def weighted_error(crowd, targets):
    return np.sum((crowd.effector_positions() - targets) ** 2, axis=(1, 2))


# ------------------------------------------------------------------------------------ convergence
def test_chain16_converges_on_reachable_targets():
    rig = cik.Rig.chain(**CHAIN16)
    crowd = cik.Crowd(rig, n=200, spacing=0.0)
    targets = ball_targets(200, 0.9 * 1.6, 3, seed=11)
    rep = crowd.solve(targets[:, None], method="dls", max_iterations=200, tolerance=1e-3)
    assert np.mean(rep.error <= 1e-3) >= 0.95
    assert np.all(rep.status[rep.error <= 1e-3] == Status.CONVERGED)
    assert np.all(rep.iterations <= 200) and rep.iterations.dtype == np.int32 and rep.status.dtype == np.int8
    assert np.median(rep.iterations) < 30
    # the report's error is the distance of the final pose's effector; bones keep their lengths
    np.testing.assert_allclose(rep.error, np.linalg.norm(crowd.effector_positions()[:, 0] - targets, axis=1),
                               atol=1e-6)
    bones = np.linalg.norm(np.diff(crowd.joint_positions(), axis=1), axis=-1)
    np.testing.assert_allclose(bones, 0.1, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(crowd.rotations(), axis=-1), 1.0, atol=1e-6)


def test_target_already_reached_needs_no_update():
    crowd = cik.Crowd(cik.Rig.chain(4, 0.5, dim=3), n=3)
    crowd.set_angles(np.full(12, 0.2, np.float32))
    rep = crowd.solve(crowd.effector_positions(), method="dls", tolerance=1e-4)
    assert np.all(rep.iterations == 0) and np.all(rep.status == Status.CONVERGED)


def test_humanoid_reaches_poses_it_could_hold_from_rest():
    h = cik.Rig.humanoid()
    targets = humanoid_targets(h, 100, seed=2)
    crowd = cik.Crowd(h, n=100, spacing=2.0)
    rep = crowd.solve(targets, method="dls", max_iterations=200, tolerance=5e-3)
    assert np.mean(rep.converged) >= 0.95
    lo, hi = h.angle_limits()
    a = crowd.angles()
    assert np.all(a >= lo - 1e-5) and np.all(a <= hi + 1e-5)


def test_unreachable_targets_end_stretched_toward_the_target():
    rig = cik.Rig.chain(**CHAIN16)
    targets, d = far_targets(30, 1.6, seed=5)
    crowd = cik.Crowd(rig, n=30, spacing=0.0)
    rep = crowd.solve(targets[:, None], method="dls", max_iterations=300, tolerance=1e-3)
    assert np.all(rep.status == Status.UNREACHABLE)
    pos = crowd.joint_positions()
    tip = pos[:, -1] - pos[:, 0]
    # the whole chain points at the target and is at full stretch: float32 resolves the tip to ~1e-6 m
    assert np.min(np.sum(tip / np.linalg.norm(tip, axis=1, keepdims=True) * d, axis=1)) > math.cos(1e-3)
    np.testing.assert_allclose(rep.error, np.linalg.norm(targets, axis=1) - 1.6, atol=5e-5)
    bones = np.diff(pos, axis=1)
    dirs = bones / np.linalg.norm(bones, axis=-1, keepdims=True)
    # each bone's own direction: a bend of phi at the last bone shortens the chain by only 0.05 phi^2
    # metres, which float32 forward kinematics (~1e-6 m) resolves to a few hundredths of a radian
    assert np.min(np.sum(dirs * d[:, None], axis=-1)) > math.cos(0.03)


def test_unreachable_targets_stretch_every_bone_to_1e3_rad_in_float64():
    rig = cik.Rig.chain(**CHAIN16)
    targets, d = far_targets(12, 1.6, seed=6)
    rest = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (12, rig.n_joints, 1))
    _, pos, err, _, _ = dls_solve(rig, np.zeros((12, 3)), np.zeros(12), rest, targets[:, None], max_iterations=400)
    dirs = np.diff(pos, axis=1)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    assert np.min(np.sum(dirs * d[:, None], axis=-1)) > math.cos(1e-3)
    np.testing.assert_allclose(err, np.linalg.norm(targets, axis=1) - 1.6, atol=1e-6)


# ------------------------------------------------------------------------------------ LM guarantees
def test_error_never_increases_from_one_iteration_to_the_next():
    rig = cik.Rig.chain(**CHAIN16)
    targets = ball_targets(40, 1.5, 3, seed=3)
    targets[:5] *= 2.0  # some out of reach
    crowd = cik.Crowd(rig, n=40, spacing=0.0)
    previous = None
    for k in range(1, 21):
        crowd.set_angles(np.zeros(rig.n_dof, np.float32))
        rep = crowd.solve(targets[:, None], method="dls", max_iterations=k, tolerance=1e-4)
        assert np.all(rep.iterations <= k)
        if previous is not None:
            assert np.all(rep.error <= previous + 1e-7)
        previous = rep.error
    # several effectors with limits and escapes: the weighted squared error never rises either
    h = cik.Rig.humanoid()
    targets = humanoid_targets(h, 20, seed=8)
    crowd = cik.Crowd(h, n=20, spacing=2.0)
    previous = None
    for k in range(1, 21):
        crowd.set_angles(np.zeros(h.n_dof, np.float32))
        rep = crowd.solve(targets, method="dls", max_iterations=k, tolerance=1e-4)
        f = weighted_error(crowd, targets)
        if previous is not None:
            assert np.all(f <= previous * (1 + 1e-5) + 1e-10)
        previous = f


def test_limits_always_hold():
    h = cik.Rig.humanoid()
    targets = humanoid_targets(h, 40, seed=9, scale=1.0)
    targets[:10] += np.float32(0.5)  # some far away
    crowd = cik.Crowd(h, n=40, spacing=2.0)
    lo, hi = h.angle_limits()
    for iterations in (1, 3, 50):
        crowd.set_angles(np.zeros(h.n_dof, np.float32))
        crowd.solve(targets, method="dls", max_iterations=iterations, tolerance=1e-4)
        a = crowd.angles()
        assert np.all(a >= lo - 1e-5) and np.all(a <= hi + 1e-5)
    # a box-limited ball chain and a cone-limited one, from start poses outside their limits
    for kwargs in (dict(lo=-0.3, hi=(0.5, 0.2, 0.4)), dict(cone=0.4)):
        rig = cik.Rig.chain(6, 0.2, dim=3, **kwargs)
        crowd = cik.Crowd(rig, n=30, spacing=0.0)
        crowd.set_angles(np.random.default_rng(1).uniform(-1, 1, (30, rig.n_dof)).astype(np.float32))
        crowd.solve(ball_targets(30, 1.3, 3, seed=2)[:, None], method="dls", max_iterations=60)
        if "lo" in kwargs:
            lo, hi = rig.angle_limits()
            a = crowd.angles()
            assert np.all(a >= lo - 1e-5) and np.all(a <= hi + 1e-5)
        else:
            pos = crowd.joint_positions()
            bones = np.diff(pos, axis=1)
            bones /= np.linalg.norm(bones, axis=-1, keepdims=True)
            bend = np.arccos(np.clip(np.sum(bones[:, 1:] * bones[:, :-1], -1), -1, 1))
            root_bend = np.arccos(np.clip(bones[:, 0, 0], -1, 1))
            assert bend.max() <= 0.4 + 1e-4 and root_bend.max() <= 0.4 + 1e-4


def test_a_knee_straight_on_its_limit_is_escaped():
    """From rest the knees sit on their 0 limit, where a first-order step cannot bend them: escapes do."""
    h = cik.Rig.humanoid()
    knee = h.dof_start[h.joint_names.index("knee_l")]
    pose = np.zeros(h.n_dof, np.float32)
    pose[knee] = 1.0
    c = cik.Crowd(h, n=1)
    c.set_angles(pose)
    target = c.effector_positions()
    c.set_angles(np.zeros(h.n_dof, np.float32))
    rep = c.solve(target, method="dls", weights=[0, 0, 0, 1, 0], max_iterations=100, tolerance=1e-3)
    assert rep.converged[0] and c.angles()[0, knee] > 0.1


# ------------------------------------------------------------------------------------ batches, twins
def test_batch_equals_one_at_a_time_wherever_characters_stand():
    h = cik.Rig.humanoid()
    n = 6
    rng = np.random.default_rng(4)
    home, _ = cik.Crowd(h, n=n, spacing=2.0).roots()
    roots = np.c_[rng.integers(-30, 30, n), np.zeros(n), rng.integers(-30, 30, n)].astype(np.float32)
    yaw = rng.uniform(-3, 3, n).astype(np.float32)
    # targets on a 1/1024 m grid: moved by whole metres they stay exact in float32
    targets = np.round((humanoid_targets(h, n, seed=4) - home[:, None] + roots[:, None]) * 1024) / 1024
    batch, _ = assert_each_alone_gives_the_same_bits(h, roots, yaw, targets, "dls", max_iterations=60, tolerance=1e-3)
    # the same characters 100 m away: the kernel works relative to each root, so the same bits
    moved = cik.Crowd(h, n=n)
    shift = np.float32([[64.0, 0.0, -96.0]])
    moved.set_roots(roots + shift, yaw)
    moved.solve(targets + shift[:, None], method="dls", max_iterations=60, tolerance=1e-3)
    np.testing.assert_array_equal(moved.rotations(), batch.rotations())
    np.testing.assert_allclose(moved.joint_positions() - shift[:, None], batch.joint_positions(), atol=1e-5)


@pytest.mark.parametrize("case", ["chain16", "humanoid", "limited", "objectives"])
def test_kernel_matches_numpy_twin(case):
    rng = np.random.default_rng(12)
    kwargs = dict(max_iterations=60, tolerance=1e-3)
    if case == "chain16":
        rig = cik.Rig.chain(**CHAIN16)
        n = 24
        targets = ball_targets(n, 1.5, 3, seed=12)[:, None]
        targets[:4] *= 1.5
    elif case == "humanoid":
        rig = cik.Rig.humanoid()
        n = 16
        targets = None  # effector positions of random poses of the characters where they stand
        orient = np.zeros((n, 5, 3), np.float32)
        orient[:, 3:] = (0.0, 1.0, 0.0)
        kwargs.update(orientations=orient, tolerance=5e-3)
    elif case == "limited":
        rig = cik.Rig.chain(6, 0.2, dim=3, lo=-0.5, hi=0.5, cone=0.6)
        n = 16
        targets = ball_targets(n, 1.1, 3, seed=13)[:, None]
    else:
        rig = cik.Rig.chain(5, 0.3, dim=3)
        n = 16
        targets = ball_targets(n, 1.2, 3, seed=14)[:, None]
        jw = np.ones(rig.n_dof)
        jw[3:6] = (0.0, 1.0, 0.5)
        kwargs.update(rest_weight=1e-3, velocity_weight=2e-3, joint_weights=jw, damping=0.05)
    crowd = cik.Crowd(rig, n=n, spacing=1.5)
    roots, _ = crowd.roots()
    yaw = rng.uniform(-3, 3, n).astype(np.float32)
    crowd.set_roots(roots, yaw)
    lo, hi = rig.angle_limits()
    if targets is None:
        crowd.set_angles((rng.uniform(lo, hi, (n, rig.n_dof)) * 0.5).astype(np.float32))
        targets = crowd.effector_positions().copy()
    else:
        targets = (targets + roots[:, None]).astype(np.float32)
    start = (rng.uniform(np.clip(lo, -1, 1), np.clip(hi, -1, 1), (n, rig.n_dof)) * 0.3).astype(np.float32)
    crowd.set_angles(start)
    rot0 = crowd.rotations()
    rep = crowd.solve(targets, method="dls", **kwargs)
    orient = kwargs.pop("orientations", None)
    rot, pos, err, iters, stalled = dls_solve(rig, roots, yaw, rot0, targets, orientations=orient, **kwargs)
    # float32 and float64 take the same accept/reject decisions almost always (here: all of them)
    same = (iters == rep.iterations) | (np.abs(err - rep.error) <= 1e-4)
    assert np.mean(same) >= 0.9
    agree = iters == rep.iterations
    assert np.mean(agree) >= 0.85
    np.testing.assert_allclose(rep.error[agree], err[agree], atol=1e-5)
    np.testing.assert_allclose(crowd.joint_positions()[agree], pos[agree], atol=1e-4)


def test_planar_chain_matches_planar_dls():
    for n_bones in (3, 5):
        rig = cik.Rig.chain(n_bones, 1.0, dim=2)
        crowd = cik.Crowd(rig, n=1, spacing=0.0)
        rng = np.random.default_rng(n_bones)
        for _ in range(3):
            start = rng.uniform(-0.9, 0.9, n_bones)
            target = planar.chain(start) + rng.uniform(-0.2, 0.2, 2)  # within both solvers' error clamps
            if np.linalg.norm(target) > 0.95 * n_bones:
                target *= 0.95 * n_bones / np.linalg.norm(target)
            want = planar.dls(start, target, damping=0.1, iterations=100, tolerance=1e-5)
            crowd.set_angles(start.astype(np.float32))
            rep = crowd.solve(np.float32([[target]]), method="dls", damping=0.1, max_iterations=100, tolerance=1e-5)
            # a nearby target: both take the same damped steps from the same start to the same pose
            assert rep.converged[0] and np.linalg.norm(planar.chain(want) - target) <= 1e-5
            np.testing.assert_allclose(crowd.angles()[0], want, atol=1e-4)
    # far but reachable targets: both get there
    rig = cik.Rig.chain(4, 1.0, dim=2)
    targets = ball_targets(20, 3.5, 2, seed=1)
    crowd = cik.Crowd(rig, n=20, spacing=0.0)
    rep = crowd.solve(targets[:, None], method="dls", max_iterations=200, tolerance=1e-4)
    for t, ok in zip(targets, rep.converged):
        theirs = planar.dls(np.zeros(4), t, iterations=200, tolerance=1e-4)
        if np.linalg.norm(planar.chain(theirs) - t) <= 1e-4:
            assert ok


# ------------------------------------------------------------------------------------ objectives
def test_orientation_target_turns_the_sole_up():
    h = cik.Rig.humanoid()
    n = 20
    crowd = cik.Crowd(h, n=n, spacing=2.0)
    rng = np.random.default_rng(4)
    lo, hi = h.angle_limits()
    crowd.set_angles((rng.uniform(lo, hi, (n, h.n_dof)) * 0.3).astype(np.float32))
    targets = crowd.effector_positions().copy()
    targets[:, 3, 1] += np.float32(0.05)  # lift the foot a little as well
    orient = np.zeros((n, 5, 3), np.float32)
    orient[:, 3] = (0.0, 1.0, 0.0)
    rep = crowd.solve(targets, method="dls", weights=[0, 0, 0, 1, 0], orientations=orient, max_iterations=100,
                      tolerance=1e-3)
    assert np.mean(rep.converged) >= 0.9  # a few end on a limit a centimetre short
    ankle = h.arrays["eff_joint"][3]
    up = qrot(crowd.world_rotations()[:, ankle].astype(np.float64), np.array([0.0, 1.0, 0.0]))
    assert np.all(up[:, 1] > math.cos(math.radians(2)))
    # without the orientation target the sole stays tilted
    crowd.set_angles((rng.uniform(lo, hi, (n, h.n_dof)) * 0.3).astype(np.float32))
    crowd.solve(targets, method="dls", weights=[0, 0, 0, 1, 0], max_iterations=100, tolerance=1e-3)
    up = qrot(crowd.world_rotations()[:, ankle].astype(np.float64), np.array([0.0, 1.0, 0.0]))
    assert np.mean(up[:, 1] < math.cos(math.radians(2))) > 0.5


def test_zero_joint_weight_freezes_a_dof_exactly():
    h = cik.Rig.humanoid()
    targets = humanoid_targets(h, 20, seed=6)
    crowd = cik.Crowd(h, n=20, spacing=2.0)
    start = (np.random.default_rng(6).uniform(*h.angle_limits(), (20, h.n_dof)) * 0.2).astype(np.float32)
    crowd.set_angles(start)
    frozen = [0, 4, h.dof_start[h.joint_names.index("elbow_l")], h.dof_start[h.joint_names.index("knee_r")]]
    jw = np.ones(h.n_dof)
    jw[frozen] = 0.0
    rep = crowd.solve(targets, method="dls", joint_weights=jw, max_iterations=50, tolerance=1e-3)
    assert rep.iterations.min() > 0
    np.testing.assert_allclose(crowd.angles()[:, frozen], start[:, frozen], atol=2e-6)
    # one DOF of an unlimited ball joint (then solved in its Euler angles), and a whole joint
    rig = cik.Rig.chain(6, 0.2, dim=3)
    crowd = cik.Crowd(rig, n=20, spacing=0.0)
    start = np.random.default_rng(7).uniform(-0.6, 0.6, (20, rig.n_dof)).astype(np.float32)
    crowd.set_angles(start)
    q0 = crowd.rotations()
    jw = np.ones(rig.n_dof)
    jw[[1, 6, 7, 8]] = 0.0
    rep = crowd.solve(ball_targets(20, 1.0, 3, seed=7)[:, None], method="dls", joint_weights=jw, max_iterations=80)
    assert np.mean(rep.converged) > 0.8
    np.testing.assert_allclose(crowd.angles()[:, 1], start[:, 1], atol=2e-5)
    np.testing.assert_allclose(crowd.rotations()[:, 2], q0[:, 2], atol=1e-6)


def test_rest_and_velocity_weights_move_toward_rest_and_start_and_keep_the_targets():
    # issue 15: the terms act in the null space of the targets (before, they pulled the tip up to 1 cm off: the
    # old assertions here were error < 1e-2 and a stronger pull, 0.7 x the plain solve's motion)
    rig = cik.Rig.chain(6, 0.2, dim=3)
    rng = np.random.default_rng(5)
    start = rng.uniform(-0.6, 0.6, (30, rig.n_dof)).astype(np.float32)
    targets = ball_targets(30, 1.0, 3, seed=5)[:, None]
    crowd = cik.Crowd(rig, n=30, spacing=0.0)

    def solve(**kw):
        crowd.set_angles(start)
        rep = crowd.solve(targets, method="dls", max_iterations=200, tolerance=1e-4, **kw)
        q = crowd.rotations()
        return rep, np.linalg.norm(qlog(q.astype(np.float64)), axis=-1).sum(1), crowd.angles()

    crowd.set_angles(start)
    q_start = crowd.rotations().astype(np.float64)
    plain, rot_plain, _ = solve()
    rest, rot_rest, _ = solve(rest_weight=1e-3)
    assert np.all(plain.converged) and np.all(rest.converged)
    assert np.mean(rot_rest < rot_plain) >= 0.9 and rot_rest.mean() < 0.8 * rot_plain.mean()
    vel, _, _ = solve(velocity_weight=1e-3)
    moved_vel = np.linalg.norm(qlog(qmul(crowd.rotations().astype(np.float64), qconj(q_start))), axis=-1).sum(1)
    solve()
    moved_plain = np.linalg.norm(qlog(qmul(crowd.rotations().astype(np.float64), qconj(q_start))), axis=-1).sum(1)
    assert np.mean(moved_vel < moved_plain) >= 0.9 and moved_vel.mean() < 0.8 * moved_plain.mean()
    assert np.all(vel.converged)


def test_default_damping_and_error_clamp():
    s = dls_settings(cik.Rig.chain(**CHAIN16))
    assert s["length"] == pytest.approx(1.6)
    assert s["damping"] == pytest.approx(0.05 * 1.6)
    np.testing.assert_allclose(s["eff_lim"], [[1.6, 1.0 * 0.1 * 4]], rtol=1e-6)  # d_max = 1.0 l sqrt(16)
    assert dls_settings(cik.Rig.chain(**CHAIN16), damping=0.0)["damping"] == pytest.approx(1e-3 * 1.6)
    h = dls_settings(cik.Rig.humanoid())
    assert list(h["jmode"][:5]) == [1, 1, 1, 1, 0]  # limited ball joints move their Euler angles
    assert list(dls_settings(cik.Rig.chain(3, dim=3))["jmode"]) == [2, 2, 2, 0]


def test_quaternion_helpers():
    rng = np.random.default_rng(0)
    r = rng.normal(size=(50, 3))
    r *= (rng.uniform(0, 3, 50) / np.linalg.norm(r, axis=1))[:, None]
    np.testing.assert_allclose(qlog(qexp(r)), r, atol=1e-12)
    a = rng.normal(size=(50, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    t = rng.normal(size=(50, 3))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    np.testing.assert_allclose(qrot(qexp(swing_vector(a, t)), a), t, atol=1e-12)


# ------------------------------------------------------------------------------------ static balance


@pytest.mark.parametrize("kwargs, match", [
    (dict(damping=-1.0), "damping"),
    (dict(rest_weight=-0.1), "rest_weight"),
    (dict(velocity_weight=float("inf")), "velocity_weight"),
    (dict(joint_weights=[1.0, 2.0]), "joint_weights"),
    (dict(joint_weights=-np.ones(12)), "joint_weights"),
    (dict(max_iterations=0), "max_iterations"),
    (dict(tolerance=0.0), "tolerance"),
])
def test_bad_inputs_raise(kwargs, match):
    crowd = cik.Crowd(cik.Rig.chain(4, 0.5, dim=3), n=2)
    with pytest.raises(ValueError, match=match):
        crowd.solve(np.ones((2, 1, 3), np.float32), method="dls", **kwargs)
    with pytest.raises(ValueError, match="targets"):
        crowd.solve(np.full((2, 1, 3), np.nan, np.float32), method="dls")


def test_identical_solves_give_identical_bits():
    h = cik.Rig.humanoid()
    targets = humanoid_targets(h, 30, seed=10)
    out = []
    for _ in range(2):
        crowd = cik.Crowd(h, n=30, spacing=2.0)
        rep = crowd.solve(targets, method="dls", max_iterations=40, tolerance=1e-3)
        out.append((crowd.rotations(), rep.error, rep.iterations, rep.status))
    for a, b in zip(*out):
        np.testing.assert_array_equal(a, b)


def test_all_joint_weights_zero_stalls_without_moving():
    """A frozen rig (every joint weight zero) cannot move: the solve stalls without touching the pose."""
    rig = cik.Rig.chain(3, 0.5, dim=3)
    crowd = cik.Crowd(rig, n=2)
    q0 = crowd.rotations()
    rep = crowd.solve(np.float32([[[0.5, 0.5, 0.0]], [[0.0, 1.0, 0.0]]]), method="dls",
                      joint_weights=np.zeros(rig.n_dof), max_iterations=30)
    assert np.all(rep.status == Status.STALLED) and np.all(rep.iterations == 0)
    np.testing.assert_allclose(crowd.rotations(), q0, atol=1e-7)
    crowd = cik.Crowd(rig, n=2)  # with its DOFs free it reaches both
    assert np.all(crowd.solve(np.float32([[[0.5, 0.5, 0.0]], [[0.0, 1.0, 0.0]]]), method="dls").converged)
