"""NumPy twin of kernels/game_kernels.py (same shapes and units)."""

from __future__ import annotations

import numpy as np


def limb_capsules(world_pos, bone_parent, bone_radius, prev_box):
    """(a (C, 3), b (C, 3), joints (N, J, 3), pose_box (N, 4), box (N, 4)) from world_pos (N, J, 3) and
    the previous pose's box prev_box (N, 4); see the kernel."""
    pos = np.asarray(world_pos, np.float32)
    n, n_bones = pos.shape[0], len(bone_parent)
    a = pos[:, bone_parent].reshape(-1, 3)
    b = pos[:, 1:].reshape(-1, 3)
    r = np.tile(np.asarray(bone_radius, np.float32), n)[:, None]
    ends = np.stack([a, b])[..., [0, 2]]
    lo = (ends - r[None]).min(axis=0).reshape(n, n_bones, 2).min(axis=1)
    hi = (ends + r[None]).max(axis=0).reshape(n, n_bones, 2).max(axis=1)
    pose_box = np.hstack([lo, hi]).astype(np.float32)
    prev = np.asarray(prev_box, np.float32)
    box = np.hstack([np.minimum(lo, prev[:, :2]), np.maximum(hi, prev[:, 2:])]).astype(np.float32)
    return a, b, pos.copy(), pose_box, box


def dodge_targets(rest_targets, lean, duck, guard, roots, yaw, planted, chest, lean_gain, duck_gain, planted_slot,
                  hands, hip_offset, humanoid, pelvis_share, max_shift, leg_reach, scale):
    """(targets (N, E, 3), roots (N, 3)) of characters holding a dodge; see the kernel."""
    rest_targets, lean, roots, planted, chest = (np.asarray(x, np.float64) for x in (rest_targets, lean, roots,
                                                                                   planted, chest))
    duck, guard, yaw = (np.asarray(x, np.float64) for x in (duck, guard, yaw))
    n = len(roots)
    down = np.zeros((n, 3))
    down[:, 1] = -duck
    targets = rest_targets + np.asarray(lean_gain)[None, :, None] * lean[:, None, :] \
        + np.asarray(duck_gain)[None, :, None] * down[:, None, :]
    roots = roots.copy()
    if humanoid:
        shift = lean * pelvis_share
        norm = np.linalg.norm(shift, axis=1, keepdims=True)
        shift *= np.minimum(1.0, max_shift * scale / np.maximum(norm, 1e-9))
        roots += shift
        roots[:, 1] -= 0.85 * duck
        wanted = roots[:, 1].copy()
        c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
        off = np.asarray(hip_offset, np.float64)[None]  # (1, 2, 3)
        hx = roots[:, None, 0] + c * off[..., 0] + s * off[..., 2]
        hz = roots[:, None, 2] - s * off[..., 0] + c * off[..., 2]
        dh2 = (hx - planted[..., 0]) ** 2 + (hz - planted[..., 2]) ** 2
        up = np.sqrt(np.maximum(leg_reach * leg_reach - dh2, (0.2 * leg_reach) ** 2))
        roots[:, 1] = np.minimum(wanted, np.min(planted[..., 1] + up - off[..., 1], axis=1))
        free = np.asarray(planted_slot) < 0
        targets[:, free, 1] += (roots[:, 1] - wanted)[:, None]
        fwd = np.stack([np.sin(yaw), np.zeros(n), np.cos(yaw)], axis=1)
        left = np.stack([np.cos(yaw), np.zeros(n), -np.sin(yaw)], axis=1)
        front = chest + lean * 0.8 + down
        g = guard[:, None]
        for e, side in zip(hands, (1.0, -1.0)):
            at = front + fwd * 0.28 * scale + left * (0.1 * side * scale) + np.array([0.0, 0.14 * scale, 0.0])
            targets[:, e] = targets[:, e] * (1.0 - g) + at * g
        slots = np.asarray(planted_slot)
        targets[:, slots >= 0] = planted[:, slots[slots >= 0]]
    return targets.astype(np.float32), roots.astype(np.float32)
