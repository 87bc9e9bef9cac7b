"""Damped least squares for a single position effector on a constraint-free rig, LANES characters per thread.

The same solve as kernels/dls.py's dls_solve (the same steps, LM damping, acceptance and stall tests,
so the same poses up to float32 rounding) when every joint is an unlimited ball (or fixed), the rig has
one effector with a position target, and there is no rest, velocity or balance term and no joint
weights. There the problem has closed forms that the general kernel computes the long way:

- Every ball joint n on the effector's path moves by a world-axis rotation vector; its three columns
  are a x r_n for a = x, y, z, r_n = p_eff - p_n, i.e. J_n = -[r_n]x. Hence
  J J^T = sum_n [r_n]x [r_n]x^T = sum_n (|r_n|^2 I - r_n r_n^T), a 3 x 3 sum built in one pass over
  the path (no Jacobian is stored), and the DLS step of joint n is J_n^T y = r_n x y with
  y = (w J J^T + lam^2 I)^-1 sqrt(w) e (Buss 2004, eq. 11, rows scaled by sqrt(w)).
- The step, the update q <- exp(R_p^-1 w) q and forward kinematics run in one pass root to leaf (a
  joint's step needs the pose it was computed at: the old rotations are kept as the backup that a
  rejected step restores).

One character per thread: running several interleaved per thread (as fabrik_solve_free does) gave
nothing here (chain16, 100,000 characters: 216k, 220k, 216k, 213k solves/s with 1, 2, 4, 8 per
thread), the passes have enough independent work per joint; what did pay was the series form of the
step's exponential (qexp_series, 216k -> 266k).
"""

import taichi as ti

from crowd_ik.kernels.quat import qconj, qmul, qnormalize, qrot, yaw_quat, vec3, vec4
from crowd_ik.reference.dls import FLAT, LAM_CAP, PROGRESS, STALL_AFTER, WINDOW

ndarray = ti.types.ndarray
OLD_LOCAL, OLD_WORLD = 0, 1  # slots of the backup bak[i, slot, j]


@ti.func
def objective(i, k, w, eff_lim: ti.template(), targets: ti.template(), root_pos: ti.template(),
              rel_pos: ti.template()):
    """(F, position error) of character i's pose: dls.objective for one position effector of weight w."""
    f = 0.0
    perr = 0.0
    if w > 0.0:
        t = targets[i, 0] - root_pos[i]
        base = rel_pos[i, 0]
        p = rel_pos[i, k]
        d = t - p
        perr = d.norm()
        r = t - base
        dist = r.norm()
        reach = eff_lim[0, 0]
        if dist > reach:
            q = p - base
            qn = q.norm()
            f = w * (2.0 * (dist * reach - r.dot(q)) - (reach - qn) * (reach + qn))
        else:
            f = w * d.norm_sqr()
    return ti.math.vec2(f, perr)


@ti.func
def aimed_error(i, k, eff_lim: ti.template(), targets: ti.template(), root_pos: ti.template(),
                rel_pos: ti.template()):
    """The error a step aims to remove: the target pulled to reach + d_max from the root, then clamped to d_max."""
    reach = eff_lim[0, 0]
    dmax = eff_lim[0, 1]
    base = rel_pos[i, 0]
    tgt = targets[i, 0] - root_pos[i]
    v = tgt - base
    dist = v.norm()
    if dist > reach + dmax:
        tgt = base + v * ((reach + dmax) / dist)
    d = tgt - rel_pos[i, k]
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
def step_joint(i, j, p, has_dof, moves, stepping, p_eff, y, base_root, offset: ti.template(),
               local_rot: ti.template(), world_rot: ti.template(), rel_pos: ti.template(), bak: ti.template()):
    """Joint j of character i: back up its rotations, add its step r_j x y (stepping), and run its FK."""
    q = local_rot[i, j]
    bak[i, OLD_LOCAL, j] = q
    bak[i, OLD_WORLD, j] = world_rot[i, j]
    base_new = base_root
    base_old = base_root
    base_pos = vec3(0.0)
    if p >= 0:
        base_new = world_rot[i, p]
        base_old = bak[i, OLD_WORLD, p]
        base_pos = rel_pos[i, p]
    if has_dof:
        wv = vec3(0.0)
        if stepping and moves:
            wv = ti.math.cross(p_eff - rel_pos[i, j], y)
        q = qnormalize(qmul(qexp_series(qrot(qconj(base_old), wv)), q))
        local_rot[i, j] = q
    rel_pos[i, j] = base_pos + qrot(base_new, offset[j])
    world_rot[i, j] = qmul(base_new, q)


@ti.func
def restore_joint(i, j, p, base_root, offset: ti.template(), local_rot: ti.template(), world_rot: ti.template(),
                  rel_pos: ti.template(), bak: ti.template()):
    """Joint j of character i back to its backed-up rotations (the positions follow by FK)."""
    local_rot[i, j] = bak[i, OLD_LOCAL, j]
    world_rot[i, j] = bak[i, OLD_WORLD, j]
    base_rot = base_root
    base_pos = vec3(0.0)
    if p >= 0:
        base_rot = world_rot[i, p]
        base_pos = rel_pos[i, p]
    rel_pos[i, j] = base_pos + qrot(base_rot, offset[j])


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
    rel_pos: ndarray(dtype=vec3, ndim=2),
    bak: ndarray(dtype=vec4, ndim=3),
    max_iterations: ti.i32,
    tolerance: ti.f32,
    damping: ti.f32,
    length: ti.f32,
    error: ndarray(ndim=1),
    iterations: ndarray(dtype=ti.i32, ndim=1),
    stalled: ndarray(dtype=ti.i32, ndim=1),
):
    """dls_solve for one position effector on a constraint-free rig (see the module docstring), in place.

    on_path (J,): 1 for the joints with DOFs on the effector's path to the root. eff_lim (1, 2): reach
    and d_max. Scratch: rel_pos (N, J), bak (N, 2, J). Other arguments and outputs as dls_solve.
    """
    J = parent.shape[0]
    k = eff_joint[0]
    max_attempts = 2 * max_iterations + 8
    for i in range(root_pos.shape[0]):
        base_root = yaw_quat(root_yaw[i])
        w = weights[i, 0]
        sw = ti.sqrt(ti.max(w, 0.0))
        lam = damping
        f_cur = 0.0
        perr = 0.0
        ref_f = 0.0
        accepted = 0
        ref_accepted = 0
        attempts = 0
        bad = 0
        stop = 0
        failed = 0
        stepping = 0  # 0 for the first pass: the start pose projected (normalised), no step
        p_eff = vec3(0.0)  # effector position at the pose the step was built at
        y = vec3(0.0)  # sqrt(w) (w J J^T + lam^2 I)^-1 sqrt(w) e
        live = 1
        while live == 1:
            for j in range(J):
                step_joint(i, j, parent[j], kind[j] > 0, on_path[j] != 0, stepping, p_eff, y, base_root, offset,
                           local_rot, world_rot, rel_pos, bak)
            new = objective(i, k, w, eff_lim, targets, root_pos, rel_pos)
            rejected = 0
            if stepping == 0:
                f_cur = new[0]
                perr = new[1]
                ref_f = new[0]
            elif new[0] < f_cur and failed == 0:
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
            else:
                rejected = 1
                bad += 1
                lam *= 4.0
            if bad >= STALL_AFTER or lam > LAM_CAP * length:
                stop = 1
            if accepted >= max_iterations or attempts >= max_attempts or stop == 1 or perr <= tolerance:
                live = 0
                if stop == 0 and accepted < max_iterations and perr > tolerance:
                    stop = 1  # attempts ran out: too many rejected steps
            if rejected == 1:
                for j in range(J):
                    restore_joint(i, j, parent[j], base_root, offset, local_rot, world_rot, rel_pos, bak)
            if live == 1:
                # the next step: A = w sum_n (|r_n|^2 I - r_n r_n^T) + lam^2 I over the path, b = sqrt(w) e
                attempts += 1
                stepping = 1
                p_eff = rel_pos[i, k]
                a00, a10, a11, a20, a21, a22 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
                for j in range(J):
                    if on_path[j] != 0:
                        r = p_eff - rel_pos[i, j]
                        rr = r.norm_sqr()
                        a00 += rr - r.x * r.x
                        a10 -= r.y * r.x
                        a11 += rr - r.y * r.y
                        a20 -= r.z * r.x
                        a21 -= r.z * r.y
                        a22 += rr - r.z * r.z
                lam2 = lam * lam
                x = solve3(w * a00 + lam2, w * a10, w * a11 + lam2, w * a20, w * a21, w * a22 + lam2,
                           sw * aimed_error(i, k, eff_lim, targets, root_pos, rel_pos))
                failed = 1 if x[3] == 0.0 else 0
                y = sw * x[3] * x.xyz  # a void step is zero
        for j in range(J):
            world_pos[i, j] = root_pos[i] + rel_pos[i, j]
        error[i] = perr
        iterations[i] = accepted
        stalled[i] = stop
