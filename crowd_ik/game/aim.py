"""Aiming a bullet: the ballistic launch direction to a point, and the spread cone around it."""

from __future__ import annotations

import math

import numpy as np

from crowd_ik.geometry.vectors import UP, normalize


def ballistic_direction(origin, target, speed: float, gravity: float, drag: float = 0.0) -> np.ndarray:
    """Unit launch directions (K, 3) from origin (K, 3) that reach target (K, 3) at `speed` m/s under gravity.

    Fixed-point iteration on the flight time t: aim at target + (0, g t^2 / 2, 0), t = |aim| / speed
    (the flat trajectory; the quadratic drag's extra flight time is compensated to first order:
    t_eff = t (1 + drag * speed * t / 2), drag in 1/m).
    """
    d = np.asarray(target, np.float64) - np.asarray(origin, np.float64)
    t = np.linalg.norm(d, axis=-1) / speed
    aim = d
    for _ in range(4):
        t_eff = t * (1.0 + 0.5 * drag * speed * t)
        aim = d + np.outer(0.5 * gravity * t_eff * t_eff, [0.0, 1.0, 0.0])
        t = np.linalg.norm(aim, axis=-1) / speed
    return normalize(aim.astype(np.float32))


def cone_sample(direction: np.ndarray, half_angle: float, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Directions uniformly distributed (by solid angle) in the cone of `half_angle` radians around
    each unit `direction` (K, 3), from uniforms u1, u2 (K,)."""
    d = normalize(np.asarray(direction, np.float32))
    helper = np.where(np.abs(d[:, 1:2]) < 0.9, UP, np.array([1.0, 0.0, 0.0], np.float32))
    e1 = normalize(np.cross(helper, d))
    e2 = np.cross(d, e1)
    cos_t = 1.0 - u1 * (1.0 - math.cos(half_angle))
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * math.pi * u2
    out = d * cos_t[:, None] + (e1 * np.cos(phi)[:, None] + e2 * np.sin(phi)[:, None]) * sin_t[:, None]
    return normalize(out.astype(np.float32))
