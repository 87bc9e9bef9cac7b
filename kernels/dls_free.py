"""Damped least squares for a single position effector on a constraint-free rig, in closed form.

The same solve as kernels/dls.py's dls_solve (the same steps, LM damping, acceptance and stall tests,
so the same poses up to float32 rounding) when every joint is an unlimited ball (or fixed), the rig has
one effector with a position target, and there is no rest, velocity or balance term and no joint
weights. There the problem has closed forms that the general kernel computes the long way:

- Every ball joint n on the effector's path moves by a world-axis rotation vector; its three columns
  are a x r_n for a = x, y, z, r_n = p_eff - p_n, i.e. J_n = -[r_n]x. Hence
  J J^T = sum_n [r_n]x [r_n]x^T = sum_n (|r_n|^2 I - r_n r_n^T), a 3 x 3 sum built in one pass over
  the path (no Jacobian is stored), and the DLS step of joint n is J_n^T y = r_n x y with
  y = (w J J^T + lam^2 I)^-1 sqrt(w) e (Buss 2004, eq. 11, rows scaled by sqrt(w)).
- dls_solve's update q_j <- exp(R_p^-1 w_j) q_j is, in world terms, R_j <- D_j R_j with
  D_j = D_p exp(w_j) (D_p = R_p' R_p^-1, the parent's turn; the identity above the root): the solver
  keeps world rotations and turns them, step and forward kinematics in one pass root to leaf, and
  the local rotations follow once, at the end.

Speed (chain16, 100,000 characters, 2 cores; the general kernel: 94k solves/s): the closed forms
216k; the series exponential (qexp_series) 266k; world rotations 276k; several characters interleaved
per thread (as fabrik_solve_free does) changed nothing (213k-220k for 1, 2, 4, 8). What the machine
code showed: every store to an ndarray made LLVM reload the array's shape and pointer (they may
alias), about 7 integer instructions per float stored. So each character's pose lives in local
arrays (n_joints is a compile-time constant: a kernel per rig size) and touches the ndarrays only
to read its start and write its result.
"""

import taichi as ti

from crowd_ik.kernels.fk import joint_fk_local
from crowd_ik.kernels.local_arrays import get3, get4, put
from crowd_ik.kernels.quat import qconj, qmul, qnormalize, yaw_quat, vec3, vec4
from crowd_ik.solvers.settings import (
    DLS_FLAT as FLAT, DLS_LAM_CAP as LAM_CAP, DLS_PROGRESS as PROGRESS, DLS_STALL_AFTER as STALL_AFTER,
    DLS_WINDOW as WINDOW,
)

ndarray = ti.types.ndarray


@ti.func
def objective(t, base, p, w, reach):
    """(F, position error) of a pose with the effector at p, root at base, target t (dls.objective, one effector)."""
    f = 0.0
    perr = 0.0
    if w > 0.0:
        d = t - p
        perr = d.norm()
        r = t - base
        dist = r.norm()
        if dist > reach:
            q = p - base
            qn = q.norm()
            f = w * (2.0 * (dist * reach - r.dot(q)) - (reach - qn) * (reach + qn))
        else:
            f = w * d.norm_sqr()
    return ti.math.vec2(f, perr)


@ti.func
def aimed_error(t, base, p, reach, dmax):
    """The error a step aims to remove: the target pulled to reach + d_max from the root, then clamped to d_max."""
    v = t - base
    dist = v.norm()
    tgt = t
    if dist > reach + dmax:
        tgt = base + v * ((reach + dmax) / dist)
    d = tgt - p
    dn = d.norm()
    if dn > dmax:
        d = d * (dmax / dn)
    return d


@ti.func
def solve3(a00, a10, a11, a20, a21, a22, b):
    """(x, ok) with A x = b for the symmetric 3 x 3 A (lower triangle given) by Cholesky; ok 0 if A is not
    positive definite (x is then void), as dls.solve_step."""
    ok = 1.0
    if a00 <= 0.0:
        ok = 0.0
        a00 = 1.0
    l00 = ti.sqrt(a00)
    l10 = a10 / l00
    l20 = a20 / l00
    v1 = a11 - l10 * l10
    if v1 <= 0.0:
        ok = 0.0
        v1 = 1.0
    l11 = ti.sqrt(v1)
    l21 = (a21 - l20 * l10) / l11
    v2 = a22 - l20 * l20 - l21 * l21
    if v2 <= 0.0:
        ok = 0.0
        v2 = 1.0
    l22 = ti.sqrt(v2)
    z0 = b.x / l00
    z1 = (b.y - l10 * z0) / l11
    z2 = (b.z - l20 * z0 - l21 * z1) / l22
    x2 = z2 / l22
    x1 = (z1 - l21 * x2) / l11
    x0 = (z0 - l10 * x1 - l20 * x2) / l00
    return vec4(x0, x1, x2, ok)


@ti.func
def qexp_series(r):
    """Unit quaternion of the rotation vector r (as dls.qexp): Taylor series of sin(h) / h and cos(h), h = |r| / 2,
    for h <= 0.75 (truncation below 2e-9, under float32 rounding; no sqrt, sin or cos), libm beyond."""
    h2 = 0.25 * r.norm_sqr()
    out = vec4(0.0, 0.0, 0.0, 1.0)
    if h2 <= 0.5625:
        sinc = 1.0 - h2 / 6.0 * (1.0 - h2 / 20.0 * (1.0 - h2 / 42.0 * (1.0 - h2 / 72.0)))
        cosh = 1.0 - h2 / 2.0 * (1.0 - h2 / 12.0 * (1.0 - h2 / 30.0 * (1.0 - h2 / 56.0 * (1.0 - h2 / 90.0))))
        v = 0.5 * sinc * r
        out = vec4(v.x, v.y, v.z, cosh)
    else:
        a = ti.sqrt(4.0 * h2)
        s = ti.sin(0.5 * a) / a
        out = vec4(r.x * s, r.y * s, r.z * s, ti.cos(0.5 * a))
    return out


@ti.func
def renormalize(q):
    """q / |q| for a q within float32 rounding of unit length: one Newton step of 1 / sqrt (error O(|q|^2 - 1)^2)."""
    return q * (1.5 - 0.5 * q.dot(q))


@ti.kernel
def dls_solve_free(
    parent: ndarray(dtype=ti.i32, ndim=1),
    offset: ndarray(dtype=vec3, ndim=1),
    kind: ndarray(dtype=ti.i32, ndim=1),
    on_path: ndarray(dtype=ti.i32, ndim=1),
    eff_joint: ndarray(dtype=ti.i32, ndim=1),
    eff_lim: ndarray(ndim=2),
    root_pos: ndarray(dtype=vec3, ndim=1),
    root_yaw: ndarray(ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    targets: ndarray(dtype=vec3, ndim=2),
    weights: ndarray(ndim=2),
    max_iterations: ti.i32,
    tolerance: ti.f32,
    damping: ti.f32,
    length: ti.f32,
    error: ndarray(ndim=1),
    iterations: ndarray(dtype=ti.i32, ndim=1),
    stalled: ndarray(dtype=ti.i32, ndim=1),
    n_joints: ti.template(),
):
    """dls_solve for one position effector on a constraint-free rig (see the module docstring), in place.

    on_path (J,): 1 for the joints with DOFs on the effector's path to the root. eff_lim (1, 2): reach
    and d_max. n_joints: J, as a Python int. Other arguments and outputs as dls_solve.
    """
    k = eff_joint[0]
    reach = eff_lim[0, 0]
    dmax = eff_lim[0, 1]
    max_attempts = 2 * max_iterations + 8
    for i in range(root_pos.shape[0]):
        rot = ti.Matrix.zero(ti.f32, n_joints, 4)  # world rotations
        pos = ti.Matrix.zero(ti.f32, n_joints, 3)  # joint positions relative to the root point
        rot_bak = ti.Matrix.zero(ti.f32, n_joints, 4)  # world rotations before the step
        turn = ti.Matrix.zero(ti.f32, n_joints, 4)  # D_j of the step
        base_root = yaw_quat(root_yaw[i])
        t = targets[i, 0] - root_pos[i]
        w = weights[i, 0]
        sw = ti.sqrt(ti.max(w, 0.0))
        # the start pose, its rotations normalised (dls_solve's first, zero, step)
        for j in range(n_joints):
            q = local_rot[i, j]
            if kind[j] > 0:
                q = qnormalize(q)
                local_rot[i, j] = q
            put(rot, j, qmul(joint_fk_local(j, parent[j], base_root, offset, rot, pos), q))
        obj = objective(t, get3(pos, 0), get3(pos, k), w, reach)
        f_cur = obj[0]
        perr = obj[1]
        ref_f = f_cur
        lam = damping
        accepted = 0
        ref_accepted = 0
        attempts = 0
        bad = 0
        stop = 0
        go = 1
        if perr <= tolerance or max_iterations <= 0:
            go = 0
        while go == 1:
            # the step at this pose: A = w sum_n (|r_n|^2 I - r_n r_n^T) + lam^2 I over the path, b = sqrt(w) e
            attempts += 1
            p_eff = get3(pos, k)
            a00, a10, a11, a20, a21, a22 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            for j in range(n_joints):
                if on_path[j] != 0:
                    r = p_eff - get3(pos, j)
                    rr = r.norm_sqr()
                    a00 += rr - r.x * r.x
                    a10 -= r.y * r.x
                    a11 += rr - r.y * r.y
                    a20 -= r.z * r.x
                    a21 -= r.z * r.y
                    a22 += rr - r.z * r.z
            lam2 = lam * lam
            x = solve3(w * a00 + lam2, w * a10, w * a11 + lam2, w * a20, w * a21, w * a22 + lam2,
                       sw * aimed_error(t, get3(pos, 0), p_eff, reach, dmax))
            failed = x[3] == 0.0
            y = sw * x[3] * x.xyz  # a void step is zero
            # take it: R_j <- D_j R_j, D_j = D_p exp(r_j x y), and FK, root to leaf
            for j in range(n_joints):
                p = parent[j]
                r_old = get4(rot, j)
                put(rot_bak, j, r_old)
                d = vec4(0.0, 0.0, 0.0, 1.0)
                if p >= 0:
                    d = get4(turn, p)
                if on_path[j] != 0:
                    d = qmul(d, qexp_series(ti.math.cross(p_eff - get3(pos, j), y)))
                put(turn, j, d)
                joint_fk_local(j, p, base_root, offset, rot, pos)
                put(rot, j, renormalize(qmul(d, r_old)))
            new = objective(t, get3(pos, 0), get3(pos, k), w, reach)
            if new[0] < f_cur and not failed:
                if f_cur - new[0] < FLAT * f_cur:
                    bad += 1
                else:
                    bad = 0
                f_cur = new[0]
                perr = new[1]
                accepted += 1
                lam = ti.max(0.5 * lam, damping)
                if accepted - ref_accepted >= WINDOW:  # too slow: F fell by less than PROGRESS
                    if f_cur > (1.0 - PROGRESS) * ref_f:
                        bad = STALL_AFTER
                    ref_f = f_cur
                    ref_accepted = accepted
            else:  # rejected: back to the pose before the step
                bad += 1
                lam *= 4.0
                for j in range(n_joints):
                    put(rot, j, get4(rot_bak, j))
                    joint_fk_local(j, parent[j], base_root, offset, rot, pos)
            if bad >= STALL_AFTER or lam > LAM_CAP * length:
                stop = 1
            if accepted >= max_iterations or attempts >= max_attempts or stop == 1 or perr <= tolerance:
                go = 0
                if stop == 0 and accepted < max_iterations and perr > tolerance:
                    stop = 1  # attempts ran out: too many rejected steps
        for j in range(n_joints):
            q = get4(rot, j)
            world_rot[i, j] = q
            world_pos[i, j] = root_pos[i] + get3(pos, j)
            if accepted > 0 and kind[j] > 0:
                base_rot = base_root
                if parent[j] >= 0:
                    base_rot = get4(rot, parent[j])
                local_rot[i, j] = qnormalize(qmul(qconj(base_rot), q))
        error[i] = perr
        iterations[i] = accepted
        stalled[i] = stop
