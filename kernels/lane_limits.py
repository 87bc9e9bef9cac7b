"""Joint-limit projection on lane packets: kernels/quat.py's constrain_rotation with one character per lane.

Each function takes a quaternion as four lane vectors and the joint's axes and limits as scalars (every
lane of a packet holds the same joint), and performs per lane the operations of its twin in
kernels/quat.py; the twin's branches become per-lane selects. The costly branches (the Euler
decomposition and rebuild where a box limit bites, a hinge's clamp, the cone) are computed only when
some lane of ``on`` (the lanes whose result is used) needs them: lanes that do not take the branch get
the other side, so a lane's result never depends on its lane-mates.

Trigonometry: almost none. A clamp works on half angles: the angle's pseudo-angle decides whether a limit bites
(solvers/limits.py's limit_pseudo_angles), its half angle's (cos, sin) comes from the rotation's entries by the
half-angle identities (lane_math.half_turn: one square root), and a limit that bites puts in its own half angle's
(cos, sin), precomputed per DOF (limit_half_turns), so the hinge, the universal joint and the ball joint's Euler box
are rebuilt without sin, cos, atan2 or asin. The ball joint's cone (acos and its swing back) and the rare bisection
of a box back into a cone use kernels/lane_trig.py's polynomials; none of libm's calls, which Taichi makes one per
lane and around which every live lane vector is spilled. The polynomials had taken the warm 10,000-humanoid game
solve from 13.9 to 12.2 ms (2-core AVX-512 AMD); the half angles take the limited kernel's 4-iteration solve from
15.1 to 14.2 ms (2-core AVX-512 Intel, tests/test_lane_limits.py checks them against the NumPy twin). A ball joint
pinned on its cone turns by ang - cone, so its few ulp of difference from libm's ang can grow over the iterations:
on a windowed solve's characters 2 m out of reach one final error in 67 ends 10.5 mm (0.8 %) from the
one-character kernel's (tests/test_fabrik_restart.py).
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
    return euler_halves_to_quat(ca, sa, cb, sb, cc, sc)


@ti.func
def euler_halves_to_quat(ca, sa, cb, sb, cc, sc):
    """euler_xyz_to_quat from the cosines and sines of the half angles."""
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
def clamp_half(p, hc, hs, lim_p: ti.template(), lim_h: ti.template(), d):
    """An angle given as its pseudo-angle p and its half angle's (cos, sin), clamped to DOF d's limits: the
    clamped half angle's (cos, sin) (the limit's own, solvers/limits.py's limit_half_turns, where it bites) and
    whether it bites."""
    below = p < lim_p[d, 0]
    above = p > lim_p[d, 1]
    return (ti.select(below, lim_h[d, 0], ti.select(above, lim_h[d, 2], hc)),
            ti.select(below, lim_h[d, 1], ti.select(above, lim_h[d, 3], hs)), below | above)


@ti.func
def twist_half(qx, qy, qz, qw, ax, ay, az):
    """quat.twist_part's twist of q about a unit axis as its half angle's (cos, sin) (w >= 0; the identity where
    the twist vanishes) and the pseudo-angle of the full angle."""
    t = lm.dot3(qx, qy, qz, ax, ay, az)
    w = qw
    n2 = t * t + w * w
    flip = (w < 0.0) | ((w == 0.0) & (t < 0.0))
    t, w = ti.select(flip, -t, t), ti.select(flip, -w, w)
    r = 1.0 / ti.sqrt(ti.max(n2, 1e-30))
    zero = n2 == 0.0
    hc, hs = ti.select(zero, 1.0, w * r), ti.select(zero, 0.0, t * r)
    return hc, hs, lm.pseudo_angle(w * w - t * t, 2.0 * t * w)


@ti.func
def constrain_hinge(qx, qy, qz, qw, ax0, lim_p: ti.template(), lim_h: ti.template(), s):
    """The hinge case of quat.constrain_rotation: the twist about ax0, clamped to [lo[s], hi[s]]. Where the clamp
    bites the result is the rotation by the limit, (ax0 sin, cos) of its half angle, so no angle is evaluated."""
    hc, hs, p = twist_half(qx, qy, qz, qw, ax0.x, ax0.y, ax0.z)
    hc, hs, _bites = clamp_half(p, hc, hs, lim_p, lim_h, s)
    return ax0.x * hs, ax0.y * hs, ax0.z * hs, hc


@ti.func
def constrain_universal(qx, qy, qz, qw, ax0, ax1, lim_p: ti.template(), lim_h: ti.template(), s):
    """The universal case of quat.constrain_rotation: quat.joint_angles, clamped, quat.joint_quat, as half angles:
    t0 = atan2(y0, x0) gives the rotation u about ax0 by half_turn (no atan2, no sin or cos), t1 is the twist of
    u^-1 q about ax1, and each clamp that bites puts its limit's rotation in place."""
    vx, vy, vz = lm.qrot(qx, qy, qz, qw, ax1.x, ax1.y, ax1.z)
    cx, cy, cz = lm.cross(ax1.x, ax1.y, ax1.z, vx, vy, vz)
    x0, y0 = lm.dot3(ax1.x, ax1.y, ax1.z, vx, vy, vz), lm.dot3(ax0.x, ax0.y, ax0.z, cx, cy, cz)
    uc, us = lm.unit_half_turn(x0, y0)
    rx, ry, rz, rw = lm.qmul(-ax0.x * us, -ax0.y * us, -ax0.z * us, uc, qx, qy, qz, qw)
    bc, bs, p1 = twist_half(rx, ry, rz, rw, ax1.x, ax1.y, ax1.z)
    uc, us, _b0 = clamp_half(lm.pseudo_angle(x0, y0), uc, us, lim_p, lim_h, s)
    bc, bs, _b1 = clamp_half(p1, bc, bs, lim_p, lim_h, s + 1)
    return lm.qmul(ax0.x * us, ax0.y * us, ax0.z * us, uc, ax1.x * bs, ax1.y * bs, ax1.z * bs, bc)


@ti.func
def cone_within_box(qx, qy, qz, qw, fx, fy, fz, fw, lo: ti.template(), hi: ti.template(), s, cone, bone, on):
    """quat.cone_within_box per lane: q = the rotation of f's box-clamped Euler angles (a, b, c); where its bone
    left the cone, bisect toward the box's point nearest rest."""
    cos_cone = ti.cos(cone)
    bx, by, bz = lm.qrot(qx, qy, qz, qw, bone.x, bone.y, bone.z)
    out_ = lm.dot3(bx, by, bz, bone.x, bone.y, bone.z) < cos_cone
    ox, oy, oz, ow = qx, qy, qz, qw
    if lm.any_lane(on & out_):
        a, b, c = quat_to_euler_xyz(fx, fy, fz, fw)
        a = ti.math.clamp(a, lo[s], hi[s])
        b = ti.math.clamp(b, lo[s + 1], hi[s + 1])
        c = ti.math.clamp(c, lo[s + 2], hi[s + 2])
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
def constrain_ball(qx, qy, qz, qw, lo: ti.template(), hi: ti.template(), lim_p: ti.template(),
                   lim_h: ti.template(), s, cone, bone, on):
    """The ball case of quat.constrain_rotation: the cone on the swing of `bone`, then the Euler box. The box as
    half angles: each Euler angle's (cos, sin) from the rotation matrix's entries (quat.quat_to_euler_xyz's atan2
    and asin arguments) by half_turn, or its limit's where the clamp bites, rebuilt by euler_halves_to_quat; the
    bisection back into the cone (rare: only with a cone and a box) evaluates the angles."""
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
    # quat.euler_xyz_inside: the box holds q's Euler angles (an unlimited DOF's pseudo-angle limits are -3 and 3)
    r02, r12, r22, r01, r00 = euler_xyz_entries(ox, oy, oz, ow)
    xb = ti.sqrt(r12 * r12 + r22 * r22)
    p0 = lm.pseudo_angle(r22, -r12)
    p1 = lm.pseudo_angle(xb, r02)
    p2 = lm.pseudo_angle(r00, -r01)
    lock = ti.abs(r02) >= GIMBAL
    inside = ((lock == 0) & (p0 >= lim_p[s, 0]) & (p0 <= lim_p[s, 1]) & (p1 >= lim_p[s + 1, 0])
              & (p1 <= lim_p[s + 1, 1]) & (p2 >= lim_p[s + 2, 0]) & (p2 <= lim_p[s + 2, 1]))
    need = on & (inside == 0)
    if lm.any_lane(need):
        # gimbal-locked: a from R21 and R11, c = 0
        xa = ti.select(lock, 1.0 - 2.0 * (ox * ox + oz * oz), r22)
        ya = ti.select(lock, 2.0 * (oy * oz + ox * ow), -r12)
        xc, yc = ti.select(lock, 1.0, r00), ti.select(lock, 0.0, -r01)
        hca, hsa = lm.unit_half_turn(xa, ya)
        hcb, hsb = lm.unit_half_turn(xb, r02)
        hcc, hsc = lm.unit_half_turn(xc, yc)
        hca, hsa, bite_a = clamp_half(lm.pseudo_angle(xa, ya), hca, hsa, lim_p, lim_h, s)
        hcb, hsb, bite_b = clamp_half(p1, hcb, hsb, lim_p, lim_h, s + 1)
        hcc, hsc, bite_c = clamp_half(ti.select(lock, 0.0, p2), hcc, hsc, lim_p, lim_h, s + 2)
        bite = need & (bite_a | bite_b | bite_c)  # rebuild only where a limit bites
        if lm.any_lane(bite):
            rx, ry, rz, rw = euler_halves_to_quat(hca, hsa, hcb, hsb, hcc, hsc)
            if cone > 0.0 and bone.norm_sqr() > 0.0:
                rx, ry, rz, rw = cone_within_box(rx, ry, rz, rw, ox, oy, oz, ow, lo, hi, s, cone, bone, bite)
            ox, oy, oz, ow = ti.select(bite, rx, ox), ti.select(bite, ry, oy), ti.select(bite, rz, oz), \
                ti.select(bite, rw, ow)
    return ox, oy, oz, ow
