"""The general DLS lanes' rows (kernels/dls_general_lanes.py): dls_system.build_system without its secondary terms,
per lane, into the request's row layout: the aimed error e0 and the Jacobian jac of a stream's lanes. A factory
over the kernel's stream fields (no Taichi state of its own). Each DOF column's world axis is computed once per
build into da*, for every effector's walk to the root (and the balance rows of kernels/dls_lane_null.py)."""

import taichi as ti

from crowd_ik.kernels import dls_lane_steps as dl
from crowd_ik.kernels import lane_math as lm
from crowd_ik.solvers.settings import DLS_ORI_CLAMP as ORI_CLAMP


def row_builder(F: dict, rot: bool, free_root: bool):
    """build(s, ...) over the fields of F (dls_general_lanes.general_solver's dict of them: the pose p*, r*, angles th,
    targets t*, o*, tq*, rows jac, e0, the columns' world axes da*, and its target and parent_rot)."""
    V = F["V"]
    px, py, pz, rx, ry, rz, rw, th = (F[k] for k in ("px", "py", "pz", "rx", "ry", "rz", "rw", "th"))
    tw, ox, oy, oz = F["tw"], F["ox"], F["oy"], F["oz"]
    tqx, tqy, tqz, tqw, tqk = F["tqx"], F["tqy"], F["tqz"], F["tqw"], F["tqk"]
    jac, e0, target, parent_rot = F["jac"], F["e0"], F["target"], F["parent_rot"]
    dax, day, daz = F["dax"], F["day"], F["daz"]

    @ti.func
    def build(s, parent: ti.template(), kind: ti.template(), jmode: ti.template(), axes: ti.template(),
              dof_start: ti.template(), eff_joint: ti.template(), eff_axis: ti.template(), eff_lim: ti.template(),
              eff_rows: ti.template(), length, R, C):
        """dls_system.build_system without its secondary terms, per lane, into the request's row layout
        (eff_rows bits: 1 position rows, 2 axis rows and a zero row, 4 rotation rows)."""
        for r, d in ti.ndrange(R, C):
            jac[s, r, d] = V(0.0)
        for n in range(parent.shape[0]):  # each DOF column's world axis, once per joint (the walks below share them)
            kd = kind[n]
            if kd > 0:
                d0 = dof_start[n]
                ax, ay, az, aw = parent_rot(s, n, parent)
                t1 = th[s, d0]
                if kd >= 2:
                    t1 = th[s, d0 + 1]
                cols = dl.dof_axes(kd, jmode[n] == 1, axes[n, 0], axes[n, 1], ax, ay, az, aw, th[s, d0], t1)
                for c in ti.static(range(3)):
                    if c < kd:
                        dax[s, d0 + c], day[s, d0 + c], daz[s, d0 + c] = cols[3 * c], cols[3 * c + 1], cols[3 * c + 2]
        r = 0
        for e in range(eff_joint.shape[0]):
            if eff_rows[e] > 0:
                sw = ti.sqrt(ti.max(tw[s, e], 0.0))
                k = eff_joint[e]
                ex, ey, ez = px[s, k], py[s, k], pz[s, k]
                reach, dmax = eff_lim[e, 0], eff_lim[e, 1]
                gx, gy, gz = target(s, e, C)
                cx, cy, cz = gx - px[s, 0], gy - py[s, 0], gz - pz[s, 0]
                dist = lm.norm3(cx, cy, cz)
                far = dist > reach + dmax
                sc = (reach + dmax) / ti.select(far, dist, 1.0)
                gx = ti.select(far, px[s, 0] + cx * sc, gx)
                gy = ti.select(far, py[s, 0] + cy * sc, gy)
                gz = ti.select(far, pz[s, 0] + cz * sc, gz)
                dx, dy, dz = gx - ex, gy - ey, gz - ez
                dn = lm.norm3(dx, dy, dz)
                big = dn > dmax
                dc = dmax / ti.select(big, dn, 1.0)
                e0[s, r] = sw * ti.select(big, dx * dc, dx)
                e0[s, r + 1] = sw * ti.select(big, dy * dc, dy)
                e0[s, r + 2] = sw * ti.select(big, dz * dc, dz)
                if ti.static(free_root):  # the whole body translates: identity in the position rows
                    for c in ti.static(range(3)):
                        jac[s, r + c, C - 3 + c] = sw
                ori = tw[s, e] < 0.0  # no lane
                u1x, u1y, u1z, u2x, u2y, u2z = sw * 0.0, sw * 0.0, sw * 0.0, sw * 0.0, sw * 0.0, sw * 0.0
                axis_rows = eff_rows[e] & 2
                rr = r + 3  # the rotation rows (with `rot`): after the position and axis rows
                if axis_rows != 0:
                    rr += 3
                sr = sw * 0.0
                if ti.static(rot):
                    if eff_rows[e] & 4:
                        sr = ti.sqrt(ti.max(tqk[s, e], 0.0))
                        vx_, vy_, vz_ = dl.qlog(*lm.qmul(tqx[s, e], tqy[s, e], tqz[s, e], tqw[s, e], -rx[s, k],
                                                        -ry[s, k], -rz[s, k], rw[s, k]))
                        ang = lm.norm3(vx_, vy_, vz_)
                        cl = ang > ORI_CLAMP
                        ac = ORI_CLAMP / ti.select(cl, ang, 1.0)
                        e0[s, rr] = sr * length * ti.select(cl, vx_ * ac, vx_)
                        e0[s, rr + 1] = sr * length * ti.select(cl, vy_ * ac, vy_)
                        e0[s, rr + 2] = sr * length * ti.select(cl, vz_ * ac, vz_)
                if axis_rows != 0:
                    ori = ox[s, e] * ox[s, e] + oy[s, e] * oy[s, e] + oz[s, e] * oz[s, e] > 0.0
                    a = eff_axis[e]
                    ax, ay, az = lm.normalized(*lm.qrot(rx[s, k], ry[s, k], rz[s, k], rw[s, k], a.x, a.y, a.z))
                    wx, wy, wz = dl.swing_vector(ax, ay, az, ox[s, e], oy[s, e], oz[s, e])
                    ang = lm.norm3(wx, wy, wz)
                    cl = ang > ORI_CLAMP
                    ac = ORI_CLAMP / ti.select(cl, ang, 1.0)
                    wx, wy, wz = ti.select(cl, wx * ac, wx), ti.select(cl, wy * ac, wy), ti.select(cl, wz * ac, wz)
                    u1x, u1y, u1z = dl.perpendicular(ax, ay, az)
                    u2x, u2y, u2z = lm.cross(ax, ay, az, u1x, u1y, u1z)
                    e0[s, r + 3] = ti.select(ori, sw * length * lm.dot3(wx, wy, wz, u1x, u1y, u1z), 0.0)
                    e0[s, r + 4] = ti.select(ori, sw * length * lm.dot3(wx, wy, wz, u2x, u2y, u2z), 0.0)
                n = k
                while n >= 0:
                    kd = kind[n]
                    if kd > 0:
                        hx, hy, hz = ex - px[s, n], ey - py[s, n], ez - pz[s, n]
                        for d in range(dof_start[n], dof_start[n] + kd):
                            wx, wy, wz = dax[s, d], day[s, d], daz[s, d]
                            qx, qy, qz = lm.cross(wx, wy, wz, hx, hy, hz)
                            jac[s, r, d] = sw * qx
                            jac[s, r + 1, d] = sw * qy
                            jac[s, r + 2, d] = sw * qz
                            if axis_rows != 0:
                                a1 = sw * length * lm.dot3(wx, wy, wz, u1x, u1y, u1z)
                                a2 = sw * length * lm.dot3(wx, wy, wz, u2x, u2y, u2z)
                                jac[s, r + 3, d] = ti.select(ori, a1, 0.0)
                                jac[s, r + 4, d] = ti.select(ori, a2, 0.0)
                            if ti.static(rot):
                                if eff_rows[e] & 4:
                                    jac[s, rr, d] = sr * length * wx
                                    jac[s, rr + 1, d] = sr * length * wy
                                    jac[s, rr + 2, d] = sr * length * wz
                    n = parent[n]
                r = rr
                if eff_rows[e] & 4:
                    r += 3

    return build
