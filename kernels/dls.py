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
3. The step is Buss's weighted DLS d = W J^T (J W J^T + lam^2 I)^-1 e (w_d joint weights). The secondary
   terms, alpha |rho|^2 (rho: offset from rest), beta |nu|^2 (nu: offset from the solve's start pose) and
   balance (7.), act in the null space of the targets' rows (task priority, Siciliano & Slotine 1991; the
   gradient projection of Liegeois 1977, d = J^+ e + (I - J^+ J) z, with damped pseudo-inverses):
   z minimises the balance rows projected into that null space plus lam^2 z^T W^-1 z + alpha |rho + z|^2
   + beta |nu + z|^2 (so z = M g, m_d = w_d / (lam^2 + w_d (alpha + beta)), g = -(alpha rho + beta nu),
   without balance), z is scaled to at most NULL_STEP * damping / lam per column, and d = d1 + N1 z, N1
   the projector onto that null space (damped by DAMPING_MIN L only; kernels/dls_system.solve_step).
   They shape the pose among the solutions; if a character stalls with a target error above tolerance
   (z's second-order effect, or a secondary goal out of reach, can hold the targets a little off), it
   drops z (zmax = 0) and goes on with the targets alone until they are back within NULL_BAND x
   tolerance, so a secondary term never holds a reachable target off. (Its stall test counts S's
   progress only once the targets are within tolerance.) The R x R system (R <= 3E + 2 per effector with an axis) is solved by a Cholesky
   factorisation in a per-character scratch array (no local matrices).
4. Active set: a DOF at a limit whose step points outward is frozen (m = 0) and the system solved
   again; every attempt starts with all DOFs free, so a DOF is released when its step points inward.
5. Levenberg-Marquardt: the step is taken (angles clamped to their limits, cones projected) and
   kept only if the objective F (the targets' weighted squared errors) drops, or, with secondary terms,
   if their sum S (alpha |rho|^2 + beta |nu|^2 + balance) drops while every target error stays within
   NULL_BAND x tolerance; lam then halves toward `damping`. A rejected step restores the pose and lam
   grows x4.
6. Escape: a limb straight on its limit (a knee or elbow at 0) is a saddle of F that first-order
   steps cannot leave. When a character stalls, its DOFs frozen on a limit are kicked KICK inward
   and it gets ESCAPE_ATTEMPTS attempts to beat the pose before the kick; otherwise that pose comes
   back. So F never rises between the poses a solve can end in, except within the band of 5.

7. Static balance (balance_weight beta_b > 0; crowd_ik/reference/dls.py defines the centre of mass c
   and the support point s, both weighted sums of joint positions): 2 more rows, sqrt(beta_b) times
   the x and z rows of d(c - s)/dq aiming at -(c - s)_xz (a secondary task, 3.), and beta_b |(c - s)_xz|^2
   in S. A DOF with
   world axis w at joint n has the column w x sum_j a_j (p_j - p_n) over the weighted points j below
   n (bone midpoints, minus the feet), summed once per build in qwork[i, Q_COM] by a pass from the
   leaves up.

8. A free root (extra bit 4, Crowd.solve(root_weight=w)): the root's translation is 3 more unknowns, the
   last columns of work, jac (identity in every effector position row, zero in orientation, rotation and
   balance rows, as the whole body translates), weighted w like a joint weight; F then counts |t - p|^2 for
   every target (none is out of reach), and root_pos is written back.

A character stops when every active position error, every scaled orientation error and the balance
error |(c - s)_xz| are <= tolerance. It is stalled after STALL_AFTER rejected or flat (gain < FLAT * F)
attempts in a row, when F falls by less than PROGRESS over WINDOW accepted steps, when lam passes
LAM_CAP * L, or when its attempts run out (2 * max_iterations + 8), each unless an escape is left. The
constants live in crowd_ik/solvers/settings.py, shared with the NumPy twin.
"""

import taichi as ti

from crowd_ik.kernels.quat import (
    constrain_rotation, joint_quat, qconj, qmul, qnormalize, qrot, quat_to_euler_xyz,
    vec3, vec4,
)
from crowd_ik.solvers.settings import (
    DLS_DAMPING_MIN as DAMPING_MIN, DLS_ESCAPE_ATTEMPTS as ESCAPE_ATTEMPTS, DLS_FLAT as FLAT, DLS_KICK as KICK, DLS_LAM_CAP as LAM_CAP,
    DLS_LIMIT_EPS as LIMIT_EPS, DLS_MAX_ESCAPES as MAX_ESCAPES, DLS_NULL_BAND as NULL_BAND,
    DLS_NULL_STEP as NULL_STEP, DLS_PROGRESS as PROGRESS, DLS_STALL_AFTER as STALL_AFTER, DLS_WINDOW as WINDOW,
)

from crowd_ik.kernels.dls_pose import (
    FREE, N_DOF_SLOTS, N_Q_SLOTS, Q_BAK, Q_SAVE, Q_START, STEP, THETA, THETA0, THETA_BAK, THETA_SAVE,  # noqa: F401
    first_bone, fk_relative, parent_rot, qexp, read_angles, root_point, vec5,
)
from crowd_ik.kernels.dls_system import build_system, objective, solve_step

ndarray = ti.types.ndarray



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
               qwork: ti.template(), extra: ti.template()):
    """Back up the pose, add work[i, STEP] (angles clamped to their limits, cones projected), and run FK.

    With a zero step this projects a start pose onto the joints' DOFs and limits.
    """
    for d in range(work.shape[2]):
        work[i, THETA_BAK, d] = work[i, THETA, d]
    if ti.static(extra & 4):  # the root's translation
        for c in ti.static(range(3)):
            work[i, THETA, work.shape[2] - 3 + c] += work[i, STEP, work.shape[2] - 3 + c]
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
    rot_t: ndarray(dtype=vec4, ndim=2),
    rot_w: ndarray(ndim=2),
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
    extra: ti.template(),
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
    extra (compile time, 0 = the plain kernel): bit 2 the secondary terms (set iff rest_w, vel_w or bal_w > 0)
    in the null space of the targets; bit 4 a free root (work, jac have 3 more columns, the last, joint_w its
    weights there; root_pos is moved in place); bit 1 full rotation targets rot_t (N, E, 4) x y z w of the
    effector joints' world rotations, weighted by rot_w (N, E) (0: none), 3 rows each (R grows by 3 per
    effector); with extra 0 rot_t and rot_w are not read.
    """
    for i in range(root_pos.shape[0]):
        read_angles(i, parent, kind, jmode, axes, dof_start, local_rot, work)
        D = work.shape[2]
        mu2 = (DAMPING_MIN * length) * (DAMPING_MIN * length)  # the null-space projector's damping
        Rb = 0  # balance rows, last
        if bal_w > 0.0:
            Rb = 2
        max_attempts = 2 * max_iterations + 8
        obj = vec5(0.0)
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
        saved_obj = vec5(0.0)
        saved_accepted = 0
        ref_f = 0.0
        ref_s = 0.0
        ref_accepted = 0
        zon = 1.0  # 0 once the secondary terms are dropped (see the stall test)
        go = 1
        while go == 1:
            # one call site per phase (every ti.func is inlined: fewer sites, faster compiles)
            apply_step(i, parent, offset, kind, jmode, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                       root_yaw, local_rot, rel_pos, world_rot, work, qwork, extra)
            if first == 1:  # the projected start pose is the reference of the velocity term
                copy_pose(i, THETA, THETA0, -1, Q_START, parent, local_rot, work, qwork)
            new = objective(i, parent, kind, jmode, dof_start, eff_joint, eff_axis, eff_has_axis, eff_lim, root_pos,
                            local_rot, rel_pos, world_rot, targets, weights, orient, work, qwork, com_w, support_w,
                            length, rest_w, vel_w, bal_w, rot_t, rot_w, extra)
            need_fk = 0
            if first == 1:
                obj = new
                ref_f = obj[0]
                ref_s = obj[3]
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
                ref_s = obj[3]
                ref_accepted = accepted
            else:
                better = new[0] < obj[0]
                flat = obj[0] - new[0] < FLAT * obj[0]
                if ti.static(extra & 2):
                    # secondary terms: also taken when S falls while every target error stays in the band
                    band = NULL_BAND * tolerance
                    better = better or (new[3] < obj[3] and new[1] <= band and new[4] <= band)
                    flat = flat and obj[3] - new[3] < FLAT * obj[3]
                if better and failed == 0:
                    if flat:
                        bad += 1
                    else:
                        bad = 0
                    obj = new
                    accepted += 1
                    lam = ti.max(0.5 * lam, damping)
                    if ti.static(extra & 2):  # back in the band: the secondary step resumes
                        if new[1] <= NULL_BAND * tolerance and new[4] <= NULL_BAND * tolerance:
                            zon = 1.0
                    if accepted - ref_accepted >= WINDOW:  # too slow: F (and S) fell by less than PROGRESS
                        slow = obj[0] > (1.0 - PROGRESS) * ref_f
                        if ti.static(extra & 2):  # S's progress counts once the targets are within tolerance
                            slow = slow and (obj[3] >= (1.0 - PROGRESS) * ref_s or obj[1] > tolerance
                                             or obj[4] > tolerance)
                        if slow:
                            bad = STALL_AFTER
                        ref_f = obj[0]
                        ref_s = obj[3]
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
                elif ti.static(extra & 2) and zon > 0.0 and (obj[1] > tolerance or obj[4] > tolerance):
                    zon = 0.0  # the secondary step held the targets off: go on with the targets alone
                    bad = 0
                    lam = damping
                    stop = 0
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
                ref_s = obj[3]
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
                                     vel_w, bal_w, rot_t, rot_w, extra)
                    for d in range(D):
                        work[i, FREE, d] = 1.0
                    failed = 0
                    rounds = 0
                    frozen = 1
                    while frozen > 0 and rounds <= D:
                        failed = 1 - solve_step(i, R, Rb, lam * lam, mu2, zon * NULL_STEP * damping / lam, rest_w,
                                                vel_w, joint_w, jac, rows, sys, work, extra)
                        frozen = freeze_outward(i, parent, kind, jmode, lo, hi, dof_start, work)
                        rounds += 1
                    if failed == 1:
                        for d in range(D):
                            work[i, STEP, d] = 0.0
        rp = root_point(i, root_pos, work, extra)
        for j in range(parent.shape[0]):
            world_pos[i, j] = rp + rel_pos[i, j]
        if ti.static(extra & 4):
            root_pos[i] = rp
        error[i] = obj[1]
        iterations[i] = accepted
        stalled[i] = stop
