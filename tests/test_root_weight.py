"""Crowd.solve(root_weight=w) (issue 15): a free root. DLS moves it as 3 more unknowns (against the NumPy twin);
FABRIK and CCD first move it by the sub-base rule of kernels/root_shift.py (against its twin); roots() and the
world pose follow; balance with a free root keeps the feet planted and the centre of mass over them."""

import math

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.crowd import Status
from crowd_ik.reference.dls import balance_offset, dls_solve
from crowd_ik.reference.root_shift import shift_roots
from solve_checks import assert_each_alone_gives_the_same_bits

METHODS = ("fabrik", "dls", "ccd")


def far_case(n, dim=3, seed=0):
    """(crowd, targets (n, 1, dim)): a 4-bone chain of reach 1.2 and targets 1.3-2 m from each root."""
    rig = cik.Rig.chain(4, 0.3, dim=dim)
    crowd = cik.Crowd(rig, n=n, spacing=3.0)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, dim))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    roots, _ = crowd.roots()
    return crowd, (roots + d * rng.uniform(1.3, 2.0, (n, 1)))[:, None].astype(np.float32)


def assert_world_pose_follows_roots(crowd):
    roots, yaw = crowd.roots()
    again = cik.Crowd(crowd.rig, n=crowd.n)
    again.set_roots(roots, yaw if crowd.dim == 3 else None)
    again.set_rotations(crowd.rotations())
    np.testing.assert_allclose(crowd.joint_positions(), again.joint_positions(), atol=2e-5)


@pytest.mark.parametrize("value", [0, 0.0, -1.0, math.nan, math.inf, "1", True, [1.0]])
def test_bad_root_weight_raises(value):
    crowd = cik.Crowd(cik.Rig.chain(3, 0.3, dim=3), n=1)
    with pytest.raises(ValueError, match="root_weight"):
        crowd.solve(crowd.effector_positions(), method="dls", root_weight=value)


@pytest.mark.parametrize("method", METHODS)
def test_a_free_root_reaches_targets_beyond_the_chain(method):
    crowd, targets = far_case(12)
    start, _ = crowd.roots()
    base = crowd.joint_positions()[:, 0]
    assert np.all(np.linalg.norm(targets[:, 0] - base, axis=1) > 1.05 * crowd.rig.reach[0])  # UNREACHABLE if fixed
    rep = crowd.solve(targets, method=method, max_iterations=100, tolerance=1e-3, root_weight=1.0)
    assert np.all(rep.converged) and not np.any(rep.status == Status.UNREACHABLE)
    moved, _ = crowd.roots()
    assert np.all(np.linalg.norm(moved - start, axis=1) > 0.05)
    np.testing.assert_allclose(rep.error, np.linalg.norm(crowd.effector_positions() - targets, axis=-1)[:, 0],
                               atol=1e-6)
    assert_world_pose_follows_roots(crowd)


@pytest.mark.parametrize("method", METHODS)
def test_a_planar_root_moves_in_its_plane(method):
    crowd, targets = far_case(6, dim=2)
    rep = crowd.solve(targets, method=method, max_iterations=100, tolerance=1e-3, root_weight=2.0)
    assert np.all(rep.converged)
    assert crowd.roots()[0].shape == (6, 2) and np.all(crowd.root_pos[:, 2] == 0.0)
    assert_world_pose_follows_roots(crowd)


def test_fabrik_and_ccd_leave_a_root_whose_targets_are_in_reach():
    crowd = cik.Crowd(cik.Rig.chain(4, 0.3, dim=3), n=5, spacing=3.0)
    roots, _ = crowd.roots()
    targets = (roots + np.array([0.3, 0.4, 0.2]))[:, None].astype(np.float32)
    for method in ("fabrik", "ccd"):
        crowd.solve(targets, method=method, root_weight=1.0)
        np.testing.assert_array_equal(crowd.roots()[0], roots)


def test_root_shift_kernel_matches_its_twin():
    h = cik.Rig.humanoid()
    n = 32
    crowd = cik.Crowd(h, n=n, spacing=2.0)
    rng = np.random.default_rng(3)
    roots, yaw = crowd.roots()
    crowd.set_roots(roots, rng.uniform(-3, 3, n).astype(np.float32))
    targets = crowd.effector_positions() + rng.normal(size=(n, 5, 3)).astype(np.float32) * 0.8
    weights = rng.uniform(0, 1, (n, 5)).astype(np.float32) * (rng.uniform(size=(n, 5)) > 0.3)
    weights[:, 0] = 1.0
    base = crowd.joint_positions()[:, 0].astype(np.float64)
    root0 = crowd.root_pos.astype(np.float64)
    crowd.solve(targets, method="fabrik", weights=weights, root_weight=0.7, max_iterations=1)
    want = shift_roots(h.reach, root0, base, targets, weights, 0.7)
    np.testing.assert_allclose(crowd.root_pos, want, atol=1e-5)
    assert np.mean(np.linalg.norm(want - root0, axis=1) > 1e-3) > 0.5


def test_dls_free_root_matches_numpy_twin_and_batch_equals_one_at_a_time():
    crowd, targets = far_case(10, seed=2)
    rig = crowd.rig
    rng = np.random.default_rng(2)
    roots, _ = crowd.roots()
    yaw = rng.uniform(-3, 3, 10).astype(np.float32)
    crowd.set_roots(roots, yaw)
    crowd.set_angles(rng.uniform(-0.5, 0.5, (10, rig.n_dof)).astype(np.float32))
    rot0 = crowd.rotations()
    rep = crowd.solve(targets, method="dls", max_iterations=60, root_weight=0.5)
    rot, pos, err, iters, _, moved = dls_solve(rig, np.c_[roots], yaw, rot0, targets, max_iterations=60,
                                               root_weight=0.5)
    agree = iters == rep.iterations
    assert np.mean(agree) >= 0.85
    np.testing.assert_allclose(crowd.roots()[0][agree], moved[agree], atol=1e-4)
    np.testing.assert_allclose(crowd.joint_positions()[agree], pos[agree], atol=1e-4)
    np.testing.assert_allclose(rep.error[agree], err[agree], atol=1e-5)
    assert_each_alone_gives_the_same_bits(rig, roots[:4], yaw[:4], targets[:4], "dls", root_weight=0.5,
                                          max_iterations=40)


def test_balance_with_a_free_root_keeps_the_feet_and_puts_the_centre_of_mass_over_them():
    # feet held where they stand, hands pulled 15-30 cm forward: with the pelvis fixed the centre of mass stays
    # ~11 cm off the feet (before issue 15 balance let the feet slide 2.2 cm instead); with a free root it moves
    h = cik.Rig.humanoid()
    n, tol = 6, 1e-3
    out = {}
    for root_weight in (None, 1.0):
        crowd = cik.Crowd(h, n=n, spacing=2.0)
        targets = crowd.effector_positions().copy()
        targets[:, 1:3, 2] += np.linspace(0.15, 0.3, n)[:, None]
        targets[:, 1:3, 1] -= 0.1
        rep = crowd.solve(targets, method="dls", weights=[0, 1, 1, 1, 1], balance_weight=1.0, max_iterations=200,
                          tolerance=tol, root_weight=root_weight)
        slide = np.linalg.norm(crowd.effector_positions()[:, 3:] - targets[:, 3:], axis=-1).max()
        com = np.linalg.norm(balance_offset(h, crowd.joint_positions().astype(np.float64))[:, [0, 2]], axis=1)
        out[root_weight] = (rep, slide, com)
    rep, slide, com = out[1.0]
    assert np.all(rep.converged) and slide <= 1.5 * tol
    assert com.max() <= 2 * tol  # (seen: 0.3 mm mean)
    assert out[None][2].min() > 0.05
