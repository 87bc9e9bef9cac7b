"""Swept sphere against capsules, analytic: when a moving bullet first touches a limb (NumPy, float64).

Ericson, Real-Time Collision Detection, 5.3.7: a segment against a cylinder and spheres. The game's
player-versus-shooter hits use it, and it is the independent oracle of the kernels' cutting-plane +
Newton search (crowd_ik/reference/projectiles.py).
"""

from __future__ import annotations

import numpy as np


def point_segment_distance(p, a, b):
    """Distance from points p to segments [a, b] (broadcast over leading axes)."""
    e = b - a
    ee = np.sum(e * e, axis=-1)
    u = np.where(ee > 0, np.sum((p - a) * e, axis=-1) / np.where(ee > 0, ee, 1.0), 0.0)
    return np.linalg.norm(p - (a + np.clip(u, 0.0, 1.0)[..., None] * e), axis=-1)


def _sphere_entry(p0, d, c, r):
    m = p0 - c
    A = np.sum(d * d, axis=-1)
    B = np.sum(m * d, axis=-1)
    C = np.sum(m * m, axis=-1) - r * r
    disc = B * B - A * C
    ok = (A > 0) & (disc >= 0)
    t = (-B - np.sqrt(np.where(ok, disc, 0.0))) / np.where(ok, A, 1.0)
    return np.where(ok & (t >= 0.0), t, np.inf)


def _cylinder_entry(p0, d, a, e, r):
    ee = np.sum(e * e, axis=-1)
    safe = np.where(ee > 0, ee, 1.0)[..., None]
    m = p0 - a
    mp = m - np.sum(m * e, axis=-1)[..., None] / safe * e
    dp = d - np.sum(d * e, axis=-1)[..., None] / safe * e
    A = np.sum(dp * dp, axis=-1)
    B = np.sum(mp * dp, axis=-1)
    C = np.sum(mp * mp, axis=-1) - r * r
    disc = B * B - A * C
    ok = (ee > 0) & (A > 0) & (C > 0) & (disc >= 0)
    t = (-B - np.sqrt(np.where(ok, disc, 0.0))) / np.where(ok, A, 1.0)
    u = np.sum((m + t[..., None] * d) * e, axis=-1) / safe[..., 0]
    return np.where(ok & (t >= 0.0) & (u >= 0.0) & (u <= 1.0), t, np.inf)


def sweep_toi(p0, p1, a, b, r):
    """Smallest t in [0, 1] with dist(p0 + t (p1 - p0), [a, b]) <= r, else -1 (broadcast, analytic).

    The capsule is the union of its lateral cylinder and its two end spheres; a point starting
    outside enters the union when it first enters one of them: the smaller root of each quadratic.
    """
    p0, p1, a, b, r = (np.asarray(x, np.float64) for x in (p0, p1, a, b, r))
    d = p1 - p0
    t = np.minimum(np.minimum(_sphere_entry(p0, d, a, r), _sphere_entry(p0, d, b, r)),
                   _cylinder_entry(p0, d, a, b - a, r))
    t = np.where(t <= 1.0, t, -1.0)
    return np.where(point_segment_distance(p0, a, b) <= r, 0.0, t)
