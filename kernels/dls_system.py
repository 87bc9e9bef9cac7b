"""The DLS step's linear system (kernels/dls.py, steps 1-3 and 7 of its docstring): the objective F,
the Jacobian rows and columns, and the damped solve by Cholesky in per-character scratch."""

import taichi as ti

from crowd_ik.kernels.quat import (
    axis_angle, qconj, qmul, qrot, vec3, vec4,
)
from crowd_ik.solvers.settings import (
    DLS_ORI_CLAMP as ORI_CLAMP,
)

from crowd_ik.kernels.dls_pose import (
    FREE, G, HB0, MG, MP, Q_COM, Q_START, STEP, THETA, THETA0, Z, has_orientation, parent_rot, perpendicular, qlog,
    root_point, swing_vector, vec5,
)

ndarray = ti.types.ndarray



@ti.func
def objective(i, parent: ti.template(), kind: ti.template(), jmode: ti.template(), dof_start: ti.template(),
              eff_joint: ti.template(), eff_axis: ti.template(),
              eff_has_axis: ti.template(), eff_lim: ti.template(), root_pos: ti.template(), local_rot: ti.template(),
              rel_pos: ti.template(), world_rot: ti.template(), targets: ti.template(),
              weights: ti.template(), orient: ti.template(), work: ti.template(), qwork: ti.template(),
              com_w: ti.template(), support_w: ti.template(), length, rest_w, vel_w, bal_w,
              rot_t: ti.template(), rot_w: ti.template(), extra: ti.template()):
    """(F, max position error, max(orientation error * L, balance error), S, orientation error * L) of the pose.

    F counts the targets (positions, axes, rotations); S the secondary terms (rest, velocity, balance), which
    exist only with extra bit 2 (the null-space rule), so without it S = 0 and nothing else changes.
    extra (compile time) bit 4: the root is free (root_point adds its translation), and F is |t - p|^2 even for
    a target beyond the fixed root's reach (the root can close that gap). extra bit 1: full rotation targets rot_t (N, E, 4) weighted by rot_w (N, E), each adding
    rot_w * (L * angle)^2 to F and L * angle to the orientation error (angle = |log(q_target q^-1)|).

    F counts each position term as |t - p|^2 - beyond^2, beyond = max(|t - base| - reach, 0), the part
    no pose can remove: the same minimiser and the same comparisons, but for a target out of reach it
    is written as 2 |r| (reach - u.q) - (reach - |q|)(reach + |q|) (r = t - base, u = r / |r|,
    q = p - base), which keeps float32 precision as the chain straightens (F itself stays large).
    """
    f = 0.0
    sec = 0.0
    perr = 0.0
    oerr = 0.0
    berr = 0.0
    base = rel_pos[i, 0]
    rp = root_point(i, root_pos, work, extra)
    for e in range(eff_joint.shape[0]):
        w = weights[i, e]
        if w > 0.0:
            k = eff_joint[e]
            t = targets[i, e] - rp
            d = t - rel_pos[i, k]
            perr = ti.max(perr, d.norm())
            r = t - base
            dist = r.norm()
            reach = eff_lim[e, 0]
            if ti.static(extra & 4):
                reach = 1e30
            if dist > reach:
                q = rel_pos[i, k] - base
                qn = q.norm()
                f += w * (2.0 * (dist * reach - r.dot(q)) - (reach - qn) * (reach + qn))
            else:
                f += w * d.norm_sqr()
            if has_orientation(i, e, eff_has_axis, orient):
                a = qrot(world_rot[i, k], eff_axis[e])
                ang = length * swing_vector(a, orient[i, e]).norm()
                f += w * ang * ang
                oerr = ti.max(oerr, ang)
        if ti.static(extra & 1):
            rw = rot_w[i, e]
            if rw > 0.0:
                ang = length * qlog(qmul(rot_t[i, e], qconj(world_rot[i, eff_joint[e]]))).norm()
                f += rw * ang * ang
                oerr = ti.max(oerr, ang)
    if ti.static(extra & 2):
        if rest_w > 0.0 or vel_w > 0.0:
            for j in range(parent.shape[0]):
                k = kind[j]
                s = dof_start[j]
                if k > 0:
                    if jmode[j] == 1:
                        for c in range(k):
                            th = work[i, THETA, s + c]
                            dv = th - work[i, THETA0, s + c]
                            sec += rest_w * th * th + vel_w * dv * dv
                    else:
                        q = local_rot[i, j]
                        sec += (rest_w * qlog(q).norm_sqr()
                                + vel_w * qlog(qmul(q, qconj(qwork[i, Q_START, j]))).norm_sqr())
        if bal_w > 0.0:
            b = vec3(0.0)  # c - s
            for j in range(parent.shape[0]):
                p = rel_pos[i, j]
                mid = p
                if parent[j] >= 0:
                    mid = 0.5 * (rel_pos[i, parent[j]] + p)
                b += com_w[j] * mid - support_w[j] * p
            bb = b.x * b.x + b.z * b.z
            sec += bal_w * bb
            berr = ti.sqrt(bb)
    return vec5(f, perr, ti.max(oerr, berr), sec, oerr)


@ti.func
def dof_axes(i, j, k, s, angle_joint, parent: ti.template(), axes: ti.template(), root_yaw: ti.template(),
             world_rot: ti.template(), work: ti.template()):
    """World axes (columns) of joint j's DOFs: d(angle) axes from the solver's angles, or world x, y, z."""
    w0 = vec3(1.0, 0.0, 0.0)
    w1 = vec3(0.0, 1.0, 0.0)
    w2 = vec3(0.0, 0.0, 1.0)
    if angle_joint:
        base = parent_rot(i, j, parent, root_yaw, world_rot)
        if k == 1:
            w0 = qrot(base, axes[j, 0])
        elif k == 2:
            w0 = qrot(base, axes[j, 0])
            w1 = qrot(qmul(base, axis_angle(axes[j, 0], work[i, THETA, s])), axes[j, 1])
        else:
            rx = qmul(base, axis_angle(vec3(1.0, 0.0, 0.0), work[i, THETA, s]))
            w0 = qrot(base, vec3(1.0, 0.0, 0.0))
            w1 = qrot(rx, vec3(0.0, 1.0, 0.0))
            w2 = qrot(qmul(rx, axis_angle(vec3(0.0, 1.0, 0.0), work[i, THETA, s + 1])), vec3(0.0, 0.0, 1.0))
    return ti.Matrix.cols([w0, w1, w2])


@ti.func
def build_system(i, parent: ti.template(), kind: ti.template(), jmode: ti.template(), axes: ti.template(),
                 dof_start: ti.template(), eff_joint: ti.template(), eff_axis: ti.template(),
                 eff_has_axis: ti.template(), eff_lim: ti.template(), root_pos: ti.template(),
                 root_yaw: ti.template(), local_rot: ti.template(), rel_pos: ti.template(), world_rot: ti.template(),
                 targets: ti.template(), weights: ti.template(), orient: ti.template(), work: ti.template(),
                 qwork: ti.template(), com_w: ti.template(), support_w: ti.template(), jac: ti.template(),
                 rows: ti.template(), length, rest_w, vel_w, bal_w, rot_t: ti.template(), rot_w: ti.template(),
                 extra: ti.template()):
    """Fill jac[i, :R], rows[i, 0, :R] (the aimed error) and work[i, G]; return R, the number of rows.

    The balance rows (bal_w > 0) come last, after the effectors' rows. extra bit 4 (a free root): the last 3
    columns are the root's translation, identity (times sqrt(weight)) in every effector's position rows and zero
    elsewhere (c - s and rotations do not change when the whole body translates). extra bit 1 (compile time): an effector
    with a full rotation target (rot_w > 0) gets 3 more rows after its position (and axis) rows:
    sqrt(rot_w) L times the world rotation vector log(q_target q^-1) (clamped to ORI_CLAMP), whose column for
    a DOF of world axis w is sqrt(rot_w) L w.
    """
    D = jac.shape[2]
    for r, d in ti.ndrange(jac.shape[1], D):
        jac[i, r, d] = 0.0
    base = rel_pos[i, 0]
    rp = root_point(i, root_pos, work, extra)
    E = eff_joint.shape[0]
    J = parent.shape[0]
    r = 0
    # e = E is the balance term: its walk visits every joint (n = J-1 .. 0) instead of a path to the root
    # (one walk for both keeps a single inlined dof_axes: faster compiles)
    for e in range(E + 1):
        bal = e == E
        sw = 0.0
        sr = 0.0
        if bal:
            sw = ti.sqrt(ti.max(bal_w, 0.0))
        else:
            sw = ti.sqrt(ti.max(weights[i, e], 0.0))
            if ti.static(extra & 1):
                sr = ti.sqrt(ti.max(rot_w[i, e], 0.0))
        if sw > 0.0 or sr > 0.0:
            k = J - 1
            p_eff = vec3(0.0)
            ori = False
            u1 = vec3(0.0)
            u2 = vec3(0.0)
            if bal:
                # qwork[i, Q_COM, n] = (sum a_j p_j, sum a_j) over the weighted points strictly below joint n:
                # the midpoint of the bone ending at j (a_j = com_w[j]) and a foot at j (a_j = -support_w[j])
                for j in range(J):
                    qwork[i, Q_COM, j] = vec4(0.0)
                for jj in range(J - 1):
                    j = J - 1 - jj
                    p = rel_pos[i, j]
                    own = com_w[j] * 0.5 * (rel_pos[i, parent[j]] + p) - support_w[j] * p
                    acc = qwork[i, Q_COM, j]
                    qwork[i, Q_COM, parent[j]] += vec4(own + acc.xyz, com_w[j] - support_w[j] + acc.w)
                total = qwork[i, Q_COM, 0].xyz - support_w[0] * rel_pos[i, 0]  # c - s (the root has no bone)
                rows[i, 0, r] = -sw * total.x
                rows[i, 0, r + 1] = -sw * total.z
            else:
                k = eff_joint[e]
                p_eff = rel_pos[i, k]
                reach = eff_lim[e, 0]
                dmax = eff_lim[e, 1]
                tgt = targets[i, e] - rp
                v = tgt - base
                dist = v.norm()
                if dist > reach + dmax:
                    tgt = base + v * ((reach + dmax) / dist)
                d = tgt - p_eff
                dn = d.norm()
                if dn > dmax:
                    d = d * (dmax / dn)
                for c in ti.static(range(3)):
                    rows[i, 0, r + c] = sw * d[c]
                if ti.static(extra & 4):
                    for c in ti.static(range(3)):
                        jac[i, r + c, D - 3 + c] = sw
                ori = has_orientation(i, e, eff_has_axis, orient)
                if ori:
                    a = qrot(world_rot[i, k], eff_axis[e]).normalized()
                    rv = swing_vector(a, orient[i, e])
                    ang = rv.norm()
                    if ang > ORI_CLAMP:
                        rv = rv * (ORI_CLAMP / ang)
                    u1 = perpendicular(a)
                    u2 = ti.math.cross(a, u1)
                    rows[i, 0, r + 3] = sw * length * rv.dot(u1)
                    rows[i, 0, r + 4] = sw * length * rv.dot(u2)
                if ti.static(extra & 1):
                    if sr > 0.0:
                        rr = r + 3
                        if ori:
                            rr += 2
                        rq = qlog(qmul(rot_t[i, e], qconj(world_rot[i, k])))
                        ang = rq.norm()
                        if ang > ORI_CLAMP:
                            rq = rq * (ORI_CLAMP / ang)
                        for c in ti.static(range(3)):
                            rows[i, 0, rr + c] = sr * length * rq[c]
            n = k
            while n >= 0:
                kd = kind[n]
                if kd > 0:
                    s = dof_start[n]
                    wm = dof_axes(i, n, kd, s, jmode[n] == 1, parent, axes, root_yaw, world_rot, work)
                    lever = p_eff - rel_pos[i, n]
                    if bal:
                        acc = qwork[i, Q_COM, n]
                        lever = acc.xyz - acc.w * rel_pos[i, n]
                    for c in range(kd):
                        col = vec3(wm[0, c], wm[1, c], wm[2, c])
                        dp = ti.math.cross(col, lever)
                        if bal:
                            jac[i, r, s + c] = sw * dp.x
                            jac[i, r + 1, s + c] = sw * dp.z
                        else:
                            for cc in ti.static(range(3)):
                                jac[i, r + cc, s + c] = sw * dp[cc]
                            if ori:
                                jac[i, r + 3, s + c] = sw * length * col.dot(u1)
                                jac[i, r + 4, s + c] = sw * length * col.dot(u2)
                            if ti.static(extra & 1):
                                if sr > 0.0:
                                    rr = r + 3
                                    if ori:
                                        rr += 2
                                    for cc in ti.static(range(3)):
                                        jac[i, rr + cc, s + c] = sr * length * col[cc]
                if bal:
                    n -= 1
                else:
                    n = parent[n]
            if bal:
                r += 2
            else:
                r += 3
                if ori:
                    r += 2
                if ti.static(extra & 1):
                    if sr > 0.0:
                        r += 3
    # g = -(alpha rho + beta nu): rho, nu in the columns' coordinates (world axes for quaternion joints)
    # (the root's columns have no rest or start pose: their g is 0)
    for d in range(D):
        work[i, G, d] = 0.0
    if ti.static(extra & 2):
        if rest_w > 0.0 or vel_w > 0.0:
            for j in range(parent.shape[0]):
                k = kind[j]
                s = dof_start[j]
                if k > 0:
                    if jmode[j] == 1:
                        for c in range(k):
                            th = work[i, THETA, s + c]
                            work[i, G, s + c] = -(rest_w * th + vel_w * (th - work[i, THETA0, s + c]))
                    else:
                        base_rot = parent_rot(i, j, parent, root_yaw, world_rot)
                        q = local_rot[i, j]
                        rho = qrot(base_rot, qlog(q))
                        nu = qrot(base_rot, qlog(qmul(q, qconj(qwork[i, Q_START, j]))))
                        g = -(rest_w * rho + vel_w * nu)
                        for c in ti.static(range(3)):
                            work[i, G, s + c] = g[c]
    return r


@ti.func
def factor(i, R1, lam2, jac: ti.template(), sys: ti.template(), work: ti.template()):
    """sys[i, :R1, :R1] = the Cholesky factor (lower) of J M' J^T + lam^2 I over rows 0..R1, M' = work[i, MP].

    Returns 1, or 0 when round-off made the system not positive definite (the step is then void).
    """
    D = jac.shape[2]
    for r in range(R1):
        for c in range(r + 1):
            acc = 0.0
            for d in range(D):
                acc += jac[i, r, d] * work[i, MP, d] * jac[i, c, d]
            if r == c:
                acc += lam2
            sys[i, r, c] = acc
    ok = 1
    for c in range(R1):  # Cholesky, lower triangle in place
        v = sys[i, c, c]
        for k in range(c):
            v -= sys[i, c, k] * sys[i, c, k]
        if v <= 0.0:
            ok = 0
            v = 1.0
        lc = ti.sqrt(v)
        sys[i, c, c] = lc
        for r in range(c + 1, R1):
            x = sys[i, r, c]
            for k in range(c):
                x -= sys[i, r, k] * sys[i, c, k]
            sys[i, r, c] = x / lc
    return ok


@ti.func
def back_solve(i, R1, slot, rows: ti.template(), sys: ti.template()):
    """rows[i, slot, :R1] <- (L L^T)^-1 rows[i, slot, :R1] with the factor L in sys (see factor)."""
    for r in range(R1):  # L z = b
        x = rows[i, slot, r]
        for k in range(r):
            x -= sys[i, r, k] * rows[i, slot, k]
        rows[i, slot, r] = x / sys[i, r, r]
    for rr in range(R1):  # L^T y = z
        r = R1 - 1 - rr
        x = rows[i, slot, r]
        for k in range(r + 1, R1):
            x -= sys[i, k, r] * rows[i, slot, k]
        rows[i, slot, r] = x / sys[i, r, r]


@ti.func
def solve_step(i, R, Rb, lam2, mu2, zmax, rest_w, vel_w, joint_w: ti.template(), jac: ti.template(),
               rows: ti.template(), sys: ti.template(), work: ti.template(), extra: ti.template()):
    """work[i, STEP] over the free DOFs; returns 1, or 0 when the float32 Cholesky failed (the step is then void).

    Without extra bit 2: Buss's weighted DLS d = W J^T (J W J^T + lam^2 I)^-1 e, W = diag(joint_w) (times FREE).
    With it (rest, velocity or balance terms), the task-priority rule of Siciliano & Slotine 1991 with a damped
    pseudo-inverse (Liegeois 1977 for the gradient term): the Rb = 2 balance rows (last) and the rest and
    velocity terms act in the null space of the R1 = R - Rb target rows J1,
        d1 = J1^+ e1,   J1^+ = W J1^T (J1 W J1^T + lam^2 I)^-1,
        N1 = I - W J1^T (J1 W J1^T + mu^2 I)^-1 J1   (mu = DLS_DAMPING_MIN L: a projector up to mu^2; the
             damped one, with lam, would leak lam^2 / (sigma^2 + lam^2) of z into the targets' rows),
        z  = argmin |Jb N1 z - (eb - Jb d1)|^2 + lam^2 z^T W^-1 z + alpha |rho + z|^2 + beta |nu + z|^2
           = M g + M' Hb^T (Hb M' Hb^T + lam^2 I)^-1 (eb - Jb d1 - Hb M g),   Hb = Jb N1,
        d  = d1 + N1 z (z scaled to at most zmax per column),
    M, M', g as in kernels/dls.py's docstring; Hb's rows (work[i, HB0 + b]) cost two solves with N1's factor.
    The phases run in one loop so that factor and back_solve are inlined once (faster compiles).
    """
    D = jac.shape[2]
    ok = 1
    if ti.static(not (extra & 2)):
        for d in range(D):
            work[i, MP, d] = joint_w[d] * work[i, FREE, d]
        ok = factor(i, R, lam2, jac, sys, work)
        for r in range(R):
            rows[i, 1, r] = rows[i, 0, r]
        back_solve(i, R, 1, rows, sys)
        for d in range(D):
            acc = 0.0
            for r in range(R):
                acc += jac[i, r, d] * rows[i, 1, r]
            work[i, STEP, d] = work[i, MP, d] * acc
    else:
        R1 = R - Rb
        for d in range(D):
            w = joint_w[d] * work[i, FREE, d]
            work[i, MP, d] = w
            work[i, MG, d] = w * work[i, G, d] / (lam2 + w * (rest_w + vel_w))
            work[i, Z, d] = work[i, MG, d]
        eh = ti.Vector([0.0, 0.0])
        # phase 0: d1 (lam); 1: N1's factor (mu); 2, 3: Hb's rows; 4: z, then N1 z
        for ph in range(5):
            if ph <= 1:
                mu = lam2
                if ph == 1:
                    mu = mu2
                ok = ti.min(ok, factor(i, R1, mu, jac, sys, work))
            slot = 1
            if ph == 0:
                for r in range(R1):
                    rows[i, 1, r] = rows[i, 0, r]
            elif ph == 2 or ph == 3:
                b = R1 + ph - 2
                slot = 2
                for r in range(R1):
                    acc = 0.0
                    for d in range(D):
                        acc += jac[i, r, d] * work[i, MP, d] * jac[i, b, d]
                    rows[i, 2, r] = acc
            elif ph == 4:
                zm = 0.0
                for d in range(D):
                    zm = ti.max(zm, ti.abs(work[i, Z, d]))
                scale = 1.0
                if zm > zmax:
                    scale = zmax / zm
                for d in range(D):
                    work[i, Z, d] *= scale
                for r in range(R1):
                    acc = 0.0
                    for d in range(D):
                        acc += jac[i, r, d] * work[i, Z, d]
                    rows[i, 1, r] = acc
            if ph != 1 and (Rb > 0 or ph == 0 or ph == 4):
                back_solve(i, R1, slot, rows, sys)
            if ph == 0:  # d1 and the balance rows' aim left after it
                for d in range(D):
                    acc = 0.0
                    for r in range(R1):
                        acc += jac[i, r, d] * rows[i, 1, r]
                    work[i, STEP, d] = work[i, MP, d] * acc
                if Rb > 0:
                    eh = ti.Vector([rows[i, 0, R1], rows[i, 0, R1 + 1]])
                    for d in range(D):
                        eh[0] -= jac[i, R1, d] * work[i, STEP, d]
                        eh[1] -= jac[i, R1 + 1, d] * work[i, STEP, d]
            elif (ph == 2 or ph == 3) and Rb > 0:
                b = ph - 2
                for d in range(D):
                    acc = jac[i, R1 + b, d]
                    for r in range(R1):
                        acc -= rows[i, 2, r] * jac[i, r, d]
                    work[i, HB0 + b, d] = acc
                if ph == 3:  # z: the 2 x 2 system of the projected balance rows
                    a00 = lam2
                    a01 = 0.0
                    a11 = lam2
                    for d in range(D):
                        w = work[i, MP, d]
                        mp = w * lam2 / (lam2 + w * (rest_w + vel_w))
                        h0 = work[i, HB0, d]
                        h1 = work[i, HB0 + 1, d]
                        a00 += h0 * mp * h0
                        a01 += h0 * mp * h1
                        a11 += h1 * mp * h1
                        eh[0] -= h0 * work[i, MG, d]
                        eh[1] -= h1 * work[i, MG, d]
                    det = a00 * a11 - a01 * a01
                    y0 = (a11 * eh[0] - a01 * eh[1]) / det
                    y1 = (a00 * eh[1] - a01 * eh[0]) / det
                    for d in range(D):
                        w = work[i, MP, d]
                        mp = w * lam2 / (lam2 + w * (rest_w + vel_w))
                        work[i, Z, d] += mp * (work[i, HB0, d] * y0 + work[i, HB0 + 1, d] * y1)
            elif ph == 4:  # d = d1 + z - W J1^T (J1 W J1^T + mu^2 I)^-1 J1 z
                for d in range(D):
                    acc = 0.0
                    for r in range(R1):
                        acc += jac[i, r, d] * rows[i, 1, r]
                    work[i, STEP, d] += work[i, Z, d] - work[i, MP, d] * acc
    return ok
