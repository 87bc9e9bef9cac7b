"""Sine ease-in/ease-out (Parent, "Computer Animation", sec. 3.2) and keyframe interpolation of
joint angles, as in the seeds' coursework (section 5.1, with its garbled formula corrected per
seeds/README.md).

The curve s(t), t in [0, 1]: a quarter sine accelerates from rest until t = k1, the speed is
constant until t = k2, a quarter sine decelerates to rest at t = 1; s is normalised so s(1) = 1.
Key poses are eased one segment at a time (each segment starts and stops at rest) and the angles
are interpolated linearly in s, which gives the arc-like motion the coursework describes.
"""

from __future__ import annotations

import numbers
import os

import numpy as np

__all__ = ["ease", "ease_velocity", "interpolate_keyframes", "load_keyframes"]

_HALF_PI = 0.5 * np.pi


def _check_ks(k1, k2) -> tuple[float, float]:
    for name, k in (("k1", k1), ("k2", k2)):
        if isinstance(k, bool) or not isinstance(k, numbers.Real) or not np.isfinite(k):
            raise ValueError(f"{name}: expected a finite number in [0, 1] (got {k!r})")
    if not 0.0 <= k1 <= k2 <= 1.0:
        raise ValueError(f"k1, k2: expected 0 <= k1 <= k2 <= 1 (got k1={k1!r}, k2={k2!r})")
    return float(k1), float(k2)


def _check_t(t) -> np.ndarray:
    try:
        a = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"t: expected numbers in [0, 1] (got {t!r})") from None
    if not np.isfinite(a).all() or (a < 0).any() or (a > 1).any():
        raise ValueError(f"t: expected numbers in [0, 1] (got {t!r})")
    return a


def _ease(t: np.ndarray, k1: float, k2: float) -> np.ndarray:
    # Parent's piecewise curve (seeds/README.md), before normalisation by
    # f = 2 k1/pi + (k2 - k1) + 2 (1 - k2)/pi:
    #   t <= k1:      k1 (2/pi) (sin(t/k1 pi/2 - pi/2) + 1)
    #   k1..k2:       2 k1/pi + t - k1
    #   t >= k2:      2 k1/pi + k2 - k1 + (1 - k2)(2/pi) sin((t - k2)/(1 - k2) pi/2)
    # An empty piece (k1 = 0 or k2 = 1) is never evaluated, so nothing divides by zero.
    f = 2 * k1 / np.pi + (k2 - k1) + 2 * (1 - k2) / np.pi
    s = 2 * k1 / np.pi + t - k1
    lo, hi = t < k1, t > k2
    if lo.any():
        s[lo] = k1 * (2 / np.pi) * (np.sin(t[lo] / k1 * _HALF_PI - _HALF_PI) + 1)
    if hi.any():
        s[hi] = 2 * k1 / np.pi + k2 - k1 + (1 - k2) * (2 / np.pi) * np.sin((t[hi] - k2) / (1 - k2) * _HALF_PI)
    return s / f


def ease(t, k1: float = 0.2, k2: float = 0.75):
    """Eased distance s(t) in [0, 1] for t in [0, 1] (scalar or array): s(0) = 0, s(1) = 1."""
    k1, k2 = _check_ks(k1, k2)
    a = _check_t(t)
    s = _ease(np.atleast_1d(a), k1, k2)
    return s.reshape(a.shape) if a.ndim else float(s[0])


def ease_velocity(t, k1: float = 0.2, k2: float = 0.75):
    """ds/dt, analytic: cos(t/k1 pi/2 - pi/2)/f, then 1/f, then cos((t-k2)/(1-k2) pi/2)/f.

    Zero at t = 0 (when k1 > 0) and t = 1 (when k2 < 1); continuous at k1 and k2, where it is 1/f.
    """
    k1, k2 = _check_ks(k1, k2)
    a = _check_t(t)
    t1 = np.atleast_1d(a)
    f = 2 * k1 / np.pi + (k2 - k1) + 2 * (1 - k2) / np.pi
    v = np.ones_like(t1)
    lo, hi = t1 < k1, t1 > k2
    if lo.any():
        v[lo] = np.cos(t1[lo] / k1 * _HALF_PI - _HALF_PI)
    if hi.any():
        v[hi] = np.cos((t1[hi] - k2) / (1 - k2) * _HALF_PI)
    v /= f
    return v.reshape(a.shape) if a.ndim else float(v[0])


def interpolate_keyframes(durations, poses, fps: float = 30.0, k1: float = 0.2, k2: float = 0.75) -> np.ndarray:
    """Joint angles at every frame, (frames, n) float64, easing from key pose to key pose.

    poses: (K, n) radians. durations: (K,) seconds; durations[i] (i >= 1, > 0) is the time to go
    from pose i-1 to pose i; durations[0] (>= 0) is a hold on pose 0 before the first move. Frame j
    is at time j/fps; the clip has ceil(total*fps) + 1 frames, the last clamped to the total time,
    so row 0 is pose 0 and the last row is exactly the last pose.
    """
    k1, k2 = _check_ks(k1, k2)
    if isinstance(fps, bool) or not isinstance(fps, numbers.Real) or not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps: expected a positive finite number (got {fps!r})")
    try:
        d = np.asarray(durations, dtype=np.float64)
        p = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"durations, poses: expected numbers (got {durations!r}, {poses!r})") from None
    if p.ndim != 2 or p.shape[0] < 1:
        raise ValueError(f"poses: expected shape (K, n) with K >= 1 (got shape {p.shape})")
    if d.shape != (p.shape[0],):
        raise ValueError(f"durations: expected shape ({p.shape[0]},), one per pose (got shape {d.shape})")
    if not np.isfinite(d).all() or not np.isfinite(p).all():
        raise ValueError(f"durations, poses: expected finite numbers (got {durations!r}, {poses!r})")
    if d[0] < 0 or (d[1:] <= 0).any():
        raise ValueError(f"durations: expected durations[0] >= 0 and the rest > 0 (got {d.tolist()!r})")

    ends = np.cumsum(d)  # ends[i]: time pose i is reached (ends[0]: end of the hold)
    total = float(ends[-1])
    frames = int(np.ceil(total * fps - 1e-9)) + 1
    times = np.minimum(np.arange(frames) / fps, total)
    if p.shape[0] == 1:
        return np.repeat(p, frames, axis=0)
    # segment i (1..K-1) covers (ends[i-1], ends[i]]; times within the hold map to segment 1 at u=0
    seg = np.clip(np.searchsorted(ends, times, side="left"), 1, p.shape[0] - 1)
    u = np.clip((times - ends[seg - 1]) / d[seg], 0.0, 1.0)
    snap = 1e-9  # seconds: a frame this close to a key time is on it (j/fps and sums of durations round)
    u[np.abs(times - ends[seg]) <= snap] = 1.0
    u[np.abs(times - ends[seg - 1]) <= snap] = 0.0
    s = _ease(u, k1, k2)[:, None]
    out = p[seg - 1] + s * (p[seg] - p[seg - 1])
    # frames on a key time carry that key pose exactly (no rounding in a + 1*(b - a))
    return np.where(u[:, None] >= 1.0, p[seg], np.where(u[:, None] <= 0.0, p[seg - 1], out))


def load_keyframes(path) -> tuple[np.ndarray, np.ndarray]:
    """Read key poses from a CSV: header ``duration_s,theta1,...,thetaN``, then one row per key
    pose, angles in degrees. Blank lines and lines starting with '#' are skipped.

    Returns (durations (K,) seconds, poses (K, N) radians). Problems raise
    ValueError("path:LINE: problem (got value)"); a missing file raises FileNotFoundError.
    """
    from crowd_ik.io.csv_table import finite, read_table

    path = os.fspath(path)

    def is_header(fields: list[str]) -> bool:
        return len(fields) >= 2 and fields == ["duration_s"] + [f"theta{i}" for i in range(1, len(fields))]

    table = read_table(path, is_header, "duration_s,theta1,...,thetaN", what="key pose")
    values = np.empty((len(table.rows), len(table.header)))
    for k, (number, fields) in enumerate(table.rows):
        values[k] = [finite(path, number, name, f) for name, f in zip(table.header, fields)]
        dur = values[k, 0]
        if (k == 0 and dur < 0) or (k > 0 and dur <= 0):
            need = ">= 0 (a hold)" if k == 0 else "> 0"
            raise ValueError(f"{path}:{number}: duration_s: expected {need} (got {fields[0]!r})")
    return values[:, 0].copy(), np.radians(values[:, 1:])
