"""Small vector helpers of the game's host code: turning about the vertical, safe normalisation."""

from __future__ import annotations

import numpy as np

UP = np.array([0.0, 1.0, 0.0], np.float32)


def yaw_rotate(v: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) about +y by yaw (...) radians (+z turns toward +x)."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.empty(np.broadcast_shapes(v.shape, np.shape(yaw) + (3,)), np.float32)
    out[..., 0] = c * v[..., 0] + s * v[..., 2]
    out[..., 1] = v[..., 1]
    out[..., 2] = -s * v[..., 0] + c * v[..., 2]
    return out


def normalize(v: np.ndarray, fallback=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Unit vectors along v (..., 3) as float32; `fallback` where |v| <= 1e-9."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-9, v / np.maximum(n, 1e-9), np.asarray(fallback, v.dtype)).astype(np.float32)
