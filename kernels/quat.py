"""Quaternion and joint-rotation helpers (@ti.func) shared by the kernels.

Quaternions are vec4 (x, y, z, w), scalar last (as scipy's Rotation), unit length, acting on column
vectors: v' = q v q*. A ball joint's Euler angles are intrinsic XYZ: R = Rx(a) Ry(b) Rz(c).
Joint kind codes equal their DOF counts: 0 fixed, 1 hinge, 2 universal, 3 ball.
"""

import taichi as ti

from crowd_ik.solvers.settings import CONE_BOX_STEPS, GIMBAL

vec3 = ti.math.vec3
vec4 = ti.math.vec4
PI = 3.141592653589793


@ti.func
def qmul(a, b):
    """Hamilton product a * b (apply b first, then a)."""
    av, bv = a.xyz, b.xyz
    v = a.w * bv + b.w * av + ti.math.cross(av, bv)
    return vec4(v.x, v.y, v.z, a.w * b.w - ti.math.dot(av, bv))


@ti.func
def qconj(q):
    return vec4(-q.x, -q.y, -q.z, q.w)


@ti.func
def qrot(q, v):
    """Rotate v by unit quaternion q (t = 2 q.xyz x v; v + w t + q.xyz x t)."""
    u = q.xyz
    t = 2.0 * ti.math.cross(u, v)
    return v + q.w * t + ti.math.cross(u, t)


@ti.func
def qnormalize(q):
    n = ti.sqrt(q.dot(q))
    out = vec4(0.0, 0.0, 0.0, 1.0)
    if n > 1e-12:
        out = q / n
    return out


@ti.func
def axis_angle(axis, angle):
    h = 0.5 * angle
    s = ti.sin(h)
    return vec4(axis.x * s, axis.y * s, axis.z * s, ti.cos(h))


@ti.func
def yaw_quat(yaw):
    return axis_angle(vec3(0.0, 1.0, 0.0), yaw)


@ti.func
def euler_xyz_to_quat(a, b, c):
    qx = axis_angle(vec3(1.0, 0.0, 0.0), a)
    qy = axis_angle(vec3(0.0, 1.0, 0.0), b)
    qz = axis_angle(vec3(0.0, 0.0, 1.0), c)
    return qmul(qmul(qx, qy), qz)


@ti.func
def euler_xyz_entries(q):
    """The rotation matrix entries an XYZ decomposition reads: R02, R12, R22, R01, R00."""
    x, y, z, w = q.x, q.y, q.z, q.w
    return (2.0 * (x * z + y * w), 2.0 * (y * z - x * w), 1.0 - 2.0 * (x * x + y * y), 2.0 * (x * y - z * w),
            1.0 - 2.0 * (y * y + z * z))


@ti.func
def quat_to_euler_xyz(q):
    """Intrinsic XYZ angles of R = Rx(a) Ry(b) Rz(c): b = asin(R02), a = atan2(-R12, R22), c = atan2(-R01, R00)."""
    r02, r12, r22, r01, r00 = euler_xyz_entries(q)
    b = ti.asin(ti.math.clamp(r02, -1.0, 1.0))
    a = 0.0
    c = 0.0
    if ti.abs(r02) < GIMBAL:
        a = ti.atan2(-r12, r22)
        c = ti.atan2(-r01, r00)
    else:  # gimbal lock: put the whole remaining rotation on a
        x, y, z, w = q.x, q.y, q.z, q.w
        r21 = 2.0 * (y * z + x * w)
        r11 = 1.0 - 2.0 * (x * x + z * z)
        a = ti.atan2(r21, r11)
    return vec3(a, b, c)


@ti.func
def pseudo_angle(x, y):
    """A stand-in for atan2(y, x) with the same order on (-pi, pi] and range (-2, 2], without trigonometry."""
    p = y / ti.max(ti.abs(x) + ti.abs(y), 1e-30)
    out = p
    if x < 0.0:
        out = 2.0 - p if y >= 0.0 else -2.0 - p
    return out


@ti.func
def euler_xyz_inside(q, lim_p: ti.template(), s):
    """Whether quat_to_euler_xyz(q) lies inside the box of DOFs s..s+2 (lim_p: their limits' pseudo-angles),
    decided on pseudo-angles of the matrix entries the angles are taken from (b = atan2(r02, cos b) as
    cos b = |(r12, r22)|); False near gimbal lock, where only the full decomposition decides."""
    r02, r12, r22, r01, r00 = euler_xyz_entries(q)
    p = vec3(pseudo_angle(r22, -r12), pseudo_angle(ti.sqrt(r12 * r12 + r22 * r22), r02), pseudo_angle(r00, -r01))
    inside = ti.abs(r02) < GIMBAL
    for d in ti.static(range(3)):
        if p[d] < lim_p[s + d, 0] or p[d] > lim_p[s + d, 1]:
            inside = False
    return inside


@ti.func
def wrap_angle(t):
    """Wrap to (-pi, pi]."""
    return t - 2.0 * PI * ti.floor((t + PI) / (2.0 * PI))


@ti.func
def twist_angle(q, axis):
    """Angle of the twist of q about a unit axis (swing-twist decomposition), in (-pi, pi]."""
    return wrap_angle(2.0 * ti.atan2(q.xyz.dot(axis), q.w))


@ti.func
def twist_part(q, axis):
    """The twist of q about a unit axis as a unit quaternion with w >= 0 (axis_angle(axis, twist_angle(q, axis))
    without trigonometry), the pseudo_angle of that twist angle, and whether q has a twist to take (False when
    q turns the axis half a turn, where twist_angle falls back to 0)."""
    s = q.xyz.dot(axis)
    w = q.w
    n2 = s * s + w * w
    if w < 0.0 or (w == 0.0 and s < 0.0):
        s, w = -s, -w
    r = 1.0 / ti.sqrt(ti.max(n2, 1e-30))
    # the twist angle t = 2 atan2(s, w): (cos t, sin t) is proportional to (w^2 - s^2, 2 s w)
    return vec4(axis.x * s * r, axis.y * s * r, axis.z * s * r, w * r), pseudo_angle(w * w - s * s, 2.0 * s * w), \
        n2 > 1e-12


@ti.func
def joint_quat(kind, ax0, ax1, a0, a1, a2):
    """Local rotation of a joint from its DOF values (unused values ignored)."""
    q = vec4(0.0, 0.0, 0.0, 1.0)
    if kind == 1:
        q = axis_angle(ax0, a0)
    elif kind == 2:
        q = qmul(axis_angle(ax0, a0), axis_angle(ax1, a1))
    elif kind == 3:
        q = euler_xyz_to_quat(a0, a1, a2)
    return q


@ti.func
def joint_angles(kind, ax0, ax1, q):
    """DOF values of a joint's local rotation q (the projection onto its DOFs for hinge/universal)."""
    out = vec3(0.0, 0.0, 0.0)
    if kind == 1:
        out.x = twist_angle(q, ax0)
    elif kind == 2:
        # R a1 = R(ax0, t0) a1, so t0 is the angle that turns a1 to R a1 about ax0; then the rest is about ax1.
        v = qrot(q, ax1)
        t0 = ti.atan2(ax0.dot(ti.math.cross(ax1, v)), ax1.dot(v))
        rest = qmul(qconj(axis_angle(ax0, t0)), q)
        out.x = t0
        out.y = twist_angle(rest, ax1)
    elif kind == 3:
        out = quat_to_euler_xyz(q)
    return out


@ti.func
def swing(u, v):
    """The minimal rotation taking unit vector u to unit vector v (no twist about either)."""
    d = u.dot(v)
    q = vec4(0.0, 0.0, 0.0, 1.0)
    if d < -0.999999:
        axis = ti.math.cross(u, vec3(1.0, 0.0, 0.0))
        if axis.norm_sqr() < 1e-8:
            axis = ti.math.cross(u, vec3(0.0, 1.0, 0.0))
        axis = axis.normalized()
        q = vec4(axis.x, axis.y, axis.z, 0.0)
    else:
        c = ti.math.cross(u, v)
        q = qnormalize(vec4(c.x, c.y, c.z, 1.0 + d))
    return q


@ti.func
def safe_normalize(v, fallback):
    n = v.norm()
    out = fallback
    if n > 1e-9:
        out = v / n
    return out


@ti.func
def constrain_rotation(kind, ax0, ax1, q, lo: ti.template(), hi: ti.template(), lim_p: ti.template(), s, cone, bone):
    """Project q onto the joint's DOFs and clamp it to its limits (cone on the swing of `bone`, then boxes; where
    the box clamp leaves the cone again, cone_within_box finds angles inside both). lim_p: the limits'
    pseudo-angles, to skip the Euler decomposition where no box limit bites."""
    out = q
    if kind == 1:
        tw, p, ok = twist_part(q, ax0)
        if ok and lim_p[s, 0] <= p and p <= lim_p[s, 1]:
            out = tw
        else:
            t = ti.math.clamp(twist_angle(q, ax0), lo[s], hi[s])
            out = axis_angle(ax0, t)
    elif kind == 2:
        a = joint_angles(kind, ax0, ax1, q)
        out = joint_quat(kind, ax0, ax1, ti.math.clamp(a.x, lo[s], hi[s]), ti.math.clamp(a.y, lo[s + 1], hi[s + 1]),
                         0.0)
    elif kind == 3:
        if cone > 0.0 and bone.norm_sqr() > 0.0:
            cur = qrot(out, bone)
            ang = ti.acos(ti.math.clamp(cur.dot(bone), -1.0, 1.0))
            if ang > cone:
                # rotate the bone back toward rest along the great circle until it sits on the cone
                axis = safe_normalize(ti.math.cross(cur, bone), vec3(0.0, 0.0, 1.0))
                out = qmul(axis_angle(axis, ang - cone), out)
        # (an unlimited DOF's pseudo-angle limits are -3 and 3: inside always)
        if not euler_xyz_inside(out, lim_p, s):
            a = quat_to_euler_xyz(out)
            c = vec3(ti.math.clamp(a.x, lo[s], hi[s]), ti.math.clamp(a.y, lo[s + 1], hi[s + 1]),
                     ti.math.clamp(a.z, lo[s + 2], hi[s + 2]))
            if c.x != a.x or c.y != a.y or c.z != a.z:  # rebuild only when a limit bites
                out = euler_xyz_to_quat(c.x, c.y, c.z)
                if cone > 0.0 and bone.norm_sqr() > 0.0:
                    out = cone_within_box(out, c, lo, hi, s, cone, bone)
    return out


@ti.func
def cone_within_box(q, c, lo: ti.template(), hi: ti.template(), s, cone, bone):
    """q = the rotation of box-clamped Euler angles c; if the box clamp put `bone` back outside the cone, the
    angles z + t (c - z) with the largest t in [0, 1] whose bone lies inside it (bisection), z = the box's point
    nearest rest: inside the box exactly and the cone to ~2^-CONE_BOX_STEPS of the range (z itself where even
    z leaves the cone)."""
    out = q
    cos_cone = ti.cos(cone)
    if qrot(q, bone).dot(bone) < cos_cone:
        z = vec3(ti.math.clamp(0.0, lo[s], hi[s]), ti.math.clamp(0.0, lo[s + 1], hi[s + 1]),
                 ti.math.clamp(0.0, lo[s + 2], hi[s + 2]))
        t0 = 0.0
        t1 = 1.0
        for _ in range(CONE_BOX_STEPS):
            t = 0.5 * (t0 + t1)
            m = z + t * (c - z)
            if qrot(euler_xyz_to_quat(m.x, m.y, m.z), bone).dot(bone) >= cos_cone:
                t0 = t
            else:
                t1 = t
        m = z + t0 * (c - z)
        out = euler_xyz_to_quat(m.x, m.y, m.z)
    return out


@ti.func
def best_angle_about(axis, u, v):
    """Angle about a unit axis that best turns u toward v: atan2(a.(u x v), u.v) on the projections."""
    up = u - u.dot(axis) * axis
    vp = v - v.dot(axis) * axis
    return ti.atan2(axis.dot(ti.math.cross(up, vp)), up.dot(vp))


@ti.func
def align_axis(kind, ax0, ax1, q, u, t):
    """Turn a joint's local rotation q so that its local direction u points along t (both in the parent frame).

    Ball: the minimal swing. Hinge: the best angle about its axis. Universal: alternating best angles
    about its two axes (block coordinate descent; exact for each axis, converges in a few rounds).
    """
    out = q
    if kind == 3:
        out = qnormalize(qmul(swing(qrot(q, u).normalized(), t), q))
    elif kind == 1:
        out = qnormalize(qmul(axis_angle(ax0, best_angle_about(ax0, qrot(q, u), t)), q))
    elif kind == 2:
        a = joint_angles(kind, ax0, ax1, q)
        for _ in range(4):
            a.x = best_angle_about(ax0, qrot(axis_angle(ax1, a.y), u), t)
            a.y = best_angle_about(ax1, u, qrot(axis_angle(ax0, -a.x), t))
        out = joint_quat(kind, ax0, ax1, a.x, a.y, 0.0)
    return out
