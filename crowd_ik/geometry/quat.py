"""NumPy twins of kernels/quat.py: quaternions (x, y, z, w) and joint rotations, vectorised over leading axes."""

from __future__ import annotations

import numpy as np

from crowd_ik.solvers.limits import limit_pseudo_angles, pseudo_angle  # noqa: F401  (the twins' too)
from crowd_ik.solvers.settings import CONE_BOX_STEPS, GIMBAL  # GIMBAL: |R02| from which XYZ is gimbal-locked


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    av, aw = a[..., :3], a[..., 3:]
    bv, bw = b[..., :3], b[..., 3:]
    v = aw * bv + bw * av + np.cross(av, bv)
    w = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    return np.concatenate([v, w], axis=-1)


def qconj(q: np.ndarray) -> np.ndarray:
    return q * np.array([-1.0, -1.0, -1.0, 1.0], dtype=q.dtype)


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    u, w = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    angle = np.asarray(angle)[..., None]
    return np.concatenate([np.asarray(axis) * np.sin(0.5 * angle), np.cos(0.5 * angle) * np.ones_like(angle)], -1)


def euler_xyz_to_quat(a: np.ndarray) -> np.ndarray:
    """a (..., 3) intrinsic XYZ angles -> (..., 4)."""
    ex, ey, ez = np.eye(3)
    return qmul(qmul(axis_angle(ex, a[..., 0]), axis_angle(ey, a[..., 1])), axis_angle(ez, a[..., 2]))



def quat_to_euler_xyz(q: np.ndarray) -> np.ndarray:
    x, y, z, w = np.moveaxis(q, -1, 0)
    r02 = 2 * (x * z + y * w)
    r12 = 2 * (y * z - x * w)
    r22 = 1 - 2 * (x * x + y * y)
    r01 = 2 * (x * y - z * w)
    r00 = 1 - 2 * (y * y + z * z)
    r21 = 2 * (y * z + x * w)
    r11 = 1 - 2 * (x * x + z * z)
    b = np.arcsin(np.clip(r02, -1, 1))
    lock = np.abs(r02) >= GIMBAL
    a = np.where(lock, np.arctan2(r21, r11), np.arctan2(-r12, r22))
    c = np.where(lock, 0.0, np.arctan2(-r01, r00))
    return np.stack([a, b, c], axis=-1)


def wrap_angle(t: np.ndarray) -> np.ndarray:
    return t - 2 * np.pi * np.floor((t + np.pi) / (2 * np.pi))


def twist_angle(q: np.ndarray, axis: np.ndarray) -> np.ndarray:
    return wrap_angle(2 * np.arctan2(np.sum(q[..., :3] * axis, axis=-1), q[..., 3]))


def joint_quat(kind: int, axes: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Local rotation (..., 4) of a joint of `kind` (DOF count) from its angles a (..., kind)."""
    shape = a.shape[:-1]
    if kind == 0:
        return np.broadcast_to(np.array([0.0, 0.0, 0.0, 1.0]), shape + (4,)).copy()
    if kind == 1:
        return axis_angle(axes[0], a[..., 0])
    if kind == 2:
        return qmul(axis_angle(axes[0], a[..., 0]), axis_angle(axes[1], a[..., 1]))
    return euler_xyz_to_quat(a)


def joint_angles(kind: int, axes: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angles (..., kind) of a joint's local rotation q (..., 4)."""
    if kind == 0:
        return np.zeros(q.shape[:-1] + (0,))
    if kind == 1:
        return twist_angle(q, axes[0])[..., None]
    if kind == 2:
        v = qrot(q, np.broadcast_to(axes[1], q.shape[:-1] + (3,)))
        t0 = np.arctan2(np.sum(axes[0] * np.cross(axes[1], v), -1), np.sum(axes[1] * v, -1))
        rest = qmul(qconj(axis_angle(axes[0], t0)), q)
        return np.stack([t0, twist_angle(rest, axes[1])], -1)
    return quat_to_euler_xyz(q)


def qnormalize(q: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    ident = np.zeros_like(q)
    ident[..., 3] = 1.0
    return np.where(n > 1e-12, q / np.maximum(n, 1e-30), ident)


def safe_normalize(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-9, v / np.maximum(n, 1e-30), fallback)


def swing(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Minimal rotation (..., 4) taking unit u to unit v."""
    d = np.sum(u * v, axis=-1, keepdims=True)
    c = np.cross(u, v)
    q = qnormalize(np.concatenate([c, 1.0 + d], -1))
    axis = np.cross(u, np.array([1.0, 0.0, 0.0]))
    alt = np.cross(u, np.array([0.0, 1.0, 0.0]))
    axis = np.where(np.sum(axis * axis, -1, keepdims=True) < 1e-8, alt, axis)
    axis = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-30)
    flip = np.concatenate([axis, np.zeros_like(d)], -1)
    return np.where(d < -0.999999, flip, q)


def constrain_rotation(kind: int, axes: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                       cone: float, bone: np.ndarray) -> np.ndarray:
    """Twin of quat.constrain_rotation for one joint over (N, 4) rotations; lo/hi are that joint's (kind,) limits."""
    if kind == 0:
        return q
    if kind in (1, 2):
        a = np.clip(joint_angles(kind, axes, q), lo, hi)
        return joint_quat(kind, axes, a)
    out = q
    if cone > 0 and np.dot(bone, bone) > 0:
        cur = qrot(out, np.broadcast_to(bone, out.shape[:-1] + (3,)))
        ang = np.arccos(np.clip(np.sum(cur * bone, -1), -1, 1))
        axis = safe_normalize(np.cross(cur, bone), np.array([0.0, 0.0, 1.0]))
        back = qmul(axis_angle(axis, np.maximum(ang - cone, 0.0)), out)
        out = np.where((ang > cone)[..., None], back, out)
    if np.any(lo > -1e29) or np.any(hi < 1e29):
        a = quat_to_euler_xyz(out)
        c = np.clip(a, lo, hi)
        rebuilt = euler_xyz_to_quat(c)
        if cone > 0 and np.dot(bone, bone) > 0:
            rebuilt = cone_within_box(rebuilt, c, lo, hi, cone, bone)
        out = np.where(np.any(c != a, axis=-1, keepdims=True), rebuilt, out)
    return out


def cone_within_box(q: np.ndarray, c: np.ndarray, lo, hi, cone: float, bone: np.ndarray) -> np.ndarray:
    """Twin of quat.cone_within_box over (N, 4) rotations q of box-clamped angles c (N, 3); bone (3,) or (N, 3)."""
    bone = np.broadcast_to(bone, q.shape[:-1] + (3,))
    cos_cone = np.cos(cone)
    outside = np.sum(qrot(q, bone) * bone, -1) < cos_cone
    z = np.clip(np.zeros(3), lo, hi)
    t0, t1 = np.zeros(c.shape[:-1]), np.ones(c.shape[:-1])
    for _ in range(CONE_BOX_STEPS):
        t = 0.5 * (t0 + t1)
        inside = np.sum(qrot(euler_xyz_to_quat(z + t[..., None] * (c - z)), bone) * bone, -1) >= cos_cone
        t0, t1 = np.where(inside, t, t0), np.where(inside, t1, t)
    return np.where(outside[..., None], euler_xyz_to_quat(z + t0[..., None] * (c - z)), q)


def best_angle_about(axis: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    up = u - np.sum(u * axis, -1, keepdims=True) * axis
    vp = v - np.sum(v * axis, -1, keepdims=True) * axis
    return np.arctan2(np.sum(axis * np.cross(up, vp), -1), np.sum(up * vp, -1))


def align_axis(kind: int, axes: np.ndarray, q: np.ndarray, u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Twin of quat.align_axis over (N, 4) rotations; u (3,) local direction, t (N, 3) target in the parent frame."""
    u = np.broadcast_to(u, q.shape[:-1] + (3,))
    if kind == 3:
        cur = qrot(q, u)
        return qnormalize(qmul(swing(cur / np.linalg.norm(cur, axis=-1, keepdims=True), t), q))
    if kind == 1:
        return qnormalize(qmul(axis_angle(axes[0], best_angle_about(axes[0], qrot(q, u), t)), q))
    if kind == 2:
        a = joint_angles(2, axes, q)
        for _ in range(4):
            a0 = best_angle_about(axes[0], qrot(axis_angle(axes[1], a[..., 1]), u), t)
            a1 = best_angle_about(axes[1], u, qrot(axis_angle(axes[0], -a0), t))
            a = np.stack([a0, a1], -1)
        return joint_quat(2, axes, a)
    return q
