"""StepSolve: one crowd's IK solve as the game asks it every world step, its arguments checked once.

The game builds its targets, weights and poles itself (finite by construction), in arrays of the same shapes
every step, with the same solver settings and constant orientation targets. Crowd.solve would check and
normalise all of them again each step (a few hundred microseconds at 40 characters); a StepSolve checks them
the first time (solvers.request.check_request, as Crowd.solve does), then refills that request in place
(solvers.request.refill) and solves it (Crowd.solve_request). Whenever the request's form changes (poles
given or not) it checks again. The solve is the one Crowd.solve gives (tests/test_game_solving.py).
"""

from __future__ import annotations

import numpy as np

from crowd_ik.solvers.request import check_request, refill


class StepSolve:
    """Solves of `crowd` with the scene's solver settings `sv` (method, iterations, tolerance) and the constant
    orientation targets `orientations` (N, E, 3) (or None)."""

    def __init__(self, crowd, sv, orientations: np.ndarray | None):
        self.crowd = crowd
        self.settings = (sv.method, sv.iterations, sv.tolerance)
        self.orientations = orientations
        self.request = None

    def __call__(self, targets: np.ndarray, weights: np.ndarray, poles: np.ndarray | None = None,
                 report: bool = True):
        """Solve toward targets (N, E, 3) with weights (N, E) and poles (N, E, 3) or None; returns the
        SolveReport (None with report=False)."""
        req = self.request
        if req is None or not refill(req, targets, weights, poles):
            c = self.crowd
            method, iterations, tolerance = self.settings
            req = check_request(c.rig, c.n, targets, method, iterations, tolerance, weights, self.orientations,
                                0.0, 0.0, None, None, 0.0, poles)
            # the request's own arrays (check_request may hand back read-only views of the caller's), refilled
            # from then on
            req.targets, req.weights = np.array(req.targets), np.array(req.weights)
            if req.poles is not None:
                req.poles = np.array(req.poles)
            self.request = req
        return self.crowd.solve_request(req, report=report)
