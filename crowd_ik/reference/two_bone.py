"""Scalar reference for crowd_ik.analytic.two_bone: one limb at a time, with the math module only.

Derived independently of the batched version: the middle joint lies on the circle where the
sphere of radius ``upper`` about the root meets the sphere of radius ``lower`` about the (clamped)
end point; the circle's centre sits at distance (d^2 + upper^2 - lower^2) / 2d along the root-end
line and its radius is sqrt(upper^2 - that^2). The same documented tie-breaks are used for the
degenerate cases (target at the root, pole along the root-target line).
"""

from __future__ import annotations

import math


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(a):
    return math.sqrt(_dot(a, a))


def _least_aligned_perpendicular(d):
    """Unit vector perpendicular to unit d, from the coordinate axis with the smallest |d_k| (first on ties)."""
    k = min(range(3), key=lambda i: (abs(d[i]), i))
    e = tuple(1.0 if i == k else 0.0 for i in range(3))
    p = _sub(e, _scale(d, _dot(e, d)))
    return _scale(p, 1.0 / _norm(p))


def two_bone_scalar(upper: float, lower: float, target, pole, solution: int = 1, root=(0.0, 0.0, 0.0)):
    """Return (mid, end, mid_angle, root_angle, reachable) for one limb; positions as 3-tuples in root's frame."""
    root = tuple(float(v) for v in root)
    t = _sub(tuple(float(v) for v in target), root)
    pole = tuple(float(v) for v in pole)
    d = _norm(t)
    lo, hi = abs(upper - lower), upper + lower
    pole_len = _norm(pole)
    if d <= 1e-12 * hi:
        direction = _least_aligned_perpendicular(_scale(pole, 1.0 / pole_len)) if pole_len > 0 else (1.0, 0.0, 0.0)
    else:
        direction = _scale(t, 1.0 / d)
    reachable = lo * (1 - 1e-12) <= d <= hi * (1 + 1e-12)
    span = min(max(d, lo), hi)
    end = t if reachable else _scale(direction, span)

    # the bend plane's in-plane perpendicular, by Gram-Schmidt of the pole against the direction
    side = None
    if pole_len > 0:
        pole_hat = _scale(pole, 1.0 / pole_len)
        side = _sub(pole_hat, _scale(direction, _dot(pole_hat, direction)))
        if _norm(side) <= 1e-9:
            side = None
    side = _least_aligned_perpendicular(direction) if side is None else _scale(side, 1.0 / _norm(side))

    if span > 1e-12 * hi:
        along = (span * span + upper * upper - lower * lower) / (2.0 * span)
    else:
        along = 0.0
    along = max(-upper, min(upper, along))
    radius = math.sqrt(max(upper * upper - along * along, 0.0))
    mid = _add(_scale(direction, along), _scale(side, solution * radius))
    root_angle = math.atan2(radius, along)
    # interior angle at the middle joint between the bones towards the root and towards the end
    to_root = _scale(mid, -1.0)
    to_end = _sub(_scale(direction, span), mid)
    mid_angle = math.atan2(_norm(_cross(to_root, to_end)), _dot(to_root, to_end))
    return _add(mid, root), _add(end, root), mid_angle, root_angle, reachable


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
