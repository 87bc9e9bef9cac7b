"""NumPy twin of kernels/rotation_goals.py (vectorised over characters, float64)."""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.quat import qrot


def turn_error(rig, wrot, weights, orient) -> np.ndarray:
    """(N,) max over effectors with an axis target of the angle between its world axis and the target."""
    q = wrot[:, rig.arrays["eff_joint"]]
    axis = np.broadcast_to(rig.arrays["eff_axis"].astype(np.float64), q.shape[:-1] + (3,))
    cos = np.clip(np.sum(qrot(q, axis) * orient, -1), -1.0, 1.0)
    has = (weights > 0) & (np.sum(orient * orient, -1) > 0)
    return np.max(np.where(has, np.arccos(cos), 0.0), axis=1)
