"""NumPy twin of kernels/report_rows.py statuses: Crowd's status rule for the characters of a solve."""

from __future__ import annotations

import numpy as np

from crowd_ik.crowd import Status


def statuses(error, turn, tolerance: float, rotation_tolerance: float, targets, weights, base, bound_sq, stalled,
             free_root: bool) -> np.ndarray:
    """(N,) int8: CONVERGED where error <= tolerance and turn <= rotation_tolerance (both compared in float32);
    else UNREACHABLE where a target (N, E, 3) with weight > 0 lies farther from base (N, 3) than bound_sq (E,)
    (Rig.beyond_reach) and the roots are fixed; else STALLED where stalled != 0; else MAX_ITERATIONS."""
    error, turn = np.asarray(error, np.float32), np.asarray(turn, np.float32)
    left = (error > np.float32(tolerance)) | (turn > np.float32(rotation_tolerance))
    d = (np.asarray(targets, np.float32) - np.asarray(base, np.float32)[:, None, :]).astype(np.float64)
    far = np.any((np.einsum("nek,nek->ne", d, d) > bound_sq) & (np.asarray(weights) > 0), axis=1) & (not free_root)
    out = np.where(far, Status.UNREACHABLE, np.where(np.asarray(stalled) != 0, Status.STALLED, Status.MAX_ITERATIONS))
    return np.where(left, out, Status.CONVERGED).astype(np.int8)
