"""Host side of the kernels' joint-limit test: limits as pseudo-angles, so that "does a limit bite" needs no
trigonometry in the kernels (kernels/quat.py's constrain_rotation compares them with pseudo-angles of
rotation matrix entries). Used by Rig.arrays and the DLS solve set-up; the NumPy twins use it too.
"""

from __future__ import annotations

import numpy as np


def pseudo_angle(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A stand-in for atan2(y, x) with the same order on (-pi, pi] and range (-2, 2], without trigonometry:
    p = y / (|x| + |y|) on the right half plane, 2 - p above and -2 - p below on the left one."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    p = y / np.maximum(np.abs(x) + np.abs(y), 1e-30)
    return np.where(x < 0, np.where(y >= 0, 2.0 - p, -2.0 - p), p)


def limit_half_turns(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(D, 4) float32 cos(lo/2), sin(lo/2), cos(hi/2), sin(hi/2) of each DOF's limits (each clipped to [-pi, pi]):
    the rotation by a limit about a unit axis a is (a sin, cos), which the lane kernels use where a clamp to that
    limit bites instead of evaluating sin and cos of the clamped angle (kernels/lane_limits.py)."""
    lo = np.clip(np.asarray(lo, np.float64), -np.pi, np.pi)
    hi = np.clip(np.asarray(hi, np.float64), -np.pi, np.pi)
    out = np.stack([np.cos(0.5 * lo), np.sin(0.5 * lo), np.cos(0.5 * hi), np.sin(0.5 * hi)], axis=-1)
    return np.ascontiguousarray(out, np.float32)


def limit_pseudo_angles(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(D, 2) float32 pseudo_angle of each DOF's lower and upper limit, for the kernels' cheap "does a limit
    bite" test: -3 for a lower limit at or below -pi (it never bites), 3 for an upper one at or above pi."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    with np.errstate(invalid="ignore"):
        p_lo = np.where(lo <= -np.pi, -3.0, np.where(lo > np.pi, 3.0, pseudo_angle(np.cos(lo), np.sin(lo))))
        p_hi = np.where(hi >= np.pi, 3.0, np.where(hi < -np.pi, -3.0, pseudo_angle(np.cos(hi), np.sin(hi))))
    return np.ascontiguousarray(np.stack([p_lo, p_hi], axis=-1), np.float32)
