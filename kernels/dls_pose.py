"""DLS kernel helpers on one character's pose: quaternion log/exp, swings, FK relative to the root,
the angles a pose stands for, and the per-character scratch slots the solver uses (kernels/dls.py)."""

import taichi as ti

from crowd_ik.kernels.quat import (
    joint_angles, qmul, qnormalize, qrot, yaw_quat, vec3, vec4,
)

ndarray = ti.types.ndarray

# Slots of the per-DOF scratch work[i, slot, d] and of the per-joint quaternion scratch qwork[i, slot, j].
# Z, HB0, HB1: the null-space rule's secondary step and its two projected balance rows (kernels/dls_system.py).
# With a free root (extra bit 4) the last 3 columns of work are the root's translation from where the solve
# started (THETA) and its step (STEP), after the DOFs and one padding column.
THETA, THETA_BAK, THETA0, MP, MG, STEP, FREE, G, THETA_SAVE, Z, HB0, HB1 = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11
Q_BAK, Q_START, Q_SAVE, Q_COM = 0, 1, 2, 3
N_DOF_SLOTS = 12
N_Q_SLOTS = 4
vec5 = ti.types.vector(5, ti.f32)


@ti.func
def qlog(q):
    """Rotation vector (axis * angle, angle in [0, pi]) of a unit quaternion."""
    p = q
    if p.w < 0.0:
        p = -p
    v = p.xyz
    s = v.norm()
    out = 2.0 * v
    if s > 1e-7:
        out = v * (2.0 * ti.atan2(s, p.w) / s)
    return out


@ti.func
def qexp(r):
    """Unit quaternion of the rotation vector r."""
    a = r.norm()
    out = vec4(0.5 * r.x, 0.5 * r.y, 0.5 * r.z, 1.0)
    if a > 1e-7:
        s = ti.sin(0.5 * a) / a
        out = vec4(r.x * s, r.y * s, r.z * s, ti.cos(0.5 * a))
    return qnormalize(out)


@ti.func
def perpendicular(a):
    """A unit vector perpendicular to the unit vector a."""
    u = ti.math.cross(a, vec3(1.0, 0.0, 0.0))
    if u.norm_sqr() < 0.01:
        u = ti.math.cross(a, vec3(0.0, 1.0, 0.0))
    return u.normalized()


@ti.func
def swing_vector(a, t):
    """Rotation vector of the minimal rotation taking unit a to unit t."""
    c = ti.math.cross(a, t)
    s = c.norm()
    ang = ti.atan2(s, a.dot(t))
    axis = vec3(0.0)
    if s > 1e-7:
        axis = c / s
    elif a.dot(t) < 0.0:
        axis = perpendicular(a)
    return axis * ang


@ti.func
def parent_rot(i, j, parent: ti.template(), root_yaw: ti.template(), world_rot: ti.template()):
    out = yaw_quat(root_yaw[i])
    if parent[j] >= 0:
        out = world_rot[i, parent[j]]
    return out


@ti.func
def first_bone(j, offset: ti.template(), child_start: ti.template(), child_list: ti.template()):
    """Unit direction of joint j's first child bone (zero for a leaf): the bone a cone limit applies to."""
    out = vec3(0.0)
    if child_start[j] < child_start[j + 1]:
        out = offset[child_list[child_start[j]]].normalized()
    return out


@ti.func
def fk_relative(i, parent: ti.template(), offset: ti.template(), root_yaw: ti.template(), local_rot: ti.template(),
                rel_pos: ti.template(), world_rot: ti.template()):
    """Joint positions relative to the character's root point (so a batch equals one-at-a-time) and world rotations."""
    q_root = yaw_quat(root_yaw[i])
    for j in range(parent.shape[0]):
        p = parent[j]
        base_pos = vec3(0.0)
        base_rot = q_root
        if p >= 0:
            base_pos = rel_pos[i, p]
            base_rot = world_rot[i, p]
        rel_pos[i, j] = base_pos + qrot(base_rot, offset[j])
        world_rot[i, j] = qmul(base_rot, local_rot[i, j])


@ti.func
def read_angles(i, parent: ti.template(), kind: ti.template(), jmode: ti.template(), axes: ti.template(),
                dof_start: ti.template(), local_rot: ti.template(), work: ti.template()):
    """Start state: the angles of angle-mode joints from their rotations, and a zero step."""
    for d in range(work.shape[2]):
        work[i, THETA, d] = 0.0
        work[i, STEP, d] = 0.0
    for j in range(parent.shape[0]):
        k = kind[j]
        s = dof_start[j]
        if jmode[j] == 1:
            a = joint_angles(k, axes[j, 0], axes[j, 1], local_rot[i, j])
            for c in range(k):
                work[i, THETA, s + c] = a[c]


@ti.func
def has_orientation(i, e, eff_has_axis: ti.template(), orient: ti.template()):
    return eff_has_axis[e] != 0 and orient[i, e].norm_sqr() > 0.0


@ti.func
def root_point(i, root_pos: ti.template(), work: ti.template(), extra: ti.template()):
    """Character i's root point: root_pos, plus its translation so far when the root is free (extra bit 4)."""
    out = root_pos[i]
    if ti.static(extra & 4):
        c0 = work.shape[2] - 3
        out += vec3(work[i, THETA, c0], work[i, THETA, c0 + 1], work[i, THETA, c0 + 2])
    return out
