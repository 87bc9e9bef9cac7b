"""CCD's per-joint steps on lane packets (kernels/ccd_steps.py's, one character per lane): the (averaged) swing of a
joint toward its effectors' targets, the straighten step, the hinge's best angle and the hinge's reach step, over
kernels/ccd_lanes.py's stream fields (one factory call per kernel: the functions close over its fields).

Every lane of a packet holds the same joint, so its kind, axis and limits are scalars; which effectors a joint
serves is the same for every lane too (the request's weight pattern). Angles take kernels/lane_trig.py's
element-wise polynomials where the one-character kernel calls libm.
"""

import taichi as ti

from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_trig as lt
from crowd_ik.solvers.settings import CCD_MULTI_ROUNDS as MULTI_ROUNDS


def lane_steps(L: int, ex, ey, ez, tx, ty, tz, tw):
    """(swing_step, straighten, hinge_step, hinge_reach_step) for L lanes over the stream fields e*
    (effectors carried through a sweep) and t*, tw (targets relative to the root, weights)."""
    V = ti.types.vector(L, ti.f32)

    @ti.func
    def turn_about(ax, angle, qx, qy, qz, qw):
        """ccd_steps.turn_about per lane: R(ax, angle) q, ax a scalar unit vec3."""
        s, c = lt.sin_cos(0.5 * angle)
        return lm.qnormalize(*lm.qmul(ax.x * s, ax.y * s, ax.z * s, c, qx, qy, qz, qw))

    @ti.func
    def swing_step(s, j, qx, qy, qz, qw, ix, iy, iz, iw, jx, jy, jz, below: ti.template(), eff_on: ti.template()):
        """ccd_steps.swing_step per lane: q preceded by the (averaged) swing turning the effectors below j toward
        their targets, in the parent's frame (i: the inverse of the parent's world rotation, j the joint)."""
        E = eff_on.shape[0]
        n_eff = V(0.0)
        for e in range(E):
            if below[j, e] != 0 and eff_on[e] != 0:
                dx, dy, dz = ex[s, e] - jx, ey[s, e] - jy, ez[s, e] - jz
                n_eff += ti.select(dx * dx + dy * dy + dz * dz > 1e-18, 1.0, 0.0)
        rounds = ti.select(n_eff > 1.0, float(MULTI_ROUNDS), 1.0)
        dx_, dy_, dz_, dw_ = V(0.0), V(0.0), V(0.0), V(1.0)
        for r in range(MULTI_ROUNDS if lm.any_lane(n_eff > 1.0) else 1):
            ax, ay, az, a_w = V(0.0), V(0.0), V(0.0), V(0.0)
            for e in range(E):
                if below[j, e] != 0 and eff_on[e] != 0:
                    ux, uy, uz = lm.qrot(ix, iy, iz, iw, ex[s, e] - jx, ey[s, e] - jy, ez[s, e] - jz)
                    ux, uy, uz = lm.qrot(dx_, dy_, dz_, dw_, ux, uy, uz)
                    vx, vy, vz = lm.qrot(ix, iy, iz, iw, tx[s, e] - jx, ty[s, e] - jy, tz[s, e] - jz)
                    nu = lm.norm3(ux, uy, uz)
                    nv = lm.norm3(vx, vy, vz)
                    ok = (nu > 1e-9) & (nv > 1e-9)
                    du = ti.select(ok, nu, 1.0)
                    dv = ti.select(ok, nv, 1.0)
                    sx, sy, sz, sw = lm.swing(ux / du, uy / du, uz / du, vx / dv, vy / dv, vz / dv)
                    flip = ti.select(sw < 0.0, -1.0, 1.0)
                    k = tw[s, e] * nu * nv
                    ax = ti.select(ok, ax + k * (flip * sx), ax)
                    ay = ti.select(ok, ay + k * (flip * sy), ay)
                    az = ti.select(ok, az + k * (flip * sz), az)
                    a_w = ti.select(ok, a_w + k * (flip * sw), a_w)
            nx, ny, nz, nw = lm.qnormalize(*lm.qmul(*lm.qnormalize(ax, ay, az, a_w), dx_, dy_, dz_, dw_))
            take = (n_eff > 0.0) & (float(r) < rounds) & (ax * ax + ay * ay + az * az + a_w * a_w > 0.0)
            dx_, dy_, dz_, dw_ = ti.select(take, nx, dx_), ti.select(take, ny, dy_), ti.select(take, nz, dz_), \
                ti.select(take, nw, dw_)
        return lm.qnormalize(*lm.qmul(dx_, dy_, dz_, dw_, qx, qy, qz, qw))

    @ti.func
    def straighten(k, ax, qx, qy, qz, qw, ux, uy, uz, vx, vy, vz):
        """ccd_steps.straighten_step per lane: q turned so that the child bone u lines up with the parent bone v
        (both in the parent's frame): about the axis ax for a hinge (k == 1), by the swing otherwise."""
        ox, oy, oz, ow = qx, qy, qz, qw
        if k == 1:
            du, dv = lm.dot3(ux, uy, uz, ax.x, ax.y, ax.z), lm.dot3(vx, vy, vz, ax.x, ax.y, ax.z)
            px, py, pz = ux - du * ax.x, uy - du * ax.y, uz - du * ax.z
            rx, ry, rz = vx - dv * ax.x, vy - dv * ax.y, vz - dv * ax.z
            s_cross = lm.dot3(ax.x, ax.y, ax.z, *lm.cross(px, py, pz, rx, ry, rz))
            s_dot = lm.dot3(px, py, pz, rx, ry, rz)
            hx, hy, hz, hw = turn_about(ax, lt.atan2(s_cross, s_dot), qx, qy, qz, qw)
            ok = (s_cross != 0.0) | (s_dot != 0.0)
            ox, oy, oz, ow = ti.select(ok, hx, qx), ti.select(ok, hy, qy), ti.select(ok, hz, qz), ti.select(ok, hw, qw)
        else:
            ok = (ux * ux + uy * uy + uz * uz > 0.0) & (vx * vx + vy * vy + vz * vz > 0.0)
            ax_, ay_, az_ = lm.normalized(ux, uy, uz)
            bx, by, bz = lm.normalized(vx, vy, vz)
            hx, hy, hz, hw = lm.qnormalize(*lm.qmul(*lm.swing(ax_, ay_, az_, bx, by, bz), qx, qy, qz, qw))
            ox, oy, oz, ow = ti.select(ok, hx, qx), ti.select(ok, hy, qy), ti.select(ok, hz, qz), ti.select(ok, hw, qw)
        return ox, oy, oz, ow

    @ti.func
    def hinge_step(s, j, qx, qy, qz, qw, ax, ix, iy, iz, iw, jx, jy, jz, below: ti.template(),
                   eff_on: ti.template()):
        """ccd_steps.hinge_step per lane: q turned about the hinge axis ax by the best angle for the effectors
        below j."""
        s_cross, s_dot = V(0.0), V(0.0)
        for e in range(eff_on.shape[0]):
            if below[j, e] != 0 and eff_on[e] != 0:
                w = tw[s, e]
                ux, uy, uz = lm.qrot(ix, iy, iz, iw, ex[s, e] - jx, ey[s, e] - jy, ez[s, e] - jz)
                vx, vy, vz = lm.qrot(ix, iy, iz, iw, tx[s, e] - jx, ty[s, e] - jy, tz[s, e] - jz)
                du, dv = lm.dot3(ux, uy, uz, ax.x, ax.y, ax.z), lm.dot3(vx, vy, vz, ax.x, ax.y, ax.z)
                ux, uy, uz = ux - du * ax.x, uy - du * ax.y, uz - du * ax.z
                vx, vy, vz = vx - dv * ax.x, vy - dv * ax.y, vz - dv * ax.z
                s_cross += w * lm.dot3(ax.x, ax.y, ax.z, *lm.cross(ux, uy, uz, vx, vy, vz))
                s_dot += w * lm.dot3(ux, uy, uz, vx, vy, vz)
        hx, hy, hz, hw = turn_about(ax, lt.atan2(s_cross, s_dot), qx, qy, qz, qw)
        ok = (s_cross != 0.0) | (s_dot != 0.0)
        return ti.select(ok, hx, qx), ti.select(ok, hy, qy), ti.select(ok, hz, qz), ti.select(ok, hw, qw)

    @ti.func
    def hinge_reach_step(s, e, qx, qy, qz, qw, ax, lo_j, hi_j, ix, iy, iz, iw, jx, jy, jz, bx, by, bz):
        """ccd_steps.hinge_reach_step per lane: q turned about the hinge axis so that |effector - parent| =
        |target - parent| (b: the parent's place), of the two bends the one inside the limits, else the nearer,
        and on a tie the smaller turn."""
        rx, ry, rz = lm.qrot(ix, iy, iz, iw, jx - bx, jy - by, jz - bz)
        ux, uy, uz = lm.qrot(ix, iy, iz, iw, ex[s, e] - jx, ey[s, e] - jy, ez[s, e] - jz)
        d_t = lm.norm3(tx[s, e] - bx, ty[s, e] - by, tz[s, e] - bz)
        r_par = lm.dot3(rx, ry, rz, ax.x, ax.y, ax.z)
        u_par = lm.dot3(ux, uy, uz, ax.x, ax.y, ax.z)
        rpx, rpy, rpz = rx - r_par * ax.x, ry - r_par * ax.y, rz - r_par * ax.z
        upx, upy, upz = ux - u_par * ax.x, uy - u_par * ax.y, uz - u_par * ax.z
        m = 2.0 * lm.norm3(rpx, rpy, rpz) * lm.norm3(upx, upy, upz)
        ok = m > 1e-12
        c = ti.math.clamp((d_t * d_t - lm.dot3(rx, ry, rz, rx, ry, rz) - lm.dot3(ux, uy, uz, ux, uy, uz)
                           - 2.0 * r_par * u_par) / ti.select(ok, m, 1.0), -1.0, 1.0)
        phi = lt.acos(c)
        phi0 = lt.atan2(lm.dot3(ax.x, ax.y, ax.z, *lm.cross(rpx, rpy, rpz, upx, upy, upz)),
                        lm.dot3(rpx, rpy, rpz, upx, upy, upz))
        theta0 = lt.twist_angle(qx, qy, qz, qw, ax.x, ax.y, ax.z)
        d1 = lm.wrap_angle(phi - phi0)
        d2 = lm.wrap_angle(-phi - phi0)
        t1 = lm.wrap_angle(theta0 + d1)
        t2 = lm.wrap_angle(theta0 + d2)
        v1 = ti.max(lo_j - t1, 0.0) + ti.max(t1 - hi_j, 0.0)
        v2 = ti.max(lo_j - t2, 0.0) + ti.max(t2 - hi_j, 0.0)
        dlt = ti.select((v2 < v1) | ((v2 == v1) & (ti.abs(d2) < ti.abs(d1))), d2, d1)
        hx, hy, hz, hw = turn_about(ax, dlt, qx, qy, qz, qw)
        return ti.select(ok, hx, qx), ti.select(ok, hy, qy), ti.select(ok, hz, qz), ti.select(ok, hw, qw)

    return swing_step, straighten, hinge_step, hinge_reach_step
