"""Batched FK and joint-angle kernels against the NumPy twins, the planar homework chain, and one-at-a-time solves."""

import math

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.geometry import fk as ref


def _random_pose(rig, n, seed, scale=1.0):
    rng = np.random.default_rng(seed)
    lo, hi = rig.angle_limits()
    lo, hi = np.clip(lo, -math.pi / 2 + 0.05, None), np.clip(hi, None, math.pi / 2 - 0.05)
    return (rng.uniform(lo, hi, (n, rig.n_dof)) * scale).astype(np.float32), rng


@pytest.mark.parametrize("rig", [cik.Rig.chain(5, 0.3, dim=3), cik.Rig.chain(4, dim=2), cik.Rig.humanoid()],
                         ids=["chain3d", "chain2d", "humanoid"])
def test_fk_matches_numpy_twin(rig):
    a, rng = _random_pose(rig, 50, 1)
    crowd = cik.Crowd(rig, n=50, spacing=1.5)
    roots = rng.normal(size=(50, rig.dim)).astype(np.float32)
    yaw = rng.uniform(-3, 3, 50).astype(np.float32) if rig.dim == 3 else None
    crowd.set_roots(roots, yaw)
    crowd.set_angles(a)
    rot = ref.angles_to_rotations(rig, a)
    np.testing.assert_allclose(crowd.rotations(), rot, atol=1e-6)
    pos3 = np.zeros((50, 3))
    pos3[:, : rig.dim] = roots
    pos, _ = ref.forward_kinematics(rig, pos3, np.zeros(50) if yaw is None else yaw, rot)
    np.testing.assert_allclose(crowd.joint_positions(), pos[..., : rig.dim], atol=2e-5)
    np.testing.assert_allclose(crowd.angles(), a, atol=2e-6)  # Euler round trip inside the limits


@pytest.mark.parametrize("moved", [0, 3, 40])  # none, a few (FK of those alone), most (FK of all)
def test_set_roots_redoes_the_world_pose_of_the_moved_characters(moved):
    rig = cik.Rig.humanoid()
    n = 50
    a, rng = _random_pose(rig, n, 7, scale=0.5)
    crowd = cik.Crowd(rig, n=n, spacing=1.5)
    crowd.set_angles(a)
    roots, yaw = crowd.roots()
    before = crowd.joint_positions().copy()
    idx = rng.choice(n, moved, replace=False)
    roots, yaw = roots.copy(), yaw.copy()
    roots[idx] += rng.normal(size=(moved, 3)).astype(np.float32)
    yaw[idx[: moved // 2]] += 0.7  # some turn as well
    crowd.set_roots(roots, yaw)
    pos, _ = ref.forward_kinematics(rig, roots.astype(np.float64), yaw.astype(np.float64),
                                    ref.angles_to_rotations(rig, a))
    np.testing.assert_allclose(crowd.joint_positions(), pos, atol=2e-5)
    still = np.setdiff1d(np.arange(n), idx)
    np.testing.assert_array_equal(crowd.joint_positions()[still], before[still])


def test_crowd_2d_matches_planar_homework_chain():
    planar = pytest.importorskip("crowd_ik.planar")
    rig = cik.Rig.chain(4, dim=2)
    a, _ = _random_pose(rig, 200, 2)
    crowd = cik.Crowd(rig, n=200, spacing=0.0)
    crowd.set_angles(a)
    got = crowd.joint_positions()
    for i in range(0, 200, 17):
        np.testing.assert_allclose(got[i], planar.chain_all(a[i].astype(np.float64)), atol=2e-6)
    crowd1 = cik.Crowd(rig, n=1)
    crowd1.set_angles([0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(crowd1.effector_positions()[0, 0], [3.31597858, 1.80146708], atol=1e-5)


def test_batch_of_1000_equals_one_at_a_time():
    rig = cik.Rig.humanoid()
    a, rng = _random_pose(rig, 1000, 3)
    roots = rng.normal(size=(1000, 3)).astype(np.float32) * 10
    yaw = rng.uniform(-3, 3, 1000).astype(np.float32)
    crowd = cik.Crowd(rig, n=1000)
    crowd.set_roots(roots, yaw)
    crowd.set_angles(a)
    batch = crowd.joint_positions()
    one = cik.Crowd(rig, n=1)
    for i in rng.choice(1000, 25, replace=False):
        one.set_roots(roots[i : i + 1], yaw[i : i + 1])
        one.set_angles(a[i])
        np.testing.assert_allclose(one.joint_positions()[0], batch[i], atol=1e-5)


def test_translation_and_yaw_move_the_whole_character_rigidly():
    rig = cik.Rig.humanoid()
    a, _ = _random_pose(rig, 1, 4)
    crowd = cik.Crowd(rig, n=1)
    crowd.set_angles(a)
    p0 = crowd.joint_positions()[0]
    crowd.set_roots([[3.0, 0.0, -2.0]], [math.pi / 2])
    p1 = crowd.joint_positions()[0]
    rot_y = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float)  # +90 degrees about y
    np.testing.assert_allclose(p1, p0 @ rot_y.T + [3, 0, -2], atol=1e-5)


def _compiled(*modules) -> dict:
    """Per kernel of `modules`, how many instances Taichi has compiled in this process."""
    return {f"{m.__name__}.{name}": len(obj._primal.compiled_kernels) for m in modules
            for name, obj in vars(m).items() if hasattr(obj, "_primal")}


def test_a_second_rig_does_not_recompile():
    """Topology is data: the first rig compiles the kernels, another shape reuses them; only fk_kernel compiles
    once per joint count (each character's transforms in local arrays of that size: kernels/fk.py), and a rig of
    the same joint count but other bones and offsets reuses that too."""
    from crowd_ik.kernels import fk, jacobian

    def use(rig, n):
        crowd = cik.Crowd(rig, n=n)
        crowd.set_angles(np.full(rig.n_dof, 0.1))
        crowd.angles()
        crowd.jacobian()

    use(cik.Rig.chain(3, dim=3), 4)
    before = _compiled(fk, jacobian)
    assert sum(before.values()) >= 4  # the conversions, FK and the Jacobian were compiled
    use(cik.Rig.chain(29, 0.05, dim=3), 7)  # 30 joints: no other test of this file uses that many
    after = _compiled(fk, jacobian)
    assert {k: after[k] - before[k] for k in after if after[k] != before[k]} == {"crowd_ik.kernels.fk.fk_kernel": 1}
    use(cik.Rig.chain(29, 0.2, dim=3, lo=-1.0, hi=1.0), 5)  # 30 joints again, other offsets, limits
    assert _compiled(fk, jacobian) == after


def test_grid_roots_and_validation():
    crowd = cik.Crowd(cik.Rig.chain(2, dim=3), n=6, spacing=2.0)
    roots, yaw = crowd.roots()
    assert roots.shape == (6, 3) and np.all(roots[:, 1] == 0) and np.all(yaw == 0)
    assert len({tuple(r) for r in roots}) == 6
    assert np.isclose(roots[:, 0].mean(), 0.0)
    with pytest.raises(ValueError, match="positions"):
        crowd.set_roots(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="finite"):
        crowd.set_roots(np.full((6, 3), np.nan))
    with pytest.raises(ValueError, match="angles"):
        crowd.set_angles(np.zeros(5))
    with pytest.raises(ValueError, match="n"):
        cik.Crowd(cik.Rig.chain(2), n=0)
    with pytest.raises(ValueError, match="GiB"):
        cik.Crowd(cik.Rig.humanoid(), n=10**9)
    with pytest.raises(ValueError, match="yaw"):
        cik.Crowd(cik.Rig.chain(2, dim=2), n=2).set_roots(np.zeros((2, 2)), yaw=np.zeros(2))
