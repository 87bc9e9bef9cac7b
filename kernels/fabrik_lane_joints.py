"""The joint steps of kernels/fabrik_limited_lanes.py's sweep, per lane: kernels/fabrik.py's swing round (a ball
joint's rotation from its children's proposals), the closed-form two-bone limb with its swivel test, and the twist
a ball joint takes for a hinge child, over that kernel's stream fields (one factory call per kernel: the functions
close over its fields, as they did inside it)."""

import taichi as ti
from crowd_ik.kernels import lane_limits as lim
from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_trig as lt

from crowd_ik.solvers.settings import TWIST_FULL_BEND, TWIST_MIN_BEND


def joint_steps(L: int, lx, ly, lz, lw, wx, wy, wz, aw):
    """(to_base, swing_round, twist_for_hinge_child, two_bone_swing) for L lanes over the stream
    fields l* (local rotations) and w*, aw (proposals and their weights) of kernels/fabrik_limited_lanes.py."""
    V = ti.types.vector(L, ti.f32)

    @ti.func
    def last_active(j, child_start: ti.template(), child_list: ti.template(), active: ti.template()):
        """The last active child of j (-1 for none) and how many there are."""
        c = -1
        n = 0
        for cc in range(child_start[j], child_start[j + 1]):
            if active[child_list[cc]]:
                c = child_list[cc]
                n += 1
        return c, n

    @ti.func
    def to_base(s, k, ix, iy, iz, iw, jx, jy, jz):
        """Proposal of joint k in the frame of a joint at j whose base rotation's inverse is i."""
        return lm.qrot(ix, iy, iz, iw, wx[s, k] - jx, wy[s, k] - jy, wz[s, k] - jz)

    @ti.func
    def swing_round(s, qx, qy, qz, qw, c0, c1, ix, iy, iz, iw, jx, jy, jz, offset: ti.template(),
                    child_list: ti.template(), active: ti.template()):
        """fabrik.swing_round per lane."""
        ax, ay, az, a_w = V(0.0), V(0.0), V(0.0), V(0.0)
        for cc in range(c0, c1):
            c = child_list[cc]
            if active[c]:
                wc = aw[s, c]
                o = offset[c]
                ux, uy, uz = lm.qrot(qx, qy, qz, qw, o.x, o.y, o.z)
                ux, uy, uz = lm.normalized(ux, uy, uz)
                vx, vy, vz = to_base(s, c, ix, iy, iz, iw, jx, jy, jz)
                vx, vy, vz = lm.safe_normalize(vx, vy, vz, ux, uy, uz)
                sx, sy, sz, sw = lm.swing(ux, uy, uz, vx, vy, vz)
                flip = ti.select(sw < 0.0, -1.0, 1.0)
                ax, ay, az, a_w = ax + wc * (flip * sx), ay + wc * (flip * sy), az + wc * (flip * sz), \
                    a_w + wc * (flip * sw)
        nx, ny, nz, nw = lm.qnormalize(ax, ay, az, a_w)
        return lm.qnormalize(*lm.qmul(nx, ny, nz, nw, qx, qy, qz, qw))

    @ti.func
    def twist_for_hinge_child(s, j, qx, qy, qz, qw, ix, iy, iz, iw, jx, jy, jz, on, kind: ti.template(),
                              axes: ti.template(), offset: ti.template(), lo: ti.template(), hi: ti.template(),
                              dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
                              active: ti.template()):
        """fabrik.twist_for_hinge_child per lane (on: the lanes whose result is used)."""
        outx, outy, outz, outw = qx, qy, qz, qw
        c, _n = last_active(j, child_start, child_list, active)
        if c >= 0 and kind[c] == 1:
            g, _m = last_active(c, child_start, child_list, active)
            if g >= 0:
                o = offset[c]
                bx, by, bz = lm.normalized(*lm.qrot(qx, qy, qz, qw, o.x, o.y, o.z))
                ux, uy, uz = to_base(s, c, ix, iy, iz, iw, jx, jy, jz)
                vx, vy, vz = lm.qrot(ix, iy, iz, iw, wx[s, g] - wx[s, c], wy[s, g] - wy[s, c], wz[s, g] - wz[s, c])
                nx, ny, nz = lm.cross(ux, uy, uz, vx, vy, vz)
                bend = lm.norm3(nx, ny, nz) / ti.max(lm.norm3(ux, uy, uz) * lm.norm3(vx, vy, vz), 1e-12)
                go = on & (bend > TWIST_MIN_BEND)
                if lm.any_lane(go):
                    nx, ny, nz = lm.normalized(nx, ny, nz)
                    d = dof_start[c]
                    a0 = axes[c, 0]
                    px, py, pz = lm.qrot(qx, qy, qz, qw, a0.x, a0.y, a0.z)
                    sign = ti.select(lm.dot3(px, py, pz, nx, ny, nz) < 0.0, -1.0, 1.0)
                    if lo[d] >= 0.0:
                        sign = V(1.0)
                    elif hi[d] <= 0.0:
                        sign = V(-1.0)
                    nx, ny, nz = sign * nx, sign * ny, sign * nz
                    pb = lm.dot3(px, py, pz, bx, by, bz)
                    apx, apy, apz = px - pb * bx, py - pb * by, pz - pb * bz
                    nb = lm.dot3(nx, ny, nz, bx, by, bz)
                    npx, npy, npz = nx - nb * bx, ny - nb * by, nz - nb * bz
                    go = go & (lm.norm3(apx, apy, apz) > 1e-6) & (lm.norm3(npx, npy, npz) > 1e-6)
                    ramp = ti.min(1.0, (bend - TWIST_MIN_BEND) / (TWIST_FULL_BEND - TWIST_MIN_BEND))
                    cx, cy, cz = lm.cross(apx, apy, apz, npx, npy, npz)
                    h = 0.5 * (ramp * lt.atan2(lm.dot3(bx, by, bz, cx, cy, cz), lm.dot3(apx, apy, apz, npx, npy, npz)))
                    sh, ch = lt.sin_cos(h)
                    tx_, ty_, tz_, tw_ = lm.qnormalize(*lm.qmul(bx * sh, by * sh, bz * sh, ch, qx, qy, qz, qw))
                    outx, outy = ti.select(go, tx_, qx), ti.select(go, ty_, qy)
                    outz, outw = ti.select(go, tz_, qz), ti.select(go, tw_, qw)
        return outx, outy, outz, outw

    @ti.func
    def two_bone_swing(s, j, qx, qy, qz, qw, ix, iy, iz, iw, jx, jy, jz, on, kind: ti.template(),
                       axes: ti.template(), offset: ti.template(), lo: ti.template(), hi: ti.template(),
                       lim_p: ti.template(), lim_h: ti.template(), cone: ti.template(), dof_start: ti.template(),
                       child_start: ti.template(), child_list: ti.template(), active: ti.template()):
        """fabrik.two_bone_swing per lane: (the rotation of j, the lanes where the limb was solved)."""
        outx, outy, outz, outw = qx, qy, qz, qw
        ok = on & (V(0.0) > 0.0)
        c, _n = last_active(j, child_start, child_list, active)
        if c >= 0 and kind[c] == 1:
            g, n_g = last_active(c, child_start, child_list, active)
            if n_g == 1:
                og = offset[g]
                end = g
                bx, by, bz = V(og.x), V(og.y), V(og.z)
                h, n_h = last_active(g, child_start, child_list, active)
                if n_h == 1 and kind[h] == 0 and child_start[h + 1] == child_start[h]:
                    end = h
                    oh = offset[h]
                    hx, hy, hz = lm.qrot(lx[s, g], ly[s, g], lz[s, g], lw[s, g], oh.x, oh.y, oh.z)
                    bx, by, bz = og.x + hx, og.y + hy, og.z + hz
                ax = axes[c, 0]
                a = offset[c]
                bd = lm.dot3(bx, by, bz, ax.x, ax.y, ax.z)
                qpx, qpy, qpz = bx - bd * ax.x, by - bd * ax.y, bz - bd * ax.z  # b across the axis
                A = lm.dot3(a.x, a.y, a.z, qpx, qpy, qpz)
                B = lm.dot3(a.x, a.y, a.z, *lm.cross(ax.x, ax.y, ax.z, qpx, qpy, qpz))
                C = lm.dot3(a.x, a.y, a.z, bd * ax.x, bd * ax.y, bd * ax.z)
                vwx, vwy, vwz = to_base(s, end, ix, iy, iz, iw, jx, jy, jz)  # want
                want2 = lm.dot3(vwx, vwy, vwz, vwx, vwy, vwz)
                D = 0.5 * (want2 - a.norm_sqr() - lm.dot3(bx, by, bz, bx, by, bz))
                R = ti.sqrt(A * A + B * B)
                ok = on & (R > 1e-9) & (want2 > 1e-12)
                if lm.any_lane(ok):
                    d = dof_start[c]
                    phi = lt.atan2(B, A)
                    spread = lt.acos(ti.math.clamp((D - C) / R, -1.0, 1.0))
                    now = lt.twist_angle(lx[s, c], ly[s, c], lz[s, c], lw[s, c], ax.x, ax.y, ax.z)
                    t = V(0.0)
                    best = V(1e30)
                    for k in ti.static(range(2)):
                        cand = ti.math.clamp(lm.wrap_angle(phi + (1.0 - 2.0 * k) * spread), lo[d], hi[d])
                        sc, cc = lt.sin_cos(cand)
                        score = ti.abs(C + A * cc + B * sc - D) * 1e3 + ti.abs(cand - now)
                        t = ti.select(score < best, cand, t)
                        best = ti.select(score < best, score, best)
                    ux, uy, uz = lm.normalized(vwx, vwy, vwz)
                    hx, hy, hz, hw = lt.axis_angle(ax.x, ax.y, ax.z, t)
                    vx, vy, vz = lm.qrot(hx, hy, hz, hw, bx, by, bz)
                    vx, vy, vz = a.x + vx, a.y + vy, a.z + vz
                    px, py, pz = lm.normalized(*lm.qrot(qx, qy, qz, qw, vx, vy, vz))
                    sx, sy, sz, sw = lm.swing(px, py, pz, ux, uy, uz)
                    mx, my, mz, mw = lm.qnormalize(*lm.qmul(sx, sy, sz, sw, qx, qy, qz, qw))
                    # the swivel about j -> g toward the proposed hinge, kept only if it lands g no farther off
                    nx_, ny_, nz_ = lm.qrot(mx, my, mz, mw, a.x, a.y, a.z)
                    dn = lm.dot3(nx_, ny_, nz_, ux, uy, uz)
                    nx_, ny_, nz_ = nx_ - dn * ux, ny_ - dn * uy, nz_ - dn * uz
                    px, py, pz = to_base(s, c, ix, iy, iz, iw, jx, jy, jz)  # u_want
                    ex, ey, ez = wx[s, end] - wx[s, c], wy[s, end] - wy[s, c], wz[s, end] - wz[s, c]
                    bend = lm.norm3(*lm.cross(px, py, pz, *lm.qrot(ix, iy, iz, iw, ex, ey, ez))) / ti.max(
                        lm.norm3(px, py, pz) * lm.norm3(ex, ey, ez), 1e-12)
                    dw = lm.dot3(px, py, pz, ux, uy, uz)
                    px, py, pz = px - dw * ux, py - dw * uy, pz - dw * uz
                    bend = ti.min(bend, lm.norm3(nx_, ny_, nz_) / a.norm())
                    sv = ok & (bend > TWIST_MIN_BEND) & (lm.norm3(px, py, pz) > 1e-9)
                    if lm.any_lane(sv):
                        ramp = ti.min(1.0, (bend - TWIST_MIN_BEND) / (TWIST_FULL_BEND - TWIST_MIN_BEND))
                        turn = ramp * lt.best_angle_about(ux, uy, uz, nx_, ny_, nz_, px, py, pz)
                        sv = sv & (ti.abs(turn) > 1e-5)  # a negligible swivel keeps m
                        if lm.any_lane(sv):
                            ex, ey, ez, ew = lt.axis_angle(ux, uy, uz, turn)
                            ex, ey, ez, ew = lm.qnormalize(*lm.qmul(ex, ey, ez, ew, mx, my, mz, mw))
                            first = a.normalized()
                            off0, off1 = V(0.0), V(0.0)
                            for which in range(2):  # a loop, not two calls: each inlined copy costs compile time
                                cx, cy, cz, cw = mx, my, mz, mw
                                if which == 1:
                                    cx, cy, cz, cw = ex, ey, ez, ew
                                cx, cy, cz, cw = lim.constrain_ball(cx, cy, cz, cw, lo, hi, lim_p, lim_h, dof_start[j],
                                                                    cone[j], first, sv)
                                gx, gy, gz = lm.qrot(cx, cy, cz, cw, vx, vy, vz)
                                off = lm.norm3(gx - vwx, gy - vwy, gz - vwz)
                                off0 = ti.select(which == 0, off, off0)
                                off1 = ti.select(which == 1, off, off1)
                            sv = sv & (off1 <= off0 + 1e-4)
                            mx, my, mz, mw = ti.select(sv, ex, mx), ti.select(sv, ey, my), ti.select(sv, ez, mz), \
                                ti.select(sv, ew, mw)
                    outx, outy, outz, outw = ti.select(ok, mx, qx), ti.select(ok, my, qy), ti.select(ok, mz, qz), \
                        ti.select(ok, mw, qw)
                    if end != g:  # where g goes, so that the hinge recovers t and g keeps its angles
                        vx, vy, vz = lm.qrot(hx, hy, hz, hw, og.x, og.y, og.z)
                        vx, vy, vz = lm.qrot(mx, my, mz, mw, a.x + vx, a.y + vy, a.z + vz)
                        vx, vy, vz = lm.qrot(-ix, -iy, -iz, iw, vx, vy, vz)
                        wx[s, g] = ti.select(ok, jx + vx, wx[s, g])
                        wy[s, g] = ti.select(ok, jy + vy, wy[s, g])
                        wz[s, g] = ti.select(ok, jz + vz, wz[s, g])
        return outx, outy, outz, outw, ok

    return to_base, swing_round, twist_for_hinge_child, two_bone_swing
