"""Errors a SolveReport gives from the final pose, measured on the host alike for every method."""

from __future__ import annotations

import numpy as np

_UNIT_AXES: dict = {}  # id(eff_axis) -> (eff_axis, its rows as float64 unit vectors); one entry per rig seen


def _unit_axes(eff_axis: np.ndarray) -> np.ndarray:
    """eff_axis (E, 3) as float64 unit rows (zero rows stay zero), computed once per array."""
    held = _UNIT_AXES.get(id(eff_axis))
    if held is None or held[0] is not eff_axis:
        axis = eff_axis.astype(np.float64)
        held = _UNIT_AXES[id(eff_axis)] = (eff_axis, axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True),
                                                                         1e-30))
        while len(_UNIT_AXES) > 64:  # rigs come and go in tests: keep the newest
            del _UNIT_AXES[next(iter(_UNIT_AXES))]
    return held[1]


def measured(req) -> np.ndarray:
    """(E,) bool: the effectors whose rotation error counts for some character of the SolveRequest `req` (an axis
    target with weight > 0, or a rotation target with rotation weight > 0)."""
    cols = np.zeros(req.weights.shape[1], bool)
    if req.orientations is not None:
        o = req.orientations
        cols |= np.any((o[..., 0] * o[..., 0] + o[..., 1] * o[..., 1] + o[..., 2] * o[..., 2] > 0) & (req.weights > 0),
                       axis=0)
    if req.rotations is not None:
        cols |= np.any(req.rotation_weights > 0, axis=0)
    return cols


def rotation_error(rig, world_rot: np.ndarray, req) -> np.ndarray:
    """(N,) float32 radians: per character the max over its effectors with an axis (orientation) target (weight
    > 0) of the angle between the effector's world axis, q = world_rot[:, eff_joint[e]] applied to its local
    axis, and the target, and over those with a full rotation target (rotation weight > 0) of
    2 acos |<q, q_target>|; 0 for a character with none.

    world_rot (N, J, 4) float32 x y z w (Crowd.world_rotations()); req a SolveRequest.
    """
    cols = np.flatnonzero(measured(req))
    return effector_rotation_error(rig, world_rot[:, rig.arrays["eff_joint"][cols]], req, cols)


def effector_rotation_error(rig, q_eff: np.ndarray, req, cols: np.ndarray) -> np.ndarray:
    """rotation_error from q_eff (N, K, 4) float32, the world rotations of the effectors cols (K,) (ascending, at
    least those of `measured(req)`: the other effectors add nothing to the max)."""
    N = q_eff.shape[0]
    out = np.zeros(N, np.float64)
    if len(cols) == 0:
        return out.astype(np.float32)
    q = q_eff.astype(np.float64)  # (N, K, 4)
    weights = req.weights[:, cols]
    if req.orientations is not None:
        axis = _unit_axes(rig.arrays["eff_axis"])[cols]  # (K, 3) float64
        # world axis = axis + w t + u x t, t = 2 u x axis (q = (u, w)); the cross products written out per
        # component (np.cross's own operations, in its order, without its per-call axis handling)
        ux, uy, uz, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
        ax, ay, az = axis[:, 0], axis[:, 1], axis[:, 2]
        tx, ty, tz = 2.0 * (uy * az - uz * ay), 2.0 * (uz * ax - ux * az), 2.0 * (ux * ay - uy * ax)
        o = req.orientations[:, cols]
        ox, oy, oz = o[..., 0], o[..., 1], o[..., 2]
        cos = ((ax + w * tx + (uy * tz - uz * ty)) * ox + (ay + w * ty + (uz * tx - ux * tz)) * oy
               + (az + w * tz + (ux * ty - uy * tx)) * oz)
        has = (ox * ox + oy * oy + oz * oz > 0) & (weights > 0)
        np.clip(cos, -1.0, 1.0, out=cos)
        out = np.maximum(out, np.max(np.where(has, np.arccos(cos), 0.0), axis=1))
    if req.rotations is not None:  # full rotation targets: 2 acos |<q, q_target>|
        dot = np.abs(np.sum(q * req.rotations[:, cols].astype(np.float64), axis=-1))
        ang = 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))
        has = req.rotation_weights[:, cols] > 0
        out = np.maximum(out, np.max(np.where(has, ang, 0.0), axis=1))
    return out.astype(np.float32)
