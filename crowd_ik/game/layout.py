"""Where everybody stands at the start: the characters' layout and the shooters' places."""

from __future__ import annotations

import math

import numpy as np

from crowd_ik.game import streams
from crowd_ik.scene import Scene

def character_layout(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Roots (N, 3) on the ground and yaw (N,) of the characters: grid facing +z, ring facing the
    centre, random = a jittered grid (seeded) facing +z within +-60 degrees."""
    from crowd_ik.crowd import grid_positions

    c = scene.characters
    n, sp = c.count, c.spacing
    idx = np.arange(n)
    if c.layout == "ring":
        radius = max(sp * n / (2.0 * math.pi), sp)
        theta = 2.0 * math.pi * idx / n
        roots = np.stack([radius * np.sin(theta), np.zeros(n), radius * np.cos(theta)], axis=1)
        yaw = theta + math.pi
    else:
        roots = grid_positions(n, sp, 3).astype(np.float64)
        yaw = np.zeros(n)
        if c.layout == "random":
            jx = streams.rand(scene.seed, streams.LAYOUT, idx, 0) - 0.5
            jz = streams.rand(scene.seed, streams.LAYOUT, idx, 1) - 0.5
            roots[:, 0] += 0.5 * sp * jx
            roots[:, 2] += 0.5 * sp * jz
            yaw = (streams.rand(scene.seed, streams.LAYOUT, idx, 2) - 0.5) * (2.0 * math.pi / 3.0)
    return roots.astype(np.float32), yaw.astype(np.float32)


def shooter_layout(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Roots (S, 3) on the ground and yaw (S,) of the shooters, facing the centre (a ring) or +z (a line).

    ring: S places on a circle of shooters.radius, the first at angle pi / S (half a spacing from
    +z), so that no shooter stands on the axis the default camera looks along; line: 2 m apart at
    z = -radius. The layout depends on the scene alone, not on the camera.
    """
    s = scene.shooters
    k = np.arange(s.count)
    if s.placement == "line":
        roots = np.stack([(k - (s.count - 1) / 2.0) * 2.0, np.zeros(s.count), np.full(s.count, -s.radius)], axis=1)
        return roots.astype(np.float32), np.zeros(s.count, np.float32)
    theta = 2.0 * math.pi * (k + 0.5) / s.count
    roots = np.stack([s.radius * np.sin(theta), np.zeros(s.count), s.radius * np.cos(theta)], axis=1)
    return roots.astype(np.float32), (theta + math.pi).astype(np.float32)
