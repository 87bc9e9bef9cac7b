"""NumPy twin of kernels/game_kernels.py (same shapes and units)."""

from __future__ import annotations

import numpy as np


def limb_capsules(world_pos, bone_parent, bone_radius, prev_a, prev_b):
    """(a (C, 3), b (C, 3), joints (N, J, 3), box (N, 4)) from world_pos (N, J, 3); see the kernel."""
    pos = np.asarray(world_pos, np.float32)
    n, n_bones = pos.shape[0], len(bone_parent)
    a = pos[:, bone_parent].reshape(-1, 3)
    b = pos[:, 1:].reshape(-1, 3)
    r = np.tile(np.asarray(bone_radius, np.float32), n)[:, None]
    ends = np.stack([a, b, np.asarray(prev_a, np.float32), np.asarray(prev_b, np.float32)])[..., [0, 2]]
    lo = (ends - r[None]).min(axis=0).reshape(n, n_bones, 2).min(axis=1)
    hi = (ends + r[None]).max(axis=0).reshape(n, n_bones, 2).max(axis=1)
    return a, b, pos.copy(), np.hstack([lo, hi]).astype(np.float32)
