"""Helpers of the general DLS lane kernel (kernels/dls_general_lanes.py) on lane packets: each is its twin in
kernels/dls_pose.py, kernels/dls_system.py or kernels/quat.py, with every scalar of a character a lane of a
``ti.types.vector(L, ti.f32)`` and its branches per-lane selects (a 3-vector is three lane vectors, a quaternion
four). The same operations in the same order, except that normalisations multiply by one reciprocal
(kernels/lane_math.py) and angles come from kernels/lane_trig.py's polynomials. Generic in L; no Taichi state.
"""

import taichi as ti

from crowd_ik.kernels import lane_limits as lim
from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_trig as lt


@ti.func
def qexp(rx, ry, rz):
    """dls_pose.qexp per lane: the unit quaternion of the rotation vector r."""
    a = lm.norm3(rx, ry, rz)
    big = a > 1e-7
    s, c = lt.sin_cos(0.5 * a)
    s = s / ti.select(big, a, 1.0)
    return lm.qnormalize(ti.select(big, rx * s, 0.5 * rx), ti.select(big, ry * s, 0.5 * ry),
                         ti.select(big, rz * s, 0.5 * rz), ti.select(big, c, 1.0))


@ti.func
def qlog(x, y, z, w):
    """dls_pose.qlog per lane: the rotation vector (axis * angle, angle in [0, pi]) of a unit quaternion."""
    neg = w < 0.0
    x, y, z, w = ti.select(neg, -x, x), ti.select(neg, -y, y), ti.select(neg, -z, z), ti.select(neg, -w, w)
    s = lm.norm3(x, y, z)
    big = s > 1e-7
    k = 2.0 * lt.atan2(s, w) / ti.select(big, s, 1.0)
    return ti.select(big, x * k, 2.0 * x), ti.select(big, y * k, 2.0 * y), ti.select(big, z * k, 2.0 * z)


@ti.func
def perpendicular(ax, ay, az):
    """dls_pose.perpendicular per lane: a unit vector perpendicular to the unit vector a."""
    ux, uy, uz = lm.cross(ax, ay, az, 1.0, 0.0, 0.0)
    vx, vy, vz = lm.cross(ax, ay, az, 0.0, 1.0, 0.0)
    small = ux * ux + uy * uy + uz * uz < 0.01
    return lm.normalized(ti.select(small, vx, ux), ti.select(small, vy, uy), ti.select(small, vz, uz))


@ti.func
def swing_vector(ax, ay, az, tx, ty, tz):
    """dls_pose.swing_vector per lane: the rotation vector of the minimal rotation taking unit a to unit t."""
    cx, cy, cz = lm.cross(ax, ay, az, tx, ty, tz)
    s = lm.norm3(cx, cy, cz)
    dt = lm.dot3(ax, ay, az, tx, ty, tz)
    ang = lt.atan2(s, dt)
    big = s > 1e-7
    px, py, pz = perpendicular(ax, ay, az)
    anti = dt < 0.0
    sd = ti.select(big, s, 1.0)
    wx = ti.select(big, cx / sd, ti.select(anti, px, 0.0))
    wy = ti.select(big, cy / sd, ti.select(anti, py, 0.0))
    wz = ti.select(big, cz / sd, ti.select(anti, pz, 0.0))
    return wx * ang, wy * ang, wz * ang


@ti.func
def joint_quat(k, ax0, ax1, a0, a1, a2):
    """quat.joint_quat per lane: a joint's local rotation from its DOF values (k its DOF count, the same in every
    lane; ax0, ax1 its axes)."""
    one = a0 * 0.0 + 1.0
    qx, qy, qz, qw = a0 * 0.0, a0 * 0.0, a0 * 0.0, one
    if k == 1:
        qx, qy, qz, qw = lt.axis_angle(ax0.x, ax0.y, ax0.z, a0)
    elif k == 2:
        qx, qy, qz, qw = lm.qmul(*lt.axis_angle(ax0.x, ax0.y, ax0.z, a0), *lt.axis_angle(ax1.x, ax1.y, ax1.z, a1))
    elif k == 3:
        # quat.euler_xyz_to_quat: qmul(qmul(Rx(a), Ry(b)), Rz(c)) as the scalar kernel multiplies them
        qx, qy, qz, qw = lm.qmul(*lm.qmul(*lt.axis_angle(1.0, 0.0, 0.0, a0), *lt.axis_angle(0.0, 1.0, 0.0, a1)),
                                 *lt.axis_angle(0.0, 0.0, 1.0, a2))
    return qx, qy, qz, qw


@ti.func
def dof_axes(k, angle_joint, ax0, ax1, bx, by, bz, bw, t0, t1):
    """dls_system.dof_axes per lane: the world axes of a joint's DOFs (nine lane vectors: three 3-vectors), its
    parent's world rotation b and its first two angles t0, t1 given; world x, y, z for a joint solved on its
    quaternion."""
    zero = t0 * 0.0
    w0x, w0y, w0z = zero + 1.0, zero, zero
    w1x, w1y, w1z = zero, zero + 1.0, zero
    w2x, w2y, w2z = zero, zero, zero + 1.0
    if angle_joint:
        if k == 1:
            w0x, w0y, w0z = lm.qrot(bx, by, bz, bw, ax0.x, ax0.y, ax0.z)
        elif k == 2:
            w0x, w0y, w0z = lm.qrot(bx, by, bz, bw, ax0.x, ax0.y, ax0.z)
            cx, cy, cz, cw = lm.qmul(bx, by, bz, bw, *lt.axis_angle(ax0.x, ax0.y, ax0.z, t0))
            w1x, w1y, w1z = lm.qrot(cx, cy, cz, cw, ax1.x, ax1.y, ax1.z)
        else:
            rx, ry, rz, rw = lm.qmul(bx, by, bz, bw, *lt.axis_angle(1.0, 0.0, 0.0, t0))
            w0x, w0y, w0z = lm.qrot(bx, by, bz, bw, 1.0, 0.0, 0.0)
            w1x, w1y, w1z = lm.qrot(rx, ry, rz, rw, 0.0, 1.0, 0.0)
            cx, cy, cz, cw = lm.qmul(rx, ry, rz, rw, *lt.axis_angle(0.0, 1.0, 0.0, t1))
            w2x, w2y, w2z = lm.qrot(cx, cy, cz, cw, 0.0, 0.0, 1.0)
    return w0x, w0y, w0z, w1x, w1y, w1z, w2x, w2y, w2z


@ti.func
def clamp_ball(qx, qy, qz, qw, angle_joint, lo: ti.template(), hi: ti.template(), lim_p: ti.template(),
               lim_h: ti.template(), d, cone, bone, on):
    """kernels/dls.apply_step's projection of a ball joint with a cone (quat.constrain_rotation, kind 3) per lane;
    with its Euler angles after it (zero unless angle_joint) for a joint solved in its angles."""
    ox, oy, oz, ow = lim.constrain_ball(qx, qy, qz, qw, lo, hi, lim_p, lim_h, d, cone, bone, on)
    e0, e1, e2 = qx * 0.0, qx * 0.0, qx * 0.0
    if angle_joint:
        e0, e1, e2 = lim.quat_to_euler_xyz(ox, oy, oz, ow)
    return ox, oy, oz, ow, e0, e1, e2


@ti.func
def copy_pose(s, on, J, C, src: ti.template(), dst: ti.template()):
    """In the lanes `on` of stream s, a pose's field rows src into dst, each a tuple (angles (S, C), local rotation
    x, y, z, w (S, J)): the general DLS lanes' restore after a rejected step and the velocity term's start pose."""
    for d in range(C):
        dst[0][s, d] = ti.select(on, src[0][s, d], dst[0][s, d])
    for j in range(J):
        for k in ti.static(range(1, 5)):
            dst[k][s, j] = ti.select(on, src[k][s, j], dst[k][s, j])
