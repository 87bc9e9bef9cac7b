"""The general DLS lanes' linear algebra and active set (kernels/dls_general_lanes.py): the damped step by Cholesky
over blocks of three rows, the DOFs frozen on a limit, and the escape kick, per lane of a stream's field rows (passed
as template arguments; the module creates no Taichi state). Each is its twin in kernels/dls_system.py or
kernels/dls.py with every scalar a lane of a ``ti.types.vector(L, ti.f32)``."""

import taichi as ti

from crowd_ik.solvers.settings import DLS_KICK as KICK, DLS_LIMIT_EPS as LIMIT_EPS


@ti.func
def solve_step(s, act, lam2, joint_w: ti.template(), grp_eff: ti.template(), run_count: ti.template(),
               runs: ti.template(), G, C, jac: ti.template(), sys: ti.template(), e0: ti.template(), yv: ti.template(),
               mp: ti.template(), fr: ti.template(), ga: ti.template(), st: ti.template()):
    """dls_system.solve_step without secondary terms, per lane: st = W J^T (J W J^T + lam^2 I)^-1 e0 in the lanes
    act (W = joint weight times fr); returns 1 per lane, 0 where the float32 Cholesky failed. The R = 3 G rows are
    G blocks of three, each one effector's (grp_eff); J W J^T is built a pair of blocks at a time over the runs
    of columns both effectors move (runs), and J^T y a block at a time over its effector's runs: the other terms
    are zero, and each sum takes its terms in the same order."""
    R = 3 * G
    zero = ti.Vector.zero(ti.f32, ti.static(mp.n))
    for d in range(C):
        mp[s, d] = joint_w[d] * fr[s, d]
        ga[s, d] = zero
    for g in range(G):  # dls_system.factor's products
        for h in range(g + 1):
            a, b = grp_eff[g], grp_eff[h]
            r, c = 3 * g, 3 * h
            a00, a01, a02, a10, a11, a12, a20, a21, a22 = zero, zero, zero, zero, zero, zero, \
                zero, zero, zero
            for q in range(run_count[a, b]):
                for d in range(runs[a, b, q, 0], runs[a, b, q, 1]):
                    m = mp[s, d]
                    t0, t1, t2 = jac[s, r, d] * m, jac[s, r + 1, d] * m, jac[s, r + 2, d] * m
                    b0, b1, b2 = jac[s, c, d], jac[s, c + 1, d], jac[s, c + 2, d]
                    a00 += t0 * b0
                    a01 += t0 * b1
                    a02 += t0 * b2
                    a10 += t1 * b0
                    a11 += t1 * b1
                    a12 += t1 * b2
                    a20 += t2 * b0
                    a21 += t2 * b1
                    a22 += t2 * b2
            if g == h:
                sys[s, r, c] = a00 + lam2
                sys[s, r + 1, c] = a10
                sys[s, r + 1, c + 1] = a11 + lam2
                sys[s, r + 2, c] = a20
                sys[s, r + 2, c + 1] = a21
                sys[s, r + 2, c + 2] = a22 + lam2
            else:
                sys[s, r, c], sys[s, r, c + 1], sys[s, r, c + 2] = a00, a01, a02
                sys[s, r + 1, c], sys[s, r + 1, c + 1], sys[s, r + 1, c + 2] = a10, a11, a12
                sys[s, r + 2, c], sys[s, r + 2, c + 1], sys[s, r + 2, c + 2] = a20, a21, a22
    ok = zero + 1.0
    for c in range(R):
        v = sys[s, c, c]
        for k in range(c):
            v -= sys[s, c, k] * sys[s, c, k]
        bad = v <= 0.0
        ok = ti.select(bad, 0.0, ok)
        lc = ti.sqrt(ti.select(bad, 1.0, v))
        sys[s, c, c] = lc
        for r in range(c + 1, R):
            x = sys[s, r, c]
            for k in range(c):
                x -= sys[s, r, k] * sys[s, c, k]
            sys[s, r, c] = x / lc
    for r in range(R):  # dls_system.back_solve: L z = b, then L^T y = z
        x = e0[s, r]
        for k in range(r):
            x -= sys[s, r, k] * yv[s, k]
        yv[s, r] = x / sys[s, r, r]
    for rr in range(R):
        r = R - 1 - rr
        x = yv[s, r]
        for k in range(r + 1, R):
            x -= sys[s, k, r] * yv[s, k]
        yv[s, r] = x / sys[s, r, r]
    for g in range(G):  # J^T y, each column's sum over the blocks in row order
        a = grp_eff[g]
        r = 3 * g
        y0, y1, y2 = yv[s, r], yv[s, r + 1], yv[s, r + 2]
        for q in range(run_count[a, a]):
            for d in range(runs[a, a, q, 0], runs[a, a, q, 1]):
                ga[s, d] = ga[s, d] + jac[s, r, d] * y0 + jac[s, r + 1, d] * y1 + jac[s, r + 2, d] * y2
    for d in range(C):
        st[s, d] = ti.select(act, mp[s, d] * ga[s, d], st[s, d])
    return ok

@ti.func
def freeze_outward(s, act, parent: ti.template(), kind: ti.template(), jmode: ti.template(), lo: ti.template(),
                   hi: ti.template(), dof_start: ti.template(), th: ti.template(), st: ti.template(),
                   fr: ti.template()):
    """dls.freeze_outward in the lanes act: freeze the free angle DOFs on a limit whose step points outward."""
    n = ti.Vector.zero(ti.f32, ti.static(fr.n))
    for j in range(parent.shape[0]):
        if jmode[j] == 1:
            for c in range(kind[j]):
                d = dof_start[j] + c
                t, u = th[s, d], st[s, d]
                out = act & (fr[s, d] > 0.0) & (((t <= lo[d] + LIMIT_EPS) & (u < 0.0))
                                                 | ((t >= hi[d] - LIMIT_EPS) & (u > 0.0)))
                fr[s, d] = ti.select(out, 0.0, fr[s, d])
                n += ti.select(out, 1.0, 0.0)
    return n

@ti.func
def kick_step(s, on, parent: ti.template(), kind: ti.template(), jmode: ti.template(), lo: ti.template(),
              hi: ti.template(), dof_start: ti.template(), joint_w: ti.template(), C, th: ti.template(),
              st: ti.template(), fr: ti.template()):
    """dls.kick_step in the lanes `on`: st moves every weighted angle DOF frozen on a limit inward; returns how
    many per lane."""
    n = ti.Vector.zero(ti.f32, ti.static(fr.n))
    for d in range(C):
        st[s, d] = ti.select(on, 0.0, st[s, d])
    for j in range(parent.shape[0]):
        if jmode[j] == 1:
            for c in range(kind[j]):
                d = dof_start[j] + c
                size = ti.min(KICK, 0.5 * (hi[d] - lo[d]))
                if joint_w[d] > 0.0 and size > 0.0:
                    t = th[s, d]
                    frozen = on & (fr[s, d] == 0.0)
                    low = frozen & (t <= lo[d] + LIMIT_EPS)
                    high = frozen & (low == 0) & (t >= hi[d] - LIMIT_EPS)
                    st[s, d] = ti.select(low, size, ti.select(high, -size, st[s, d]))
                    n += ti.select(low | high, 1.0, 0.0)
    return n
