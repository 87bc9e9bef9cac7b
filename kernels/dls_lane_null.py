"""The general DLS lanes' secondary terms (kernels/dls_general_lanes.py with `sec`): rest, velocity and balance in the
null space of the targets' rows, per lane, as kernels/dls_system.py computes them for one character: the term S of
the objective, the balance rows Jb, eb and the gradient g of the rest and velocity terms, and the five-phase
task-priority step (dls_system.solve_step's docstring: d1 = J1^+ e1; N1's factor, damped by mu only; Hb = Jb N1;
z from the 2 x 2 system of the projected balance rows; d = d1 + N1 z).

A factory over the kernel's stream fields; it owns the fields only the secondary terms use (made when the kernel is
built: importing the module creates no Taichi state). The balance rows are not rows of the lanes' system: they act
only through z, so they live in fields of their own (jb, eb) instead of blocks of jac.
"""

import taichi as ti

from crowd_ik.kernels import dls_lane_steps as dl
from crowd_ik.kernels import dls_lane_system as dsys
from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels.lane_plan import lane_rows


def per_stream_values(max_joints: int, max_cols: int) -> int:
    """Lane values the secondary terms' fields hold per stream (for dls_general_lanes.max_streams)."""
    return 8 * max_joints + 10 * max_cols + 2


def secondary(F: dict, S: int, max_joints: int, max_cols: int) -> tuple:
    """(start, terms, rows, step) over the fields of F (dls_general_lanes.general_solver's dict of them) and the fields
    made here for S streams: th0, q0* the start pose (the velocity term's reference); cm* per joint the weighted
    points below it (dls_system's Q_COM); per column gv (g), mg (M g), zv (z), dv (d1), cv (a product's input), jb
    and hb (2 slots: the balance rows and their projection Hb); eb (the balance rows' aim)."""
    V = F["V"]
    L = V.n
    lx, ly, lz, lw, px, py, pz, th = (F[k] for k in ("lx", "ly", "lz", "lw", "px", "py", "pz", "th"))
    jac, sys, e0, yv, mp, fr, ga, st = (F[k] for k in ("jac", "sys", "e0", "yv", "mp", "fr", "ga", "st"))
    dax, day, daz, parent_rot = F["dax"], F["day"], F["daz"], F["parent_rot"]
    th0, gv, mg, zv, dv, cv = lane_rows(L, (S, max_cols), 6)
    q0x, q0y, q0z, q0w, cmx, cmy, cmz, cmw = lane_rows(L, (S, max_joints), 8)
    jb, hb = lane_rows(L, (S, 2, max_cols), 2)
    (eb,) = lane_rows(L, (S, 2), 1)

    @ti.func
    def start(s, on, J, C):
        """The pose just projected is the start pose (the velocity term's reference) in the lanes `on`."""
        dl.copy_pose(s, on, J, C, (th, lx, ly, lz, lw), (th0, q0x, q0y, q0z, q0w))

    @ti.func
    def start_offset(s, j):
        """The rotation vectors log(q) and log(q q0^-1) of joint j's local rotation q (q0 its start)."""
        qx, qy, qz, qw = lx[s, j], ly[s, j], lz[s, j], lw[s, j]
        ax, ay, az = dl.qlog(qx, qy, qz, qw)
        bx, by, bz = dl.qlog(*lm.qmul(qx, qy, qz, qw, -q0x[s, j], -q0y[s, j], -q0z[s, j], q0w[s, j]))
        return ax, ay, az, bx, by, bz

    @ti.func
    def terms(s, parent: ti.template(), kind: ti.template(), jmode: ti.template(), dof_start: ti.template(),
              com_w: ti.template(), support_w: ti.template(), rest_w, vel_w, bal_w):
        """dls_system.objective's secondary part per lane: (S, the balance error |(c - s)_xz|)."""
        sec = V(0.0)
        berr = V(0.0)
        if rest_w > 0.0 or vel_w > 0.0:
            for j in range(parent.shape[0]):
                k = kind[j]
                d0 = dof_start[j]
                if k > 0:
                    if jmode[j] == 1:
                        for c in range(k):
                            t = th[s, d0 + c]
                            dt = t - th0[s, d0 + c]
                            sec += rest_w * t * t + vel_w * dt * dt
                    else:
                        ax, ay, az, bx, by, bz = start_offset(s, j)
                        sec += rest_w * (ax * ax + ay * ay + az * az) + vel_w * (bx * bx + by * by + bz * bz)
        if bal_w > 0.0:
            bx, bz = V(0.0), V(0.0)  # c - s
            for j in range(parent.shape[0]):
                mx, mz = px[s, j], pz[s, j]
                p = parent[j]
                if p >= 0:
                    mx, mz = 0.5 * (px[s, p] + px[s, j]), 0.5 * (pz[s, p] + pz[s, j])
                bx += com_w[j] * mx - support_w[j] * px[s, j]
                bz += com_w[j] * mz - support_w[j] * pz[s, j]
            bb = bx * bx + bz * bz
            sec += bal_w * bb
            berr = ti.sqrt(bb)
        return sec, berr

    @ti.func
    def rows(s, parent: ti.template(), kind: ti.template(), jmode: ti.template(), axes: ti.template(),
             dof_start: ti.template(), com_w: ti.template(), support_w: ti.template(), rest_w, vel_w, bal_w, C):
        """dls_system.build_system's secondary part per lane, after the row builder (whose column axes it reads): the
        balance rows jb and their aim eb (bal_w > 0), and g = -(alpha rho + beta nu) in gv (rho, nu in the columns'
        coordinates; 0 in the root's columns)."""
        J = parent.shape[0]
        for d in range(C):
            jb[s, 0, d], jb[s, 1, d], gv[s, d] = V(0.0), V(0.0), V(0.0)
        if bal_w > 0.0:
            sw = ti.sqrt(bal_w)
            # cm*[n] = (sum a_j p_j, sum a_j) over the weighted points strictly below joint n: the midpoint of the bone
            # ending at j (a_j = com_w[j]) and a foot at j (a_j = -support_w[j])
            for j in range(J):
                cmx[s, j], cmy[s, j], cmz[s, j], cmw[s, j] = V(0.0), V(0.0), V(0.0), V(0.0)
            for jj in range(J - 1):
                j = J - 1 - jj
                p = parent[j]
                cw, sp = com_w[j] * 0.5, support_w[j]
                cmx[s, p] += cw * (px[s, p] + px[s, j]) - sp * px[s, j] + cmx[s, j]
                cmy[s, p] += cw * (py[s, p] + py[s, j]) - sp * py[s, j] + cmy[s, j]
                cmz[s, p] += cw * (pz[s, p] + pz[s, j]) - sp * pz[s, j] + cmz[s, j]
                cmw[s, p] += com_w[j] - sp + cmw[s, j]
            eb[s, 0] = -sw * (cmx[s, 0] - support_w[0] * px[s, 0])  # c - s (the root has no bone)
            eb[s, 1] = -sw * (cmz[s, 0] - support_w[0] * pz[s, 0])
            for n in range(J):  # the columns' world axes: the row builder's da*
                kd = kind[n]
                if kd > 0:
                    w = cmw[s, n]
                    hx, hy, hz = cmx[s, n] - w * px[s, n], cmy[s, n] - w * py[s, n], cmz[s, n] - w * pz[s, n]
                    for d in range(dof_start[n], dof_start[n] + kd):
                        qx, qy, qz = lm.cross(dax[s, d], day[s, d], daz[s, d], hx, hy, hz)
                        jb[s, 0, d] = sw * qx
                        jb[s, 1, d] = sw * qz
        if rest_w > 0.0 or vel_w > 0.0:
            for j in range(J):
                k = kind[j]
                d0 = dof_start[j]
                if k > 0:
                    if jmode[j] == 1:
                        for c in range(k):
                            t = th[s, d0 + c]
                            gv[s, d0 + c] = -(rest_w * t + vel_w * (t - th0[s, d0 + c]))
                    else:
                        ax, ay, az, aw = parent_rot(s, j, parent)
                        r0, r1, r2, n0, n1, n2 = start_offset(s, j)
                        r0, r1, r2 = lm.qrot(ax, ay, az, aw, r0, r1, r2)
                        n0, n1, n2 = lm.qrot(ax, ay, az, aw, n0, n1, n2)
                        gv[s, d0] = -(rest_w * r0 + vel_w * n0)
                        gv[s, d0 + 1] = -(rest_w * r1 + vel_w * n1)
                        gv[s, d0 + 2] = -(rest_w * r2 + vel_w * n2)

    @ti.func
    def step(s, act, lam2, mu2, zmax, rest_w, vel_w, bal_w, joint_w: ti.template(), grp_eff: ti.template(),
             run_count: ti.template(), runs: ti.template(), G, C):
        """dls_system.solve_step with the secondary terms, per lane: st = d1 + N1 z in the lanes act (z scaled to at
        most zmax per column); returns 1 per lane, 0 where a float32 Cholesky failed. As there the phases run in one
        loop, so that each product, factorisation and substitution is inlined once (a faster compile)."""
        R = 3 * G
        for d in range(C):
            w = joint_w[d] * fr[s, d]
            mp[s, d] = w
            m = w * gv[s, d] / (lam2 + w * (rest_w + vel_w))
            mg[s, d] = m
            zv[s, d] = m
        ok = lam2 * 0.0 + 1.0
        eh0, eh1 = lam2 * 0.0, lam2 * 0.0  # the balance rows' aim left after d1
        # phase 0: d1 = J1^+ e1 (lam); 1: N1's factor (mu), Hb's first row; 2: its second row, z; 3: N1 z, d
        for ph in range(4):
            if ph <= 1:
                mu = lam2
                if ph == 1:
                    mu = lam2 * 0.0 + mu2
                dsys.products(s, mu, grp_eff, run_count, runs, G, jac, sys, mp)
                ok = ti.min(ok, dsys.cholesky(s, R, sys))
            if ph == 0 or ph == 3 or bal_w > 0.0:
                if ph == 0:
                    for r in range(R):
                        yv[s, r] = e0[s, r]
                else:
                    if ph == 3:  # z scaled to at most zmax per column
                        zm = lam2 * 0.0
                        for d in range(C):
                            zm = ti.max(zm, ti.abs(zv[s, d]))
                        big = zm > zmax
                        scale = ti.select(big, zmax / ti.select(big, zm, 1.0), 1.0)
                        for d in range(C):
                            zv[s, d] *= scale
                            cv[s, d] = zv[s, d]
                    else:  # Hb = Jb - Jb M' J1^T (J1 M' J1^T + mu^2 I)^-1 J1, a row at a time
                        for d in range(C):
                            cv[s, d] = mp[s, d] * jb[s, ph - 1, d]
                    dsys.times(s, grp_eff, run_count, runs, G, jac, cv, yv)
                dsys.back_solve(s, R, sys, yv)
                dsys.transpose_times(s, grp_eff, run_count, runs, G, C, jac, yv, ga)
                if ph == 0:
                    for d in range(C):
                        dv[s, d] = mp[s, d] * ga[s, d]
                    if bal_w > 0.0:
                        eh0, eh1 = eb[s, 0], eb[s, 1]
                        for d in range(C):
                            eh0 -= jb[s, 0, d] * dv[s, d]
                            eh1 -= jb[s, 1, d] * dv[s, d]
                elif ph <= 2:
                    for d in range(C):
                        hb[s, ph - 1, d] = jb[s, ph - 1, d] - ga[s, d]
                    if ph == 2:  # z: the 2 x 2 system of the projected balance rows
                        a00, a01, a11 = lam2, lam2 * 0.0, lam2
                        for d in range(C):
                            w = mp[s, d]
                            m2 = w * lam2 / (lam2 + w * (rest_w + vel_w))
                            h0, h1 = hb[s, 0, d], hb[s, 1, d]
                            a00 += h0 * m2 * h0
                            a01 += h0 * m2 * h1
                            a11 += h1 * m2 * h1
                            eh0 -= h0 * mg[s, d]
                            eh1 -= h1 * mg[s, d]
                        det = a00 * a11 - a01 * a01
                        y0 = (a11 * eh0 - a01 * eh1) / det
                        y1 = (a00 * eh1 - a01 * eh0) / det
                        for d in range(C):
                            w = mp[s, d]
                            m2 = w * lam2 / (lam2 + w * (rest_w + vel_w))
                            zv[s, d] += m2 * (hb[s, 0, d] * y0 + hb[s, 1, d] * y1)
                else:  # d = d1 + z - M' J1^T (J1 M' J1^T + mu^2 I)^-1 J1 z
                    for d in range(C):
                        st[s, d] = ti.select(act, dv[s, d] + (zv[s, d] - mp[s, d] * ga[s, d]), st[s, d])
        return ok

    return start, terms, rows, step
