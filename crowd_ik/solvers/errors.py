"""Errors a SolveReport gives from the final pose, measured on the host alike for every method."""

from __future__ import annotations

import numpy as np


def rotation_error(rig, world_rot: np.ndarray, req) -> np.ndarray:
    """(N,) float32 radians: per character the max over its effectors with an axis (orientation) target (weight
    > 0) of the angle between the effector's world axis, q = world_rot[:, eff_joint[e]] applied to its local
    axis, and the target, and over those with a full rotation target (rotation weight > 0) of
    2 acos |<q, q_target>|; 0 for a character with none.

    world_rot (N, J, 4) float32 x y z w (Crowd.world_rotations()); req a SolveRequest.
    """
    N = world_rot.shape[0]
    out = np.zeros(N, np.float64)
    eff = rig.arrays["eff_joint"]
    q = world_rot[:, eff].astype(np.float64)  # (N, E, 4)
    if req.orientations is not None:
        axis = rig.arrays["eff_axis"].astype(np.float64)  # (E, 3)
        axis = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-30)
        u, w = q[..., :3], q[..., 3:]
        t = 2.0 * np.cross(u, np.broadcast_to(axis, u.shape))
        world_axis = axis + w * t + np.cross(u, t)
        has = (np.sum(req.orientations * req.orientations, axis=-1) > 0) & (req.weights > 0)
        cos = np.clip(np.sum(world_axis * req.orientations, axis=-1), -1.0, 1.0)
        out = np.maximum(out, np.max(np.where(has, np.arccos(cos), 0.0), axis=1))
    if req.rotations is not None:  # full rotation targets: 2 acos |<q, q_target>|
        dot = np.abs(np.sum(q * req.rotations.astype(np.float64), axis=-1))
        ang = 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))
        has = req.rotation_weights > 0
        out = np.maximum(out, np.max(np.where(has, ang, 0.0), axis=1))
    return out.astype(np.float32)
