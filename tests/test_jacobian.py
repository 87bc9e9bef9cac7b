"""Analytic Jacobians (position and orientation rows; Euler and quaternion columns) against finite differences."""

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.geometry import fk as ref
from crowd_ik.geometry.quat import qconj, qmul


def _fd_jacobian(rig, a, roots, yaw, eps=1e-6):
    """Central differences of effector positions and orientations (as rotation vectors) in float64."""
    n, D = a.shape
    E = rig.n_effectors
    eff = rig.arrays["eff_joint"]
    jac = np.zeros((n, 6 * E, D))
    pos0, wrot0 = ref.forward_kinematics(rig, roots, yaw, ref.angles_to_rotations(rig, a))
    for d in range(D):
        step = np.zeros(D)
        step[d] = eps
        pp, rp = ref.forward_kinematics(rig, roots, yaw, ref.angles_to_rotations(rig, a + step))
        pm, rm = ref.forward_kinematics(rig, roots, yaw, ref.angles_to_rotations(rig, a - step))
        dp = (pp[:, eff] - pm[:, eff]) / (2 * eps)
        # angular velocity: vector part of (q+ q-^*) ~ omega * 2 eps / 2
        dq = qmul(rp[:, eff], qconj(rm[:, eff]))
        dq = np.where(dq[..., 3:] < 0, -dq, dq)
        omega = 2 * dq[..., :3] / (2 * eps)
        for e in range(E):
            jac[:, 6 * e : 6 * e + 3, d] = dp[:, e]
            jac[:, 6 * e + 3 : 6 * e + 6, d] = omega[:, e]
    return jac


@pytest.mark.parametrize("rig", [cik.Rig.chain(6, 0.2, dim=3), cik.Rig.chain(5, 1.0, dim=2), cik.Rig.humanoid()],
                         ids=["chain3d", "chain2d", "humanoid"])
def test_kernel_jacobian_matches_finite_differences(rig):
    rng = np.random.default_rng(7)
    lo, hi = rig.angle_limits()
    lo, hi = np.clip(lo, -1.2, None), np.clip(hi, None, 1.2)
    a = rng.uniform(lo, hi, (12, rig.n_dof))
    roots = np.zeros((12, 3))
    roots[:, : rig.dim] = rng.normal(size=(12, rig.dim))
    yaw = rng.uniform(-3, 3, 12) if rig.dim == 3 else np.zeros(12)
    crowd = cik.Crowd(rig, n=12)
    crowd.set_roots(roots[:, : rig.dim], yaw if rig.dim == 3 else None)
    crowd.set_angles(a.astype(np.float32))
    fd = _fd_jacobian(rig, a, roots, yaw)
    got = crowd.jacobian("euler")
    scale = max(1.0, np.abs(fd).max())
    np.testing.assert_allclose(got, fd, atol=2e-5 * scale)


def test_homework_dchain_values_from_the_kernel():
    crowd = cik.Crowd(cik.Rig.chain(4, dim=2), n=1, spacing=0)
    crowd.set_angles(np.zeros(4))
    np.testing.assert_allclose(crowd.jacobian()[0, :2], [[0, 0, 0, 0], [4, 3, 2, 1]], atol=1e-6)
    crowd3 = cik.Crowd(cik.Rig.chain(3, dim=2), n=1, spacing=0)
    crowd3.set_angles([0.1, 0.2, 0.3])
    np.testing.assert_allclose(crowd3.jacobian()[0, :2],
                               [[-0.9599961, -0.86016268, -0.56464247], [2.77567627, 1.7806721, 0.82533561]], atol=1e-6)


def test_quaternion_columns_are_world_axis_rotations():
    """ball_mode quaternion: column k = derivative of rotating the joint's local frame about world axis k."""
    rig = cik.Rig.chain(3, 0.5, dim=3)
    rng = np.random.default_rng(3)
    a = rng.uniform(-1, 1, (4, 9))
    crowd = cik.Crowd(rig, n=4, spacing=0)
    crowd.set_angles(a.astype(np.float32))
    got = crowd.jacobian("quaternion")
    rot = ref.angles_to_rotations(rig, a)
    pos, wrot = ref.forward_kinematics(rig, np.zeros((4, 3)), np.zeros(4), rot)
    eps = 1e-6
    for j in range(3):
        parent_rot = wrot[:, j - 1] if j > 0 else np.tile([0, 0, 0, 1.0], (4, 1))
        for k in range(3):
            w = np.zeros(3)
            w[k] = eps
            from crowd_ik.geometry.quat import axis_angle
            dq = axis_angle(w / eps, np.full(4, eps))  # world rotation by eps about axis k
            local = qmul(qmul(qconj(parent_rot), qmul(dq, parent_rot)), rot[:, j])
            r2 = rot.copy()
            r2[:, j] = local
            p2, _ = ref.forward_kinematics(rig, np.zeros((4, 3)), np.zeros(4), r2)
            np.testing.assert_allclose(got[:, 0:3, 3 * j + k], (p2[:, -1] - pos[:, -1]) / eps, atol=2e-5)


def test_kernel_jacobian_matches_numpy_twin_both_modes():
    rig = cik.Rig.humanoid()
    rng = np.random.default_rng(11)
    lo, hi = rig.angle_limits()
    a = rng.uniform(lo, hi, (20, rig.n_dof)).astype(np.float32)
    crowd = cik.Crowd(rig, n=20)
    crowd.set_angles(a)
    rot = crowd.rotations().astype(np.float64)
    roots, yaw = crowd.roots()
    pos, wrot = ref.forward_kinematics(rig, roots.astype(np.float64), yaw, rot)
    for mode in ("euler", "quaternion"):
        np.testing.assert_allclose(crowd.jacobian(mode), ref.jacobian(rig, yaw, rot, pos, wrot, mode), atol=5e-6)
    with pytest.raises(ValueError, match="ball_mode"):
        crowd.jacobian("matrix")
