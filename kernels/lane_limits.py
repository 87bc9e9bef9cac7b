"""Joint-limit projection on lane packets: kernels/quat.py's constrain_rotation with one character per lane.

Each function takes a quaternion as four lane vectors and the joint's axes and limits as scalars (every
lane of a packet holds the same joint), and performs per lane the operations of its twin in
kernels/quat.py; the twin's branches become per-lane selects. The costly branches (the Euler
decomposition and rebuild where a box limit bites, a hinge's clamp, the cone) are computed only when
some lane of ``on`` (the lanes whose result is used) needs them: lanes that do not take the branch get
the other side, so a lane's result never depends on its lane-mates.

Trigonometry: the polynomials of kernels/lane_trig.py everywhere (the hinge's and universal joint's angles, the ball
joint's cone angle, the Euler decomposition and rebuild where a box limit bites, the cone's swing back, the
cone-within-box bisection), none of libm's calls, which Taichi makes one per lane and around which every live lane
vector is spilled. They had been 12.5 % of the warm 10,000-humanoid game solve's samples (perf) with libm in the
ball joint: the polynomials there take that solve from 13.9 to 12.2 ms (2-core AVX-512 AMD) with the same
agreement with the one-character kernel (statuses 99.98 %, iteration counts 99.95 %, poses within 1e-4 m 99.17 %
of 10 warm frames; before and after alike). A ball joint pinned on its cone turns by ang - cone, so its few ulp
of difference from libm's ang can grow over the iterations: on a windowed solve's characters 2 m out of reach one
final error in 67 ends 10.5 mm (0.8 %) from the one-character kernel's (tests/test_fabrik_restart.py).
"""

import taichi as ti
from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_trig as lt

from crowd_ik.solvers.settings import CONE_BOX_STEPS, GIMBAL


@ti.func
def euler_xyz_to_quat(a, b, c):
    """quat.euler_xyz_to_quat per lane: qmul(qmul(Rx(a), Ry(b)), Rz(c)) with the zero products dropped."""
    sa, ca = lt.sin_cos(0.5 * a)
    sb, cb = lt.sin_cos(0.5 * b)
    sc, cc = lt.sin_cos(0.5 * c)
    x1, y1, z1, w1 = cb * sa, ca * sb, sa * sb, ca * cb
    return cc * x1 + y1 * sc, cc * y1 - x1 * sc, w1 * sc + cc * z1, w1 * cc - z1 * sc


@ti.func
def euler_xyz_entries(x, y, z, w):
    """quat.euler_xyz_entries: R02, R12, R22, R01, R00."""
    return (2.0 * (x * z + y * w), 2.0 * (y * z - x * w), 1.0 - 2.0 * (x * x + y * y), 2.0 * (x * y - z * w),
            1.0 - 2.0 * (y * y + z * z))


@ti.func
def quat_to_euler_xyz(x, y, z, w):
    """quat.quat_to_euler_xyz per lane (the gimbal-locked case selected)."""
    r02, r12, r22, r01, r00 = euler_xyz_entries(x, y, z, w)
    b = lt.asin(ti.math.clamp(r02, -1.0, 1.0))
    lock = ti.abs(r02) >= GIMBAL
    r21 = 2.0 * (y * z + x * w)
    r11 = 1.0 - 2.0 * (x * x + z * z)
    a = lt.atan2(ti.select(lock, r21, -r12), ti.select(lock, r11, r22))  # one atan2 of the selected entries
    c = ti.select(lock, 0.0, lt.atan2(-r01, r00))
    return a, b, c


@ti.func
def euler_xyz_inside(x, y, z, w, lim_p: ti.template(), s):
    """quat.euler_xyz_inside per lane: the box of DOFs s..s+2 holds q's Euler angles (pseudo-angles)."""
    r02, r12, r22, r01, r00 = euler_xyz_entries(x, y, z, w)
    p0 = lm.pseudo_angle(r22, -r12)
    p1 = lm.pseudo_angle(ti.sqrt(r12 * r12 + r22 * r22), r02)
    p2 = lm.pseudo_angle(r00, -r01)
    return ((ti.abs(r02) < GIMBAL) & (p0 >= lim_p[s, 0]) & (p0 <= lim_p[s, 1]) & (p1 >= lim_p[s + 1, 0])
            & (p1 <= lim_p[s + 1, 1]) & (p2 >= lim_p[s + 2, 0]) & (p2 <= lim_p[s + 2, 1]))


@ti.func
def constrain_hinge(qx, qy, qz, qw, ax0, lo: ti.template(), hi: ti.template(), lim_p: ti.template(), s, on):
    """The hinge case of quat.constrain_rotation: the twist about ax0, clamped to [lo[s], hi[s]]."""
    # quat.twist_part
    t = lm.dot3(qx, qy, qz, ax0.x, ax0.y, ax0.z)
    w = qw
    n2 = t * t + w * w
    flip = (w < 0.0) | ((w == 0.0) & (t < 0.0))
    t, w = ti.select(flip, -t, t), ti.select(flip, -w, w)
    r = 1.0 / ti.sqrt(ti.max(n2, 1e-30))
    p = lm.pseudo_angle(w * w - t * t, 2.0 * t * w)
    inside = (n2 > 1e-12) & (lim_p[s, 0] <= p) & (p <= lim_p[s, 1])
    ox, oy, oz, ow = ax0.x * t * r, ax0.y * t * r, ax0.z * t * r, w * r
    if lm.any_lane(on & (inside == 0)):
        ang = ti.math.clamp(lt.twist_angle(qx, qy, qz, qw, ax0.x, ax0.y, ax0.z), lo[s], hi[s])
        cx, cy, cz, cw = lt.axis_angle(ax0.x, ax0.y, ax0.z, ang)
        ox, oy, oz, ow = ti.select(inside, ox, cx), ti.select(inside, oy, cy), ti.select(inside, oz, cz), \
            ti.select(inside, ow, cw)
    return ox, oy, oz, ow


@ti.func
def constrain_universal(qx, qy, qz, qw, ax0, ax1, lo: ti.template(), hi: ti.template(), s):
    """The universal case of quat.constrain_rotation: quat.joint_angles, clamped, quat.joint_quat."""
    vx, vy, vz = lm.qrot(qx, qy, qz, qw, ax1.x, ax1.y, ax1.z)
    cx, cy, cz = lm.cross(ax1.x, ax1.y, ax1.z, vx, vy, vz)
    t0 = lt.atan2(lm.dot3(ax0.x, ax0.y, ax0.z, cx, cy, cz), lm.dot3(ax1.x, ax1.y, ax1.z, vx, vy, vz))
    ux, uy, uz, uw = lt.axis_angle(ax0.x, ax0.y, ax0.z, t0)
    rx, ry, rz, rw = lm.qmul(-ux, -uy, -uz, uw, qx, qy, qz, qw)
    t1 = lt.twist_angle(rx, ry, rz, rw, ax1.x, ax1.y, ax1.z)
    ax, ay, az, aw = lt.axis_angle(ax0.x, ax0.y, ax0.z, ti.math.clamp(t0, lo[s], hi[s]))
    bx, by, bz, bw = lt.axis_angle(ax1.x, ax1.y, ax1.z, ti.math.clamp(t1, lo[s + 1], hi[s + 1]))
    return lm.qmul(ax, ay, az, aw, bx, by, bz, bw)


@ti.func
def cone_within_box(qx, qy, qz, qw, a, b, c, lo: ti.template(), hi: ti.template(), s, cone, bone, on):
    """quat.cone_within_box per lane: q = the rotation of box-clamped angles (a, b, c); where its bone left the
    cone, bisect toward the box's point nearest rest."""
    cos_cone = ti.cos(cone)
    bx, by, bz = lm.qrot(qx, qy, qz, qw, bone.x, bone.y, bone.z)
    out_ = lm.dot3(bx, by, bz, bone.x, bone.y, bone.z) < cos_cone
    ox, oy, oz, ow = qx, qy, qz, qw
    if lm.any_lane(on & out_):
        z0 = ti.math.clamp(0.0, lo[s], hi[s])
        z1 = ti.math.clamp(0.0, lo[s + 1], hi[s + 1])
        z2 = ti.math.clamp(0.0, lo[s + 2], hi[s + 2])
        t0 = 0.0 * a
        t1 = t0 + 1.0
        for _ in range(CONE_BOX_STEPS):
            t = 0.5 * (t0 + t1)
            mx, my, mz, mw = euler_xyz_to_quat(z0 + t * (a - z0), z1 + t * (b - z1), z2 + t * (c - z2))
            vx, vy, vz = lm.qrot(mx, my, mz, mw, bone.x, bone.y, bone.z)
            ok = lm.dot3(vx, vy, vz, bone.x, bone.y, bone.z) >= cos_cone
            t0, t1 = ti.select(ok, t, t0), ti.select(ok, t1, t)
        mx, my, mz, mw = euler_xyz_to_quat(z0 + t0 * (a - z0), z1 + t0 * (b - z1), z2 + t0 * (c - z2))
        ox, oy, oz, ow = ti.select(out_, mx, qx), ti.select(out_, my, qy), ti.select(out_, mz, qz), \
            ti.select(out_, mw, qw)
    return ox, oy, oz, ow


@ti.func
def constrain_ball(qx, qy, qz, qw, lo: ti.template(), hi: ti.template(), lim_p: ti.template(), s, cone, bone, on):
    """The ball case of quat.constrain_rotation: the cone on the swing of `bone`, then the Euler box."""
    ox, oy, oz, ow = qx, qy, qz, qw
    if cone > 0.0 and bone.norm_sqr() > 0.0:
        cx, cy, cz = lm.qrot(ox, oy, oz, ow, bone.x, bone.y, bone.z)
        ang = lt.acos(ti.math.clamp(lm.dot3(cx, cy, cz, bone.x, bone.y, bone.z), -1.0, 1.0))
        big = ang > cone
        if lm.any_lane(on & big):
            nx, ny, nz = lm.cross(cx, cy, cz, bone.x, bone.y, bone.z)
            nx, ny, nz = lm.safe_normalize(nx, ny, nz, 0.0, 0.0, 1.0)
            rx, ry, rz, rw = lt.axis_angle(nx, ny, nz, ang - cone)
            rx, ry, rz, rw = lm.qmul(rx, ry, rz, rw, ox, oy, oz, ow)
            ox, oy, oz, ow = ti.select(big, rx, ox), ti.select(big, ry, oy), ti.select(big, rz, oz), \
                ti.select(big, rw, ow)
    need = on & (euler_xyz_inside(ox, oy, oz, ow, lim_p, s) == 0)
    if lm.any_lane(need):
        a, b, c = quat_to_euler_xyz(ox, oy, oz, ow)
        ca = ti.math.clamp(a, lo[s], hi[s])
        cb = ti.math.clamp(b, lo[s + 1], hi[s + 1])
        cc = ti.math.clamp(c, lo[s + 2], hi[s + 2])
        bite = need & ((ca != a) | (cb != b) | (cc != c))  # rebuild only where a limit bites
        if lm.any_lane(bite):
            rx, ry, rz, rw = euler_xyz_to_quat(ca, cb, cc)
            if cone > 0.0 and bone.norm_sqr() > 0.0:
                rx, ry, rz, rw = cone_within_box(rx, ry, rz, rw, ca, cb, cc, lo, hi, s, cone, bone, bite)
            ox, oy, oz, ow = ti.select(bite, rx, ox), ti.select(bite, ry, oy), ti.select(bite, rz, oz), \
                ti.select(bite, rw, ow)
    return ox, oy, oz, ow
