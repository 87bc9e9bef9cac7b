"""game.solving.StepSolve: a request checked once and refilled in place solves exactly as Crowd.solve does, step
after step, as the targets, weights and poles change (poles going away and back, characters going down)."""

import numpy as np

import crowd_ik as cik
from crowd_ik.game.solving import StepSolve
from crowd_ik.solvers.request import check_request, refill


class _Settings:
    method, iterations, tolerance = "fabrik", 6, 0.004


def _pair(n=6):
    rig = cik.Rig.humanoid(1.75)
    crowds = [cik.Crowd(rig, n=n, seed=3) for _ in range(2)]
    return rig, crowds


def _steps(rig, crowd, seed, k=6):
    rng = np.random.default_rng(seed)
    eff = crowd.effector_positions()
    n, E = eff.shape[:2]
    orient = np.zeros((n, E, 3), np.float32)
    orient[:, 3:, 1] = 1.0
    for s in range(k):
        targets = (eff + rng.normal(0.0, 0.06, eff.shape)).astype(np.float32)
        weights = np.ones((n, E), np.float32)
        weights[: s % 3] = 0.0  # some characters down
        poles = np.full((n, E, 3), np.nan, np.float32)
        if s != 3:  # a step without any pole: the request changes form, and back
            poles[:, 1:3] = targets[:, 1:3] + np.float32([0.0, -0.3, -0.3])
        yield targets, weights, orient, poles if s != 4 else None


def test_step_solve_equals_crowd_solve_step_after_step():
    rig, (a, b) = _pair()
    step = StepSolve(b, _Settings, None)
    for targets, weights, orient, poles in _steps(rig, a, 0):
        step.orientations = orient
        want = a.solve(targets, method="fabrik", max_iterations=6, tolerance=0.004, weights=weights,
                       orientations=orient, poles=poles)
        got = step(targets, weights, poles)
        for field in ("error", "iterations", "status", "rotation_error"):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field))
        assert np.array_equal(a.rotations(), b.rotations()) and np.array_equal(a.joint_positions(), b.joint_positions())
        assert step(targets, weights, poles, report=False) is None  # the same solve again, without a report
        again = a.solve(targets, method="fabrik", max_iterations=6, tolerance=0.004, weights=weights,
                        orientations=orient, poles=poles)
        assert np.array_equal(a.world_rotations(), b.world_rotations())
        # what game.characters keeps of an unreported solve (last_iterations): the crowd's iterations buffer
        np.testing.assert_array_equal(b.buffers.iterations, again.iterations)


def test_refill_refuses_a_change_of_form():
    rig, (a, _) = _pair(2)
    E = rig.n_effectors
    t = a.effector_positions()
    poles = np.full((2, E, 3), np.nan, np.float32)
    poles[:, 1] = 0.5
    req = check_request(rig, 2, t, "fabrik", 4, 1e-3, None, None, 0, 0, None, None, 0, poles)
    req.targets, req.weights, req.poles = np.array(req.targets), np.array(req.weights), np.array(req.poles)
    w = np.ones((2, E), np.float32)
    assert not refill(req, t, w, None)  # poles gone
    assert not refill(req, t, w, np.full((2, E, 3), np.nan, np.float32))  # every row NaN: none at all
    assert not refill(req, t[:1], w[:1], poles[:1])  # another shape
    moved = t + np.float32(0.01)
    assert refill(req, moved, w, poles)
    np.testing.assert_array_equal(req.targets, moved)
