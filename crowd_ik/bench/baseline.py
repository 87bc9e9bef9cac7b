"""The bench's NumPy baseline: the vectorised twins of crowd_ik/reference/ on a growing subset of a
workload, within a time budget per cell."""

from __future__ import annotations

import time

import numpy as np

from crowd_ik.bench.options import BASELINE_PROBE
from crowd_ik.bench.workloads import _outcome, _reachable, make_workload

# ------------------------------------------------------------------------------------------------ NumPy baseline

def _reference_solver(solver: str):
    """The NumPy twin of `solver` as f(rig, root_pos, root_yaw, rot, targets, weights, orient, max_iterations,
    tolerance) -> (error, iterations); None when crowd_ik/reference has no twin for it."""
    import importlib

    try:
        module = importlib.import_module(f"crowd_ik.reference.{solver}")
    except ImportError:
        return None
    fn = getattr(module, f"{solver}_solve", None)
    if fn is None:
        return None

    def solve(rig, root_pos, root_yaw, rot, targets, weights, max_iterations, tolerance):
        out = fn(rig, root_pos, root_yaw, rot, targets, weights, None, max_iterations=max_iterations,
                 tolerance=tolerance)
        if isinstance(out, dict):
            return np.asarray(out["error"]), np.asarray(out["iterations"])
        return np.asarray(out[2]), np.asarray(out[3])

    return solve


class Baseline:
    """Times the NumPy twins under a per-cell budget; runs on the same subset are shared between cells.

    :meth:`measure` spends a cell's budget and returns the subset size it settled on; :meth:`summary`
    reports that subset from every run made on it (by this cell or an earlier one), so cells that share
    a subset report the same numbers.
    """

    def __init__(self, repeats: int, budget: float):
        self.repeats, self.budget = repeats, budget
        self._runs: dict[tuple, list] = {}  # (rig, solver, m) -> [(seconds, outcome dict), ...]
        self._inputs: dict[tuple, tuple] = {}

    def _inputs_for(self, rig_name: str, n: int, m: int) -> tuple:
        key = (rig_name, n, m)
        if key not in self._inputs:
            self._inputs.clear()  # one subset at a time: the rotations of 100,000 characters are not small
            wl = make_workload(rig_name, n, m)
            self._inputs[key] = (wl, wl.roots.astype(np.float64), np.zeros(m), wl.rotations(),
                                 wl.targets.astype(np.float64), np.ones((m, wl.rig.n_effectors)), _reachable(wl))
        return self._inputs[key]

    def _run(self, rig_name: str, solver: str, n: int, m: int, k: int) -> float:
        """Seconds of the k-th timed run of the NumPy twin on the first m characters (cached)."""
        runs = self._runs.setdefault((rig_name, solver, m), [])
        while len(runs) <= k:
            wl, roots, yaw, rot, targets, weights, reachable = self._inputs_for(rig_name, n, m)
            fn = _reference_solver(solver)
            t0 = time.perf_counter()
            err, iters = fn(wl.rig, roots, yaw, rot, targets, weights, wl.max_iterations, wl.tolerance)
            runs.append((time.perf_counter() - t0, _outcome(err, iters, err <= wl.tolerance, reachable)))
        return runs[k][0]

    def measure(self, rig_name: str, solver: str, n: int) -> int | None:
        """Spend the budget of cell (rig, solver, n); return the subset size measured (None: no twin, or budget 0)."""
        if _reference_solver(solver) is None or self.budget <= 0:
            return None
        start = time.perf_counter()
        m = min(n, BASELINE_PROBE)
        t = self._run(rig_name, solver, n, m, 0)
        while m < n:  # grow the subset while `repeats` runs of the next size fit in what is left
            left = self.budget - (time.perf_counter() - start)
            grow = min(n, 10 * m, int(left / (self.repeats * t / m)))
            if grow < 1.25 * m:
                break
            m = grow
            t = self._run(rig_name, solver, n, m, 0)
        for k in range(1, self.repeats):
            done = self._runs[(rig_name, solver, m)]
            if len(done) <= k and (time.perf_counter() - start) + min(r[0] for r in done) > self.budget:
                break
            self._run(rig_name, solver, n, m, k)
        return m

    def summary(self, rig_name: str, solver: str, m: int) -> dict:
        """NumPy solves/s on the first m characters (best of every run on them) and that run's outcome (success among
        all and among the reachable, by the same rule as Crowd's UNREACHABLE status: workloads._reachable)."""
        runs = self._runs[(rig_name, solver, m)]
        seconds, out = min(runs, key=lambda r: r[0])
        return dict(numpy_solves_per_s=m / seconds, numpy_n=m, numpy_repeats=len(runs), numpy_time_s=seconds,
                    numpy_success_rate=out["success_rate"], numpy_reachable_rate=out["reachable_rate"],
                    numpy_success_rate_reachable=out["success_rate_reachable"], numpy_mean_error=out["mean_error"],
                    numpy_mean_iterations=out["mean_iterations"])


# ------------------------------------------------------------------------------------------------ report
