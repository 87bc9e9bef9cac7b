"""CCD solver: convergence on chains, limits, exact bone lengths, unreachable targets, batch = single, NumPy twin."""

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.reference import ccd as ref_ccd
from crowd_ik.geometry.fk import rotations_to_angles


def ball_targets(n, dim, reach, rng, rmax=0.95):
    """n targets uniform in the ball (disc) of radius rmax * reach about the origin: (n, 1, dim)."""
    d = rng.normal(size=(n, dim))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = rmax * reach * rng.uniform(0.0, 1.0, size=(n, 1)) ** (1.0 / dim)
    return (d * r)[:, None, :].astype(np.float32)


def in_limit_pose_targets(rig, n, rng, yaw=None):
    """Effector positions (n, E, 3) of random in-limit poses: every angle uniform in half its range about rest."""
    lo, hi = rig.angle_limits()
    angles = 0.5 * rng.uniform(lo, hi, size=(n, rig.n_dof))
    crowd = cik.Crowd(rig, n=n, spacing=2.0)
    crowd.set_angles(angles.astype(np.float32))
    return crowd.effector_positions().copy()


def bone_length_error(crowd):
    rig = crowd.rig
    pos = crowd.joint_positions()
    parent = rig.arrays["parent"]
    lengths = np.linalg.norm(pos[:, 1:] - pos[:, parent[1:]], axis=-1)
    return np.abs(lengths - rig.bone_lengths[1:]).max()


@pytest.mark.parametrize("dim, tol, rate", [(3, 1e-3, 0.70), (3, 5e-3, 0.80), (2, 1e-3, 0.78), (2, 5e-3, 0.85)])
def test_chain16_converges_on_random_reachable_targets(dim, tol, rate):
    # Measured over 4 seeds (1000 targets uniform in 0.95 of the reach ball, 200 sweeps, from rest):
    # 3D 76-79 % within 1 mm, 84-86 % within 5 mm; 2D 84-85 %, 89-91 %. CCD is slow on targets near
    # full reach (it must uncurl the chain it bent), fast near the root; the bounds keep a margin.
    rig = cik.Rig.chain(16, bone_length=0.1, dim=dim)
    crowd = cik.Crowd(rig, n=1000, spacing=0.0)
    targets = ball_targets(1000, dim, 1.6, np.random.default_rng(7))
    report = crowd.solve(targets, method="ccd", max_iterations=200, tolerance=tol)
    assert report.converged.mean() >= rate
    assert np.all(report.error[report.converged] <= tol)
    assert np.all(report.iterations <= 200) and report.iterations.min() >= 1
    # converged characters really reached their target (the report is computed from the final pose)
    tip = crowd.effector_positions()[:, 0]
    np.testing.assert_allclose(np.linalg.norm(tip - targets[:, 0], axis=-1), report.error, atol=2e-6)
    # near targets converge in a handful of sweeps
    near = np.linalg.norm(targets[:, 0], axis=-1) < 0.4
    assert np.median(report.iterations[near]) <= 5
    assert bone_length_error(crowd) < 1e-5


def test_humanoid_converges_on_in_limit_pose_targets_and_keeps_limits():
    rig = cik.Rig.humanoid()
    rng = np.random.default_rng(3)
    targets = in_limit_pose_targets(rig, 300, rng)
    crowd = cik.Crowd(rig, n=300, spacing=2.0)
    report = crowd.solve(targets, method="ccd", max_iterations=200, tolerance=5e-3)
    # measured 88 % (1000 poses, seed 1); the hinge reach step is what gets the limbs out of the straight rest pose
    assert report.converged.mean() >= 0.80
    lo, hi = rig.angle_limits()
    a = crowd.angles()
    assert np.all(a >= lo - 1e-4) and np.all(a <= hi + 1e-4)
    assert bone_length_error(crowd) < 1e-5


def test_limbs_alone_converge_fast():
    # one hand or one foot: shoulder/hip aim, elbow/knee set the reach. Measured (3 seeds x 200 poses):
    # hands 100 % within 5 mm, median 1-3 sweeps; feet 97-100 %, median 1, mean 5-6 (a few creep along a limit)
    rig = cik.Rig.humanoid()
    targets = in_limit_pose_targets(rig, 200, np.random.default_rng(4))
    crowd = cik.Crowd(rig, n=200, spacing=2.0)
    for e in (1, 2, 3, 4):
        crowd.set_angles(np.zeros(rig.n_dof, np.float32))
        w = np.zeros(rig.n_effectors, np.float32)
        w[e] = 1.0
        report = crowd.solve(targets, method="ccd", max_iterations=100, tolerance=5e-3, weights=w)
        assert report.converged.mean() >= 0.95, rig.effector_names[e]
        assert np.median(report.iterations) <= 3 and report.iterations.mean() <= 10


def test_limits_and_cones_never_violated_on_random_targets():
    rng = np.random.default_rng(5)
    rig = cik.Rig.humanoid()
    n = 200
    crowd = cik.Crowd(rig, n=n, spacing=3.0)
    roots, _ = crowd.roots()
    lo, hi = rig.angle_limits()
    for _ in range(3):  # reachable or not, anywhere around the body
        targets = roots[:, None, :] + rng.uniform([-1.2, -0.2, -1.2], [1.2, 2.2, 1.2], size=(n, rig.n_effectors, 3))
        crowd.solve(targets.astype(np.float32), method="ccd", max_iterations=30, tolerance=1e-4)
        a = crowd.angles()
        assert np.all(a >= lo - 1e-4) and np.all(a <= hi + 1e-4)
        assert bone_length_error(crowd) < 1e-5

    cone = 0.4
    chain = cik.Rig.chain(8, bone_length=0.1, dim=3, cone=cone)
    crowd = cik.Crowd(chain, n=200, spacing=0.0)
    crowd.solve(ball_targets(200, 3, 0.8, rng, rmax=1.0), method="ccd", max_iterations=30, tolerance=1e-4)
    rot = crowd.rotations()
    # each joint's child bone (+x at rest) stays within the cone about its rest direction
    x = np.array([1.0, 0.0, 0.0])
    u, w = rot[:, :8, :3], rot[:, :8, 3:]
    t = 2.0 * np.cross(u, x)
    bone = x + w * t + np.cross(u, t)
    assert np.arccos(np.clip(bone[..., 0], -1, 1)).max() <= cone + 1e-4
    # and the cone is active: unconstrained CCD would bend further for targets near the root
    assert np.arccos(np.clip(bone[..., 0], -1, 1)).max() >= cone - 1e-3


@pytest.mark.parametrize("dim", [2, 3])
def test_unreachable_target_stretches_toward_it(dim):
    rig = cik.Rig.chain(16, bone_length=0.1, dim=dim)
    rng = np.random.default_rng(11)
    n = 200
    d = rng.normal(size=(n, dim))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    targets = (d * rng.uniform(2.0, 4.0, size=(n, 1)))[:, None, :].astype(np.float32)
    crowd = cik.Crowd(rig, n=n, spacing=0.0)
    crowd.set_angles(rng.uniform(-0.5, 0.5, size=(n, rig.n_dof)).astype(np.float32))
    report = crowd.solve(targets, method="ccd", max_iterations=100, tolerance=1e-3)
    assert np.all(report.status == cik.Status.UNREACHABLE)
    assert report.iterations.max() <= 12  # straight in a sweep or two, then no more progress
    pos = crowd.joint_positions()
    bones = np.diff(pos, axis=1) / 0.1
    # every bone points at the target: the chain lies straight along the root-target line
    assert np.einsum("nbk,nk->nb", bones, d).min() > 0.9999
    reach = np.linalg.norm(pos[:, -1], axis=-1)
    np.testing.assert_allclose(reach, 1.6, atol=1e-4)
    np.testing.assert_allclose(report.error, np.linalg.norm(targets[:, 0], axis=-1) - reach, atol=1e-4)


def test_unreachable_hand_reaches_out_with_a_straight_arm():
    rig = cik.Rig.humanoid()
    crowd = cik.Crowd(rig, n=50, spacing=3.0)
    rng = np.random.default_rng(12)
    roots, _ = crowd.roots()
    chest = crowd.joint_positions()[:, rig.joint_names.index("chest")]
    d = rng.normal(size=(50, 3)) + np.array([2.0, 0.0, 0.0])  # to the left side, out of reach
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    targets = crowd.effector_positions().copy()
    targets[:, 1] = chest + 3.0 * d
    w = np.array([0, 1, 0, 0, 0], np.float32)
    report = crowd.solve(targets.astype(np.float32), method="ccd", max_iterations=50, tolerance=1e-3, weights=w)
    assert np.all(report.status == cik.Status.UNREACHABLE)
    a = crowd.angles()
    lo, hi = rig.angle_limits()
    assert np.all(a >= lo - 1e-4) and np.all(a <= hi + 1e-4)
    elbow = a[:, rig.dof_start[rig.joint_names.index("elbow_l")]]
    assert np.abs(elbow).max() < 1e-3  # the elbow straightens
    # and the arm points at the target: shoulder -> hand nearly along shoulder -> target
    pos = crowd.joint_positions()
    sh = pos[:, rig.joint_names.index("shoulder_l")]
    arm = pos[:, rig.joint_names.index("hand_l")] - sh
    want = targets[:, 1] - sh
    cos = np.sum(arm * want, -1) / np.linalg.norm(arm, axis=-1) / np.linalg.norm(want, axis=-1)
    assert np.median(cos) > 0.99


def test_already_at_target_takes_no_sweep():
    rig = cik.Rig.chain(4, bone_length=0.25, dim=3)
    crowd = cik.Crowd(rig, n=3)
    report = crowd.solve(crowd.effector_positions(), method="ccd", max_iterations=10, tolerance=1e-4)
    assert np.all(report.iterations == 0) and np.all(report.status == cik.Status.CONVERGED)


@pytest.mark.parametrize("rig_name", ["humanoid", "chain16"])
def test_batch_equals_single_wherever_they_stand(rig_name):
    # N characters far apart, solved at once, against each alone at the origin with the same relative
    # targets: the kernel works relative to each root, so they agree to float32 rounding of the roots
    rng = np.random.default_rng(2)
    n = 8
    if rig_name == "humanoid":
        rig = cik.Rig.humanoid()
        rel = in_limit_pose_targets(rig, n, rng) - cik.Crowd(rig, n=n, spacing=2.0).roots()[0][:, None, :]
        rel = rel + rng.normal(0.0, 0.05, size=rel.shape)
    else:
        rig = cik.Rig.chain(16, bone_length=0.1, dim=3)
        rel = ball_targets(n, 3, 1.6, rng, rmax=1.2)  # some out of reach
    crowd = cik.Crowd(rig, n=n, spacing=5.0)
    roots, _ = crowd.roots()
    yaw = rng.uniform(-np.pi, np.pi, n).astype(np.float32)
    crowd.set_roots(roots, yaw)
    world = (rel + roots[:, None, :]).astype(np.float32)
    batch = crowd.solve(world, method="ccd", max_iterations=40, tolerance=1e-3)
    pos = crowd.joint_positions() - roots[:, None, :]
    for i in range(n):
        one = cik.Crowd(rig, n=1)
        one.set_roots(np.zeros((1, 3), np.float32), yaw[i : i + 1])
        single = one.solve(world[i : i + 1] - roots[i], method="ccd", max_iterations=40, tolerance=1e-3)
        np.testing.assert_allclose(one.joint_positions()[0], pos[i], atol=1e-5)
        np.testing.assert_allclose(single.error[0], batch.error[i], atol=1e-5)
        assert single.iterations[0] == batch.iterations[i]
        assert single.status[0] == batch.status[i]


def _compare_with_twin(rig, crowd, targets, iterations, tolerance=1e-6, weights=None, orient=None):
    """Run the kernel and the NumPy twin from the crowd's current pose; compare rotations and positions."""
    roots, yaw = crowd.roots()
    root3 = np.zeros((crowd.n, 3))
    root3[:, : rig.dim] = roots
    tgt3 = np.zeros((crowd.n, rig.n_effectors, 3))
    tgt3[..., : rig.dim] = targets
    twin = ref_ccd.ccd_solve(rig, root3, yaw, crowd.rotations(), tgt3, weights=weights, orient=orient,
                             max_iterations=iterations, tolerance=tolerance)
    report = crowd.solve(targets, method="ccd", max_iterations=iterations, tolerance=tolerance, weights=weights,
                         orientations=orient)
    q = crowd.rotations().astype(np.float64)
    sign = np.where(np.sum(q * twin["rot"], axis=-1, keepdims=True) < 0, -1.0, 1.0)
    np.testing.assert_allclose(q * sign, twin["rot"], atol=1e-4)
    np.testing.assert_allclose(crowd.joint_positions(), twin["pos"][..., : rig.dim], atol=1e-4)
    np.testing.assert_array_equal(report.iterations, twin["iterations"])
    np.testing.assert_allclose(report.error, twin["error"], atol=1e-5)
    return twin


def test_twin_matches_kernel_on_3d_chain():
    rng = np.random.default_rng(21)
    rig = cik.Rig.chain(6, bone_length=0.2, dim=3)
    crowd = cik.Crowd(rig, n=8, spacing=1.0)
    crowd.set_angles(rng.uniform(-0.5, 0.5, size=(8, rig.n_dof)).astype(np.float32))
    roots, _ = crowd.roots()
    targets = roots[:, None, :] + ball_targets(8, 3, 1.2, rng)
    _compare_with_twin(rig, crowd, targets.astype(np.float32), iterations=3)


def test_twin_matches_kernel_on_limited_chains():
    rng = np.random.default_rng(22)
    rig = cik.Rig.chain(5, bone_length=0.2, dim=3, lo=-0.4, hi=0.4, cone=0.6)
    crowd = cik.Crowd(rig, n=8, spacing=1.0)
    roots, _ = crowd.roots()
    targets = roots[:, None, :] + ball_targets(8, 3, 1.0, rng)
    _compare_with_twin(rig, crowd, targets.astype(np.float32), iterations=3)

    planar = cik.Rig.chain(6, bone_length=0.2, dim=2, lo=-1.0, hi=1.0)
    crowd = cik.Crowd(planar, n=8, spacing=1.0)
    roots, _ = crowd.roots()
    targets = roots[:, None, :] + ball_targets(8, 2, 1.2, rng)
    twin = _compare_with_twin(planar, crowd, targets.astype(np.float32), iterations=4)
    np.testing.assert_allclose(crowd.angles(), rotations_to_angles(planar, twin["rot"]), atol=1e-4)


def test_twin_matches_kernel_when_stretching_toward_unreachable_targets():
    rng = np.random.default_rng(24)
    for dim in (2, 3):
        rig = cik.Rig.chain(6, bone_length=0.2, dim=dim)
        crowd = cik.Crowd(rig, n=8, spacing=1.0)
        crowd.set_angles(rng.uniform(-1.0, 1.0, size=(8, rig.n_dof)).astype(np.float32))
        roots, _ = crowd.roots()
        d = rng.normal(size=(8, dim))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        targets = roots[:, None, :] + 2.0 * d[:, None, :]
        twin = _compare_with_twin(rig, crowd, targets.astype(np.float32), iterations=2)
        assert np.all(np.linalg.norm(twin["pos"][:, -1, :dim] - roots, axis=-1) > 1.2 - 1e-3)


def test_twin_matches_kernel_on_humanoid_with_orientations_and_weights():
    rng = np.random.default_rng(23)
    rig = cik.Rig.humanoid()
    n = 6
    targets = in_limit_pose_targets(rig, n, rng)
    crowd = cik.Crowd(rig, n=n, spacing=2.0)
    roots, _ = crowd.roots()
    crowd.set_roots(roots, rng.uniform(-1, 1, n).astype(np.float32))
    targets = (targets + rng.normal(0, 0.02, size=targets.shape)).astype(np.float32)
    weights = rng.uniform(0.2, 1.5, size=(n, rig.n_effectors)).astype(np.float32)
    weights[0, 0] = 0.0  # one character ignores its head
    orient = np.zeros((n, rig.n_effectors, 3), np.float32)
    tilt = rng.normal(0, 0.15, size=(n, 2, 3)) + np.array([0.0, 1.0, 0.0])
    orient[:, 3:5] = tilt / np.linalg.norm(tilt, axis=-1, keepdims=True)
    twin = _compare_with_twin(rig, crowd, targets, iterations=3, weights=weights, orient=orient)
    np.testing.assert_allclose(crowd.angles(), rotations_to_angles(rig, twin["rot"]), atol=1e-4)


def test_orientation_targets_turn_the_feet():
    rig = cik.Rig.humanoid()
    crowd = cik.Crowd(rig, n=4, spacing=2.0)
    feet = crowd.effector_positions() + np.array([0.0, 0.03, 0.02], np.float32)  # lift: the knees must bend
    orient = np.zeros((4, rig.n_effectors, 3), np.float32)
    tilt = np.array([0.0, np.cos(0.2), np.sin(0.2)])  # 0.2 rad about x: inside the ankle's flexion range
    orient[:, 3] = tilt
    orient[:, 4] = tilt
    weights = np.array([0, 0, 0, 1, 1], np.float32)
    report = crowd.solve(feet, method="ccd", max_iterations=50, tolerance=1e-4, weights=weights, orientations=orient)
    assert np.all(report.converged)
    wrot = crowd.world_rotations()
    for name in ("ankle_l", "ankle_r"):
        q = wrot[:, rig.joint_names.index(name)]
        u, w = q[:, :3], q[:, 3:]
        y = np.array([0.0, 1.0, 0.0])
        t = 2.0 * np.cross(u, y)
        axis = y + w * t + np.cross(u, t)
        # the orientation pass runs after the positional sweep, so nothing turns the ankle afterwards
        assert np.all(axis @ tilt > np.cos(1e-3))
