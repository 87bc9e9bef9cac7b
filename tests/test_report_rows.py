"""kernels/report_rows.py: the status rule against its NumPy twin (crowd_ik/reference/report.py), at the
tolerances' and the reach bound's edges, serial == parallel; and a Crowd's report from it."""

import numpy as np
import pytest
from crowd_ik.kernels import report_rows
from crowd_ik.reference import report as twin

import crowd_ik as cik
from crowd_ik.crowd import Status


def _case(n=3000, E=5, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.uniform(-5, 5, (n, 3)).astype(np.float32)
    bound = rng.uniform(0.5, 1.0, E)
    bound_sq = np.square(bound)
    # distances around each bound: well inside, a float32 ulp either side of it, well outside
    scale = rng.choice([0.5, 1.0 - 1e-7, 1.0, 1.0 + 1e-7, 1.5], (n, E))
    direction = rng.normal(size=(n, E, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    targets = (base[:, None, :] + direction * (bound * scale)[..., None]).astype(np.float32)
    weights = np.where(rng.random((n, E)) < 0.3, 0.0, rng.uniform(0.1, 2.0, (n, E))).astype(np.float32)
    tol = 1e-3
    error = (tol * rng.choice([0.5, 1.0, 1.0 + 1e-6, 2.0], n)).astype(np.float32)
    turn = (1e-2 * rng.choice([0.0, 1.0, 1.5], n)).astype(np.float32)
    stalled = (rng.random(n) < 0.5).astype(np.int32)
    return error, turn, tol, 1e-2, targets, weights, base, bound_sq, stalled


def _kernel(error, turn, tol, rtol, targets, weights, base, bound_sq, stalled, free_root, serial):
    out = np.full(len(error), -1, np.int8)
    report_rows.statuses(error, turn, tol, rtol, targets, weights, base, bound_sq, stalled, int(free_root), out,
                         serial)
    return out


def test_the_kernels_codes_are_crowd_status():
    assert (report_rows.CONVERGED, report_rows.UNREACHABLE, report_rows.STALLED, report_rows.MAX_ITERATIONS) == (
        Status.CONVERGED, Status.UNREACHABLE, Status.STALLED, Status.MAX_ITERATIONS)


@pytest.mark.parametrize("free_root", [False, True])
def test_statuses_match_the_twin_serial_and_parallel(free_root):
    case = _case()
    want = twin.statuses(*case, free_root=free_root)
    assert set(np.unique(want)) == ({0, 1, 2, 3} if not free_root else {0, 2, 3})  # every branch is exercised
    for serial in (True, False):
        np.testing.assert_array_equal(_kernel(*case, free_root, serial), want)


def test_a_zero_weight_target_out_of_reach_does_not_make_a_character_unreachable():
    error, turn, tol, rtol, targets, weights, base, bound_sq, stalled = _case(n=4)
    error[:] = 1.0
    turn[:] = 0.0
    stalled[:] = 0
    targets[:] = base[:, None, :]  # every target at the root joint: reachable
    targets[:, 2] += 10.0  # effector 2 far out of reach
    weights[:] = 1.0
    weights[:2, 2] = 0.0  # ... but not weighted for the first two characters
    got = _kernel(error, turn, tol, rtol, targets, weights, base, bound_sq, stalled, False, True)
    np.testing.assert_array_equal(got, [Status.MAX_ITERATIONS, Status.MAX_ITERATIONS, Status.UNREACHABLE,
                                        Status.UNREACHABLE])


def test_crowd_report_uses_the_rule():
    cik.init(arch="cpu")
    rig = cik.Rig.chain(4, bone_length=0.25, dim=3)  # reach 1 m from the root joint
    crowd = cik.Crowd(rig, n=3, spacing=5.0)
    roots, _ = crowd.roots()
    base = crowd.joint_positions()[:, 0]
    targets = base[:, None, :] + np.array([[[0.5, 0.3, 0.0]], [[2.0, 0.0, 0.0]], [[0.0, 0.6, 0.4]]], np.float32)
    rep = crowd.solve(targets, method="fabrik", max_iterations=1, tolerance=1e-4)
    assert rep.status[1] == Status.UNREACHABLE
    assert rep.status[0] in (Status.MAX_ITERATIONS, Status.CONVERGED)
    rep = crowd.solve(targets, method="fabrik", max_iterations=50, tolerance=1e-4)
    np.testing.assert_array_equal(rep.status, [Status.CONVERGED, Status.UNREACHABLE, Status.CONVERGED])
    assert rep.status.dtype == np.int8
