"""The general DLS lanes' linear algebra and active set (kernels/dls_general_lanes.py, kernels/dls_lane_null.py):
J M J^T, its Cholesky factor, back substitution and the products with J and J^T over blocks of three rows, the
damped step, the DOFs frozen on a limit, and the escape kick, per lane of a stream's field rows (passed as template
arguments; the module creates no Taichi state). Each is its twin in kernels/dls_system.py or kernels/dls.py with
every scalar a lane of a ``ti.types.vector(L, ti.f32)``."""

import taichi as ti

from crowd_ik.solvers.settings import DLS_KICK as KICK, DLS_LIMIT_EPS as LIMIT_EPS


@ti.func
def products(s, mu2, grp_eff: ti.template(), run_count: ti.template(), runs: ti.template(), G, jac: ti.template(),
             sys: ti.template(), mp: ti.template()):
    """The lower triangle of J M J^T + mu^2 I into sys (dls_system.factor's products), M = diag(mp). The R = 3 G rows
    are G blocks of three, each one effector's (grp_eff); a pair of blocks is summed over the runs of columns both
    effectors move (runs): the other terms are zero, and each sum takes its terms in the same order."""
    zero = ti.Vector.zero(ti.f32, ti.static(mp.n))
    for g in range(G):
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
                sys[s, r, c] = a00 + mu2
                sys[s, r + 1, c] = a10
                sys[s, r + 1, c + 1] = a11 + mu2
                sys[s, r + 2, c] = a20
                sys[s, r + 2, c + 1] = a21
                sys[s, r + 2, c + 2] = a22 + mu2
            else:
                sys[s, r, c], sys[s, r, c + 1], sys[s, r, c + 2] = a00, a01, a02
                sys[s, r + 1, c], sys[s, r + 1, c + 1], sys[s, r + 1, c + 2] = a10, a11, a12
                sys[s, r + 2, c], sys[s, r + 2, c + 1], sys[s, r + 2, c + 2] = a20, a21, a22


@ti.func
def cholesky(s, R, sys: ti.template()):
    """sys's lower triangle (R rows) in place by its Cholesky factor (dls_system.factor); 1 per lane, 0 where round-off
    made it not positive definite."""
    ok = ti.Vector.zero(ti.f32, ti.static(sys.n)) + 1.0
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
    return ok


@ti.func
def back_solve(s, R, sys: ti.template(), y: ti.template()):
    """y <- (L L^T)^-1 y in place, L the factor in sys (dls_system.back_solve)."""
    for r in range(R):  # L z = b
        x = y[s, r]
        for k in range(r):
            x -= sys[s, r, k] * y[s, k]
        y[s, r] = x / sys[s, r, r]
    for rr in range(R):  # L^T y = z
        r = R - 1 - rr
        x = y[s, r]
        for k in range(r + 1, R):
            x -= sys[s, k, r] * y[s, k]
        y[s, r] = x / sys[s, r, r]


@ti.func
def transpose_times(s, grp_eff: ti.template(), run_count: ti.template(), runs: ti.template(), G, C,
                    jac: ti.template(), y: ti.template(), out: ti.template()):
    """out = J^T y over the C columns: each column's sum over the blocks in row order, a block over its effector's
    runs."""
    for d in range(C):
        out[s, d] = ti.Vector.zero(ti.f32, ti.static(out.n))
    for g in range(G):
        a = grp_eff[g]
        r = 3 * g
        y0, y1, y2 = y[s, r], y[s, r + 1], y[s, r + 2]
        for q in range(run_count[a, a]):
            for d in range(runs[a, a, q, 0], runs[a, a, q, 1]):
                out[s, d] = out[s, d] + jac[s, r, d] * y0 + jac[s, r + 1, d] * y1 + jac[s, r + 2, d] * y2


@ti.func
def times(s, grp_eff: ti.template(), run_count: ti.template(), runs: ti.template(), G, jac: ti.template(),
          x: ti.template(), out: ti.template()):
    """out = J x over the R = 3 G rows, a block's rows over its effector's runs."""
    for g in range(G):
        a = grp_eff[g]
        r = 3 * g
        zero = ti.Vector.zero(ti.f32, ti.static(out.n))
        o0, o1, o2 = zero, zero, zero
        for q in range(run_count[a, a]):
            for d in range(runs[a, a, q, 0], runs[a, a, q, 1]):
                v = x[s, d]
                o0 += jac[s, r, d] * v
                o1 += jac[s, r + 1, d] * v
                o2 += jac[s, r + 2, d] * v
        out[s, r], out[s, r + 1], out[s, r + 2] = o0, o1, o2


@ti.func
def solve_step(s, act, lam2, joint_w: ti.template(), grp_eff: ti.template(), run_count: ti.template(),
               runs: ti.template(), G, C, jac: ti.template(), sys: ti.template(), e0: ti.template(), yv: ti.template(),
               mp: ti.template(), fr: ti.template(), ga: ti.template(), st: ti.template()):
    """dls_system.solve_step without secondary terms, per lane: st = W J^T (J W J^T + lam^2 I)^-1 e0 in the lanes
    act (W = joint weight times fr); returns 1 per lane, 0 where the float32 Cholesky failed."""
    R = 3 * G
    for d in range(C):
        mp[s, d] = joint_w[d] * fr[s, d]
    products(s, lam2, grp_eff, run_count, runs, G, jac, sys, mp)
    ok = cholesky(s, R, sys)
    for r in range(R):
        yv[s, r] = e0[s, r]
    back_solve(s, R, sys, yv)
    transpose_times(s, grp_eff, run_count, runs, G, C, jac, yv, ga)
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
