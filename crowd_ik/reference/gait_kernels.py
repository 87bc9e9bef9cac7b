"""NumPy twin of kernels/gait_kernels.py (same shapes and units), written for clarity."""

from __future__ import annotations

import numpy as np

from crowd_ik.analytic import two_bone
from crowd_ik.geometry.quat import axis_angle, qconj, qmul, qrot

X = np.array([1.0, 0.0, 0.0])
Z = np.array([0.0, 0.0, 1.0])
UP = np.array([0.0, 1.0, 0.0])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _matrix_quat(m: np.ndarray) -> np.ndarray:
    """(K, 4) unit quaternions (x, y, z, w) of rotation matrices m (K, 3, 3) (Shepperd's method)."""
    out = np.zeros((len(m), 4))
    for k, r in enumerate(m):
        tr = np.trace(r)
        if tr > 0.0:
            s = np.sqrt(tr + 1.0) * 2.0
            q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
        elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
            s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2.0
            q = [0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s]
        elif r[1, 1] > r[2, 2]:
            s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2.0
            q = [(r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s]
        else:
            s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2.0
            q = [(r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s, (r[1, 0] - r[0, 1]) / s]
        out[k] = np.asarray(q) / np.linalg.norm(q)
    return out


def plant_legs(world_pos, world_rot, local_rot, offset, legs, feet, yaw, active):
    """(world_pos, world_rot, local_rot) after putting the active characters' ankles on feet (N, 2, 3); see the
    kernel. The knee comes from crowd_ik.analytic.two_bone with the character's forward as the pole."""
    wp, wr, lr = (np.array(a, np.float64) for a in (world_pos, world_rot, local_rot))
    offset = np.asarray(offset, np.float64)
    n = np.flatnonzero(np.asarray(active) != 0)
    if n.size == 0:
        return wp.astype(np.float32), wr.astype(np.float32), lr.astype(np.float32)
    yaw = np.asarray(yaw, np.float64)[n]
    fwd = np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], axis=1)
    for side in range(2):
        hip, knee, ankle, toe = (int(j) for j in legs[side])
        l1, l2 = np.linalg.norm(offset[knee]), np.linalg.norm(offset[ankle])
        h = wp[n, hip]
        target = np.asarray(feet, np.float64)[n, side]
        # the kernel keeps the hip-target distance a hair above |l1 - l2| (a folded leg has no bend plane)
        solved = two_bone(l1, l2, target, fwd, root=h)
        k = solved.mid
        y_h = _unit(h - k)
        u = _unit(target - h)
        w = _unit(fwd - np.sum(fwd * u, axis=1, keepdims=True) * u)
        z_h = _unit(w - np.sum(w * y_h, axis=1, keepdims=True) * y_h)
        x_h = np.cross(y_h, z_h)
        q_hip = _matrix_quat(np.stack([x_h, y_h, z_h], axis=2))
        q_knee_local = axis_angle(X, solved.bend)
        q_knee = qmul(q_hip, q_knee_local)
        up = qrot(qconj(q_knee), np.broadcast_to(UP, q_knee.shape[:-1] + (3,)))
        a = np.arctan2(up[:, 2], up[:, 1])
        b = -np.arcsin(np.clip(up[:, 0], -1.0, 1.0))
        q_ankle_local = qmul(axis_angle(X, a), axis_angle(Z, b))
        q_ankle = qmul(q_knee, q_ankle_local)
        p_knee = h + qrot(q_hip, np.broadcast_to(offset[knee], h.shape))
        p_ankle = p_knee + qrot(q_knee, np.broadcast_to(offset[ankle], h.shape))
        lr[n, hip] = qmul(qconj(wr[n, 0]), q_hip)
        lr[n, knee] = q_knee_local
        lr[n, ankle] = q_ankle_local
        wr[n, hip], wr[n, knee], wr[n, ankle] = q_hip, q_knee, q_ankle
        wr[n, toe] = qmul(q_ankle, lr[n, toe])
        wp[n, knee], wp[n, ankle] = p_knee, p_ankle
        wp[n, toe] = p_ankle + qrot(q_ankle, np.broadcast_to(offset[toe], h.shape))
    return wp.astype(np.float32), wr.astype(np.float32), lr.astype(np.float32)


def separate(points, radius, kind, reach):
    """(steer (M, 2), push (M, 2)) of the separation kernel, by brute force over every pair (no grid)."""
    p = np.asarray(points, np.float64)
    r = np.asarray(radius, np.float64)
    kind = np.asarray(kind)
    m = len(p)
    d = p[:, None, :] - p[None, :, :]  # (M, M, 2): from j to i
    dist = np.linalg.norm(d, axis=2)
    i_idx, j_idx = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    a = 2.4 * np.minimum(i_idx, j_idx)
    sign = np.where(i_idx > j_idx, -1.0, 1.0)[..., None]
    fallback = sign * np.stack([np.cos(a), np.sin(a)], axis=2)
    unit = np.where((dist > 1e-6)[..., None], d / np.maximum(dist, 1e-6)[..., None], fallback)
    pair = (i_idx != j_idx) & (kind[:, None] == 1) & (kind[None, :] != 0)
    near = pair & (dist < reach)
    steer = np.sum(unit * np.where(near, 1.0 - dist / reach, 0.0)[..., None], axis=1)
    limit = r[:, None] + r[None, :]
    share = np.where(kind[None, :] == 2, 1.0, 0.5)
    over = pair & (dist < limit)
    push = np.sum(unit * np.where(over, (limit - dist) * share, 0.0)[..., None], axis=1)
    return steer.astype(np.float32), push.astype(np.float32)
