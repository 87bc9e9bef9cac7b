"""Damped least squares IK with Levenberg-Marquardt damping and an active set for joint limits.

One kernel launch solves every character; each character runs its own iteration loop (one thread
per character) and stops on its own. Per attempt (Buss 2004, "Introduction to IK with Jacobian
transpose, pseudoinverse and damped least squares"; Buss & Kim 2005 for the error clamp):

1. Rows over the active effectors (weight > 0), each scaled by sqrt(weight): 3 position rows, and
   for an effector with an orientation target 2 rows of the swing that turns its world axis onto
   the target (the plane perpendicular to the current axis; the twist about the axis is free),
   scaled by the length L so that radians count as metres. The position error a step aims for is
   pulled in to reach + d_max from the root (a far target then looks like a near one) and clamped
   to d_max per effector; the orientation error to ORI_CLAMP radians.
2. Columns per DOF: hinge and universal joints, and ball joints with box limits (or unequal joint
   weights), move their angles (ball: intrinsic XYZ Euler, the values the limits apply to); any
   other ball joint moves by a world-axis rotation vector w (the quaternion Jacobian) applied as
   q <- exp(R_p^-1 w) q, R_p its parent's world rotation, which turns the subtree by exp(w) about
   the joint and keeps q unit (no gimbal lock).
3. The step minimises |J d - e|^2 + sum_d (lam^2 / w_d) d_d^2 + alpha |rho + d|^2 + beta |nu + d|^2
   (rho: offset from rest, nu: offset from the solve's start pose, w_d joint weights), i.e.
   d = M g + M' J^T (J M' J^T + lam^2 I)^-1 (e - J M g), m'_d = w_d lam^2 / (lam^2 + w_d (alpha + beta)),
   m_d = m'_d / lam^2, g = -(alpha rho + beta nu). Without alpha and beta this is Buss's weighted
   DLS d = W J^T (J W J^T + lam^2 I)^-1 e. The R x R system (R <= 3E + 2 per effector with an
   axis) is solved by a Cholesky factorisation in a per-character scratch array (no local matrices).
4. Active set: a DOF at a limit whose step points outward is frozen (m = 0) and the system solved
   again; every attempt starts with all DOFs free, so a DOF is released when its step points inward.
5. Levenberg-Marquardt: the step is taken (angles clamped to their limits, cones projected) and
   kept only if the objective F (weighted squared errors + alpha |rho|^2 + beta |nu|^2) drops; lam
   then halves toward `damping`. A rejected step restores the pose and lam grows x4.
6. Escape: a limb straight on its limit (a knee or elbow at 0) is a saddle of F that first-order
   steps cannot leave. When a character stalls, its DOFs frozen on a limit are kicked KICK inward
   and it gets ESCAPE_ATTEMPTS attempts to beat the pose before the kick; otherwise that pose comes
   back. So F never rises between the poses a solve can end in.

7. Static balance (balance_weight beta_b > 0; crowd_ik/reference/dls.py defines the centre of mass c
   and the support point s, both weighted sums of joint positions): 2 more rows, sqrt(beta_b) times
   the x and z rows of d(c - s)/dq aiming at -(c - s)_xz, and beta_b |(c - s)_xz|^2 in F. A DOF with
   world axis w at joint n has the column w x sum_j a_j (p_j - p_n) over the weighted points j below
   n (bone midpoints, minus the feet), summed once per build in qwork[i, Q_COM] by a pass from the
   leaves up.

A character stops when every active position error, every scaled orientation error and the balance
error |(c - s)_xz| are <= tolerance. It is stalled after STALL_AFTER rejected or flat (gain < FLAT * F)
attempts in a row, when F falls by less than PROGRESS over WINDOW accepted steps, when lam passes
LAM_CAP * L, or when its attempts run out (2 * max_iterations + 8), each unless an escape is left. The
constants live in crowd_ik/solvers/settings.py, shared with the NumPy twin.
"""

import taichi as ti

from crowd_ik.kernels.quat import (
    axis_angle, constrain_rotation, joint_angles, joint_quat, qconj, qmul, qnormalize, qrot, quat_to_euler_xyz,
    yaw_quat, vec3, vec4,
)
from crowd_ik.solvers.settings import (
    DLS_ESCAPE_ATTEMPTS as ESCAPE_ATTEMPTS, DLS_FLAT as FLAT, DLS_KICK as KICK, DLS_LAM_CAP as LAM_CAP,
    DLS_LIMIT_EPS as LIMIT_EPS, DLS_MAX_ESCAPES as MAX_ESCAPES, DLS_ORI_CLAMP as ORI_CLAMP,
    DLS_PROGRESS as PROGRESS, DLS_STALL_AFTER as STALL_AFTER, DLS_WINDOW as WINDOW,
)

ndarray = ti.types.ndarray

# Slots of the per-DOF scratch work[i, slot, d] and of the per-joint quaternion scratch qwork[i, slot, j].
THETA, THETA_BAK, THETA0, MP, MG, STEP, FREE, G, THETA_SAVE = 0, 1, 2, 3, 4, 5, 6, 7, 8
Q_BAK, Q_START, Q_SAVE, Q_COM = 0, 1, 2, 3
N_DOF_SLOTS = 9
N_Q_SLOTS = 4


@ti.func
def qlog(q):
    """Rotation vector (axis * angle, angle in [0, pi]) of a unit quaternion."""
    p = q
    if p.w < 0.0:
        p = -p
    v = p.xyz
    s = v.norm()
    out = 2.0 * v
    if s > 1e-7:
        out = v * (2.0 * ti.atan2(s, p.w) / s)
    return out


@ti.func
def qexp(r):
    """Unit quaternion of the rotation vector r."""
    a = r.norm()
    out = vec4(0.5 * r.x, 0.5 * r.y, 0.5 * r.z, 1.0)
    if a > 1e-7:
        s = ti.sin(0.5 * a) / a
        out = vec4(r.x * s, r.y * s, r.z * s, ti.cos(0.5 * a))
    return qnormalize(out)


@ti.func
def perpendicular(a):
    """A unit vector perpendicular to the unit vector a."""
    u = ti.math.cross(a, vec3(1.0, 0.0, 0.0))
    if u.norm_sqr() < 0.01:
        u = ti.math.cross(a, vec3(0.0, 1.0, 0.0))
    return u.normalized()


@ti.func
def swing_vector(a, t):
    """Rotation vector of the minimal rotation taking unit a to unit t."""
    c = ti.math.cross(a, t)
    s = c.norm()
    ang = ti.atan2(s, a.dot(t))
    axis = vec3(0.0)
    if s > 1e-7:
        axis = c / s
    elif a.dot(t) < 0.0:
        axis = perpendicular(a)
    return axis * ang


@ti.func
def parent_rot(i, j, parent: ti.template(), root_yaw: ti.template(), world_rot: ti.template()):
    out = yaw_quat(root_yaw[i])
    if parent[j] >= 0:
        out = world_rot[i, parent[j]]
    return out


@ti.func
def first_bone(j, offset: ti.template(), child_start: ti.template(), child_list: ti.template()):
    """Unit direction of joint j's first child bone (zero for a leaf): the bone a cone limit applies to."""
    out = vec3(0.0)
    if child_start[j] < child_start[j + 1]:
        out = offset[child_list[child_start[j]]].normalized()
    return out


@ti.func
def fk_relative(i, parent: ti.template(), offset: ti.template(), root_yaw: ti.template(), local_rot: ti.template(),
                rel_pos: ti.template(), world_rot: ti.template()):
    """Joint positions relative to the character's root point (so a batch equals one-at-a-time) and world rotations."""
    q_root = yaw_quat(root_yaw[i])
    for j in range(parent.shape[0]):
        p = parent[j]
        base_pos = vec3(0.0)
        base_rot = q_root
        if p >= 0:
            base_pos = rel_pos[i, p]
            base_rot = world_rot[i, p]
        rel_pos[i, j] = base_pos + qrot(base_rot, offset[j])
        world_rot[i, j] = qmul(base_rot, local_rot[i, j])


@ti.func
def read_angles(i, parent: ti.template(), kind: ti.template(), jmode: ti.template(), axes: ti.template(),
                dof_start: ti.template(), local_rot: ti.template(), work: ti.template()):
    """Start state: the angles of angle-mode joints from their rotations, and a zero step."""
    for d in range(work.shape[2]):
        work[i, THETA, d] = 0.0
        work[i, STEP, d] = 0.0
    for j in range(parent.shape[0]):
        k = kind[j]
        s = dof_start[j]
        if jmode[j] == 1:
            a = joint_angles(k, axes[j, 0], axes[j, 1], local_rot[i, j])
            for c in range(k):
                work[i, THETA, s + c] = a[c]


@ti.func
def has_orientation(i, e, eff_has_axis: ti.template(), orient: ti.template()):
    return eff_has_axis[e] != 0 and orient[i, e].norm_sqr() > 0.0


@ti.func
def objective(i, parent: ti.template(), kind: ti.template(), jmode: ti.template(), dof_start: ti.template(),
              eff_joint: ti.template(), eff_axis: ti.template(),
              eff_has_axis: ti.template(), eff_lim: ti.template(), root_pos: ti.template(), local_rot: ti.template(),
              rel_pos: ti.template(), world_rot: ti.template(), targets: ti.template(),
              weights: ti.template(), orient: ti.template(), work: ti.template(), qwork: ti.template(),
              com_w: ti.template(), support_w: ti.template(), length, rest_w, vel_w, bal_w):
    """(F, max position error, max(orientation error * L, balance error)) of character i's current pose.

    F counts each position term as |t - p|^2 - beyond^2, beyond = max(|t - base| - reach, 0), the part
    no pose can remove: the same minimiser and the same comparisons, but for a target out of reach it
    is written as 2 |r| (reach - u.q) - (reach - |q|)(reach + |q|) (r = t - base, u = r / |r|,
    q = p - base), which keeps float32 precision as the chain straightens (F itself stays large).
    """
    f = 0.0
    perr = 0.0
    oerr = 0.0
    base = rel_pos[i, 0]
    for e in range(eff_joint.shape[0]):
        w = weights[i, e]
        if w > 0.0:
            k = eff_joint[e]
            t = targets[i, e] - root_pos[i]
            d = t - rel_pos[i, k]
            perr = ti.max(perr, d.norm())
            r = t - base
            dist = r.norm()
            reach = eff_lim[e, 0]
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
    if rest_w > 0.0 or vel_w > 0.0:
        for j in range(parent.shape[0]):
            k = kind[j]
            s = dof_start[j]
            if k > 0:
                if jmode[j] == 1:
                    for c in range(k):
                        th = work[i, THETA, s + c]
                        dv = th - work[i, THETA0, s + c]
                        f += rest_w * th * th + vel_w * dv * dv
                else:
                    q = local_rot[i, j]
                    f += rest_w * qlog(q).norm_sqr() + vel_w * qlog(qmul(q, qconj(qwork[i, Q_START, j]))).norm_sqr()
    if bal_w > 0.0:
        b = vec3(0.0)  # c - s
        for j in range(parent.shape[0]):
            p = rel_pos[i, j]
            mid = p
            if parent[j] >= 0:
                mid = 0.5 * (rel_pos[i, parent[j]] + p)
            b += com_w[j] * mid - support_w[j] * p
        bb = b.x * b.x + b.z * b.z
        f += bal_w * bb
        oerr = ti.max(oerr, ti.sqrt(bb))
    return vec3(f, perr, oerr)


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
                 rows: ti.template(), length, rest_w, vel_w, bal_w):
    """Fill jac[i, :R], rows[i, 0, :R] (the aimed error) and work[i, G]; return R, the number of rows.

    The balance rows (bal_w > 0) come last, after the effectors' rows.
    """
    D = jac.shape[2]
    for r, d in ti.ndrange(jac.shape[1], D):
        jac[i, r, d] = 0.0
    base = rel_pos[i, 0]
    E = eff_joint.shape[0]
    J = parent.shape[0]
    r = 0
    # e = E is the balance term: its walk visits every joint (n = J-1 .. 0) instead of a path to the root
    # (one walk for both keeps a single inlined dof_axes: faster compiles)
    for e in range(E + 1):
        bal = e == E
        sw = 0.0
        if bal:
            sw = ti.sqrt(ti.max(bal_w, 0.0))
        else:
            sw = ti.sqrt(ti.max(weights[i, e], 0.0))
        if sw > 0.0:
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
                tgt = targets[i, e] - root_pos[i]
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
    # g = -(alpha rho + beta nu): rho, nu in the columns' coordinates (world axes for quaternion joints)
    for d in range(D):
        work[i, G, d] = 0.0
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
def solve_step(i, R, lam2, rest_w, vel_w, joint_w: ti.template(), jac: ti.template(), rows: ti.template(),
               sys: ti.template(), work: ti.template()):
    """work[i, STEP] = M g + M' J^T (J M' J^T + lam^2 I)^-1 (e - J M g) over the free DOFs.

    Returns 1, or 0 when round-off made the system not positive definite (the step is then void).
    """
    D = jac.shape[2]
    for d in range(D):
        w = joint_w[d] * work[i, FREE, d]
        den = lam2 + w * (rest_w + vel_w)
        work[i, MP, d] = w * lam2 / den
        work[i, MG, d] = w * work[i, G, d] / den
    for r in range(R):
        for c in range(r + 1):
            acc = 0.0
            for d in range(D):
                acc += jac[i, r, d] * work[i, MP, d] * jac[i, c, d]
            if r == c:
                acc += lam2
            sys[i, r, c] = acc
        b = rows[i, 0, r]
        for d in range(D):
            b -= jac[i, r, d] * work[i, MG, d]
        rows[i, 1, r] = b
    ok = 1
    for c in range(R):  # Cholesky, lower triangle in place
        v = sys[i, c, c]
        for k in range(c):
            v -= sys[i, c, k] * sys[i, c, k]
        if v <= 0.0:
            ok = 0
            v = 1.0
        lc = ti.sqrt(v)
        sys[i, c, c] = lc
        for r in range(c + 1, R):
            x = sys[i, r, c]
            for k in range(c):
                x -= sys[i, r, k] * sys[i, c, k]
            sys[i, r, c] = x / lc
    for r in range(R):  # L z = b
        x = rows[i, 1, r]
        for k in range(r):
            x -= sys[i, r, k] * rows[i, 1, k]
        rows[i, 1, r] = x / sys[i, r, r]
    for rr in range(R):  # L^T y = z
        r = R - 1 - rr
        x = rows[i, 1, r]
        for k in range(r + 1, R):
            x -= sys[i, k, r] * rows[i, 1, k]
        rows[i, 1, r] = x / sys[i, r, r]
    for d in range(D):
        acc = 0.0
        for r in range(R):
            acc += jac[i, r, d] * rows[i, 1, r]
        work[i, STEP, d] = work[i, MG, d] + work[i, MP, d] * acc
    return ok


@ti.func
def freeze_outward(i, parent: ti.template(), kind: ti.template(), jmode: ti.template(), lo: ti.template(),
                   hi: ti.template(), dof_start: ti.template(), work: ti.template()):
    """Freeze the free angle DOFs that sit on a limit and whose step points outward; return how many."""
    n = 0
    for j in range(parent.shape[0]):
        k = kind[j]
        s = dof_start[j]
        if jmode[j] == 1:
            for c in range(k):
                d = s + c
                if work[i, FREE, d] > 0.0:
                    th = work[i, THETA, d]
                    st = work[i, STEP, d]
                    if (th <= lo[d] + LIMIT_EPS and st < 0.0) or (th >= hi[d] - LIMIT_EPS and st > 0.0):
                        work[i, FREE, d] = 0.0
                        n += 1
    return n


@ti.func
def apply_step(i, parent: ti.template(), offset: ti.template(), kind: ti.template(), jmode: ti.template(),
               axes: ti.template(), lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
               dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(), root_yaw: ti.template(),
               local_rot: ti.template(), rel_pos: ti.template(), world_rot: ti.template(), work: ti.template(),
               qwork: ti.template()):
    """Back up the pose, add work[i, STEP] (angles clamped to their limits, cones projected), and run FK.

    With a zero step this projects a start pose onto the joints' DOFs and limits.
    """
    for d in range(work.shape[2]):
        work[i, THETA_BAK, d] = work[i, THETA, d]
    for j in range(parent.shape[0]):
        qwork[i, Q_BAK, j] = local_rot[i, j]
        k = kind[j]
        s = dof_start[j]
        if k > 0:
            q = local_rot[i, j]
            by_angle = jmode[j] == 1
            if by_angle:
                a = vec3(0.0)
                for c in range(k):
                    v = ti.math.clamp(work[i, THETA, s + c] + work[i, STEP, s + c], lo[s + c], hi[s + c])
                    work[i, THETA, s + c] = v
                    a[c] = v
                q = joint_quat(k, axes[j, 0], axes[j, 1], a.x, a.y, a.z)
            else:
                wv = vec3(work[i, STEP, s], work[i, STEP, s + 1], work[i, STEP, s + 2])
                # world_rot still holds the pose the step was computed at (FK runs after the loop)
                base_rot = parent_rot(i, j, parent, root_yaw, world_rot)
                q = qnormalize(qmul(qexp(qrot(qconj(base_rot), wv)), q))
            if k == 3 and cone[j] > 0.0:
                q = constrain_rotation(k, axes[j, 0], axes[j, 1], q, lo, hi, lim_p, s, cone[j],
                                       first_bone(j, offset, child_start, child_list))
                if by_angle:
                    e = quat_to_euler_xyz(q)
                    for c in ti.static(range(3)):
                        work[i, THETA, s + c] = e[c]
            local_rot[i, j] = q
    fk_relative(i, parent, offset, root_yaw, local_rot, rel_pos, world_rot)


@ti.func
def copy_pose(i, theta_from, theta_to, q_from, q_to, parent: ti.template(), local_rot: ti.template(),
              work: ti.template(), qwork: ti.template()):
    """Copy the solver state (angles and local rotations) between slots; slot -1 is the live pose."""
    for d in range(work.shape[2]):
        v = work[i, theta_from, d]
        work[i, theta_to, d] = v
    for j in range(parent.shape[0]):
        q = local_rot[i, j]
        if q_from >= 0:
            q = qwork[i, q_from, j]
        if q_to >= 0:
            qwork[i, q_to, j] = q
        else:
            local_rot[i, j] = q


@ti.func
def kick_step(i, parent: ti.template(), kind: ti.template(), jmode: ti.template(), lo: ti.template(),
              hi: ti.template(), dof_start: ti.template(), joint_w: ti.template(), work: ti.template()):
    """Escape step: every weighted angle DOF frozen on a limit moves inward by min(KICK, half its range).

    Fills work[i, STEP]; returns the number of DOFs it moves. (A limb straight on its limit, a knee
    or an elbow, is a saddle of the error that first-order steps cannot leave.)
    """
    n = 0
    for d in range(work.shape[2]):
        work[i, STEP, d] = 0.0
    for j in range(parent.shape[0]):
        k = kind[j]
        s = dof_start[j]
        if jmode[j] == 1:
            for c in range(k):
                d = s + c
                size = ti.min(KICK, 0.5 * (hi[d] - lo[d]))
                if work[i, FREE, d] == 0.0 and joint_w[d] > 0.0 and size > 0.0:
                    th = work[i, THETA, d]
                    if th <= lo[d] + LIMIT_EPS:
                        work[i, STEP, d] = size
                        n += 1
                    elif th >= hi[d] - LIMIT_EPS:
                        work[i, STEP, d] = -size
                        n += 1
    return n


@ti.kernel
def dls_solve(
    parent: ndarray(dtype=ti.i32, ndim=1),
    offset: ndarray(dtype=vec3, ndim=1),
    kind: ndarray(dtype=ti.i32, ndim=1),
    jmode: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    lo: ndarray(ndim=1),
    hi: ndarray(ndim=1),
    lim_p: ndarray(ndim=2),
    cone: ndarray(ndim=1),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    child_start: ndarray(dtype=ti.i32, ndim=1),
    child_list: ndarray(dtype=ti.i32, ndim=1),
    eff_joint: ndarray(dtype=ti.i32, ndim=1),
    eff_axis: ndarray(dtype=vec3, ndim=1),
    eff_has_axis: ndarray(dtype=ti.i32, ndim=1),
    eff_lim: ndarray(ndim=2),
    joint_w: ndarray(ndim=1),
    com_w: ndarray(ndim=1),
    support_w: ndarray(ndim=1),
    root_pos: ndarray(dtype=vec3, ndim=1),
    root_yaw: ndarray(ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    targets: ndarray(dtype=vec3, ndim=2),
    weights: ndarray(ndim=2),
    orient: ndarray(dtype=vec3, ndim=2),
    rel_pos: ndarray(dtype=vec3, ndim=2),
    qwork: ndarray(dtype=vec4, ndim=3),
    work: ndarray(ndim=3),
    jac: ndarray(ndim=3),
    rows: ndarray(ndim=3),
    sys: ndarray(ndim=3),
    max_iterations: ti.i32,
    tolerance: ti.f32,
    damping: ti.f32,
    length: ti.f32,
    rest_w: ti.f32,
    vel_w: ti.f32,
    bal_w: ti.f32,
    error: ndarray(ndim=1),
    iterations: ndarray(dtype=ti.i32, ndim=1),
    stalled: ndarray(dtype=ti.i32, ndim=1),
):
    """Solve every character (N = root_pos.shape[0]) in place: local_rot, world_pos and world_rot are updated.

    Rig arrays as in Rig.arrays; eff_lim (E, 2): per effector the reach and d_max (metres);
    joint_w (D+1,) per-DOF weights (0 freezes a DOF); com_w, support_w (J,) the balance weights of
    crowd_ik.solvers.dls_setup.balance_weights. targets (N, E, 3) world metres; weights (N, E);
    orient (N, E, 3) unit directions or zero. Scratch: rel_pos (N, J), qwork (N, 4, J),
    work (N, 9, D+1), jac (N, R, D+1), rows (N, 2, R), sys (N, R, R), R = 3E + 2 per effector with
    an axis (+ 2 with bal_w > 0). damping and length in metres (damping > 0); rest_w, vel_w in
    m^2/rad^2; bal_w (dimensionless) weighs the squared balance error in m^2. Outputs:
    error (N,) final max effector distance, iterations (N,) accepted steps, stalled (N,) 1 if LM
    could make no more progress. jmode, lo, hi, eff_lim: crowd_ik.solvers.dls_setup.dls_settings.
    """
    for i in range(root_pos.shape[0]):
        read_angles(i, parent, kind, jmode, axes, dof_start, local_rot, work)
        D = work.shape[2]
        max_attempts = 2 * max_iterations + 8
        obj = vec3(0.0)
        lam = damping
        accepted = 0
        attempts = 0
        bad = 0
        stop = 0
        failed = 0
        first = 1
        kick = 0  # the pending step is an escape kick
        esc = 0  # on probation after a kick
        esc_left = 0
        escapes = 0
        saved_obj = vec3(0.0)
        saved_accepted = 0
        ref_f = 0.0
        ref_accepted = 0
        go = 1
        while go == 1:
            # one call site per phase (every ti.func is inlined: fewer sites, faster compiles)
            apply_step(i, parent, offset, kind, jmode, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                       root_yaw, local_rot, rel_pos, world_rot, work, qwork)
            if first == 1:  # the projected start pose is the reference of the velocity term
                copy_pose(i, THETA, THETA0, -1, Q_START, parent, local_rot, work, qwork)
            new = objective(i, parent, kind, jmode, dof_start, eff_joint, eff_axis, eff_has_axis, eff_lim, root_pos,
                            local_rot, rel_pos, world_rot, targets, weights, orient, work, qwork, com_w, support_w,
                            length, rest_w, vel_w, bal_w)
            need_fk = 0
            if first == 1:
                obj = new
                ref_f = obj[0]
                first = 0
            elif kick == 1:
                obj = new
                accepted += 1
                lam = damping
                bad = 0
                kick = 0
                esc = 1
                esc_left = ESCAPE_ATTEMPTS
                ref_f = obj[0]
                ref_accepted = accepted
            else:
                if new[0] < obj[0] and failed == 0:
                    if obj[0] - new[0] < FLAT * obj[0]:
                        bad += 1
                    else:
                        bad = 0
                    obj = new
                    accepted += 1
                    lam = ti.max(0.5 * lam, damping)
                    if accepted - ref_accepted >= WINDOW:  # too slow: F fell by less than PROGRESS
                        if obj[0] > (1.0 - PROGRESS) * ref_f:
                            bad = STALL_AFTER
                        ref_f = obj[0]
                        ref_accepted = accepted
                else:
                    copy_pose(i, THETA_BAK, THETA, Q_BAK, -1, parent, local_rot, work, qwork)
                    need_fk = 1
                    bad += 1
                    lam *= 4.0
                if esc == 1:  # kept once it beats the pose before the kick (or converges)
                    if obj[0] < saved_obj[0] or (obj[1] <= tolerance and obj[2] <= tolerance):
                        esc = 0
                    esc_left -= 1
            back = 0  # 1: return to the pose saved before the kick
            if bad >= STALL_AFTER or lam > LAM_CAP * length:
                stop = 1
                if esc == 1:
                    back = 1
                elif escapes < MAX_ESCAPES:
                    if kick_step(i, parent, kind, jmode, lo, hi, dof_start, joint_w, work) > 0:
                        copy_pose(i, THETA, THETA_SAVE, -1, Q_SAVE, parent, local_rot, work, qwork)
                        saved_obj = obj
                        saved_accepted = accepted
                        kick = 1
                        escapes += 1
                        bad = 0
                        lam = damping
                        stop = 0
            if esc == 1 and esc_left <= 0 and back == 0:
                stop = 1
                back = 1
            converged = obj[1] <= tolerance and obj[2] <= tolerance
            go = 0
            if accepted < max_iterations and attempts < max_attempts and stop == 0 and not converged:
                go = 1
            if go == 0 and esc == 1:
                back = 1
            if back == 1:
                copy_pose(i, THETA_SAVE, THETA, Q_SAVE, -1, parent, local_rot, work, qwork)
                need_fk = 1
                obj = saved_obj
                accepted = saved_accepted
                esc = 0
                ref_f = obj[0]
                ref_accepted = accepted
            if need_fk == 1:
                fk_relative(i, parent, offset, root_yaw, local_rot, rel_pos, world_rot)
            if go == 0 and stop == 0 and accepted < max_iterations and (obj[1] > tolerance or obj[2] > tolerance):
                stop = 1  # attempts ran out: too many rejected steps
            if go == 1:
                attempts += 1
                if kick == 0:
                    R = build_system(i, parent, kind, jmode, axes, dof_start, eff_joint, eff_axis,
                                     eff_has_axis, eff_lim, root_pos, root_yaw, local_rot, rel_pos, world_rot, targets,
                                     weights, orient, work, qwork, com_w, support_w, jac, rows, length, rest_w,
                                     vel_w, bal_w)
                    for d in range(D):
                        work[i, FREE, d] = 1.0
                    failed = 0
                    rounds = 0
                    frozen = 1
                    while frozen > 0 and rounds <= D:
                        failed = 1 - solve_step(i, R, lam * lam, rest_w, vel_w, joint_w, jac, rows, sys, work)
                        frozen = freeze_outward(i, parent, kind, jmode, lo, hi, dof_start, work)
                        rounds += 1
                    if failed == 1:
                        for d in range(D):
                            work[i, STEP, d] = 0.0
        for j in range(parent.shape[0]):
            world_pos[i, j] = root_pos[i] + rel_pos[i, j]
        error[i] = obj[1]
        iterations[i] = accepted
        stalled[i] = stop
