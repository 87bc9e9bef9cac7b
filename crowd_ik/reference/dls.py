"""NumPy twin of kernels/dls.py: damped least squares with LM damping and an active set, batched over characters.

The same algorithm as the kernel (read its docstring for the maths), vectorised over N with the
R x R systems solved by np.linalg.solve on (N, R, R) stacks; loops run over joints, effectors and
iterations only. Used by the tests as the kernel's oracle and by the benchmark as the NumPy
baseline. :func:`dls_settings` holds the constants both share (so they cannot drift apart).

Static balance (the lecture's g(q) = |f_com(q) - f_feet(q)|^2): the centre of mass c = sum_b m_b
midpoint_b / sum_b m_b over the bones (bone b from joint b's parent to joint b; its mass taken
proportional to its length times rig.joints[b].radius^2, a uniform-density cylinder), the support
point s = the mean of the foot effectors' positions (effectors named "foot..."), and the balance
error the horizontal (x, z) part of c - s. With balance_weight = beta_b > 0 the objective gains
beta_b |(c - s)_xz|^2 and the system two rows sqrt(beta_b) (d(c - s)/dq)_x,z aiming at -(c - s)_x,z.
Both c and s are weighted sums of joint positions (:func:`balance_weights`), so one walk up the tree
gives, per joint n, the lever sum_j a_j (p_j - p_n) over the points below it, and the column of a
DOF with world axis w at joint n is w x lever (the support moves with the feet: its rows are
subtracted, not held fixed). The solve also waits for |(c - s)_xz| <= tolerance, like an orientation.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.quat import constrain_rotation, joint_angles, qconj, qmul, qnormalize, qrot
from crowd_ik.reference.dls_system import (  # noqa: F401  (balance_offset, qlog, swing_vector: the tests' too)
    _build, _fk, _objective, _parent_rot, _Rig, _set_joint, _solve, _yaw, balance_offset, qexp, qlog, swing_vector,
)
from crowd_ik.rig import Rig
from crowd_ik.solvers.dls_setup import balance_weights, dls_settings  # noqa: F401  (the tests' too)
# The solver's constants live in crowd_ik/solvers/settings.py, shared with kernels/dls.py.
from crowd_ik.solvers.settings import (
    DLS_DAMPING_MIN as DAMPING_MIN, DLS_ESCAPE_ATTEMPTS as ESCAPE_ATTEMPTS, DLS_FLAT as FLAT, DLS_KICK as KICK, DLS_LAM_CAP as LAM_CAP,
    DLS_LIMIT_EPS as LIMIT_EPS, DLS_MAX_ESCAPES as MAX_ESCAPES, DLS_NULL_BAND as NULL_BAND,
    DLS_NULL_STEP as NULL_STEP, DLS_PROGRESS as PROGRESS, DLS_STALL_AFTER as STALL_AFTER, DLS_WINDOW as WINDOW,
)


def _freeze(R: _Rig, theta, step, free):
    """Freeze free angle DOFs on a limit whose step points outward; returns which characters changed."""
    changed = np.zeros(theta.shape[0], bool)
    for jt in R.joints:
        if jt["k"] == 0 or not jt["angle"]:
            continue
        for c in range(jt["k"]):
            d = jt["s"] + c
            out = (free[:, d] > 0) & (((theta[:, d] <= jt["lo"][c] + LIMIT_EPS) & (step[:, d] < 0))
                                      | ((theta[:, d] >= jt["hi"][c] - LIMIT_EPS) & (step[:, d] > 0)))
            free[:, d] = np.where(out, 0.0, free[:, d])
            changed |= out
    return changed


def _apply(R: _Rig, st, step):
    """New (theta, rot, pos, wrot) after the step: clamped, cones projected, FK."""
    theta = st["theta"] + 0.0
    rot = st["rot"].copy()
    q_root = _yaw(st["yaw"])
    if R.root:  # the root's translation
        theta[:, R.rig.n_dof :] += step[:, R.rig.n_dof :]
    for j, jt in enumerate(R.joints):
        k, s = jt["k"], jt["s"]
        if k == 0:
            continue
        if jt["angle"]:
            theta[:, s : s + k] += step[:, s : s + k]
            _set_joint(jt, theta, rot, j)
        else:
            base = _parent_rot(jt, q_root, st["wrot"])
            q = qnormalize(qmul(qexp(qrot(qconj(base), step[:, s : s + 3])), rot[:, j]))
            if jt["cone"] > 0:
                q = constrain_rotation(3, jt["axes"], q, jt["lo"], jt["hi"], jt["cone"], jt["bone"])
            rot[:, j] = q
    pos, wrot = _fk(R.rig, st["yaw"], rot)
    return dict(st, theta=theta, rot=rot, pos=pos, wrot=wrot)


def _take(st, idx):
    return {k: v[idx] for k, v in st.items()}


def _kick(R: _Rig, theta, free, joint_w):
    """Escape step (n, D): every weighted angle DOF frozen on a limit moves inward by min(KICK, half its range)."""
    step = np.zeros_like(theta)
    for jt in R.joints:
        if jt["k"] == 0 or not jt["angle"]:
            continue
        for c in range(jt["k"]):
            d = jt["s"] + c
            lo, hi = jt["lo"][c], jt["hi"][c]
            size = min(KICK, 0.5 * (hi - lo))
            frozen = (free[:, d] == 0) & (joint_w[d] > 0) & (size > 0)
            step[:, d] = np.where(frozen & (theta[:, d] <= lo + LIMIT_EPS), size,
                                  np.where(frozen & (theta[:, d] >= hi - LIMIT_EPS), -size, 0.0))
    return step


def dls_solve(rig: Rig, root_pos, root_yaw, rot, targets, weights=None, orientations=None, max_iterations=20,
              tolerance=1e-3, damping=None, rest_weight=0.0, velocity_weight=0.0, joint_weights=None,
              balance_weight=0.0, rotations=None, rotation_weights=None, root_weight=None):
    """Solve N characters from local rotations rot (N, J, 4); returns (rot, world_pos, error, iterations, stalled),
    and with root_weight (a free root, weighted like a joint; dim components of a planar rig) the moved roots
    (N, 3) as a sixth item.

    root_pos (N, 3), root_yaw (N,), targets (N, E, 3) world metres; weights (N, E) (default ones);
    orientations (N, E, 3) unit directions or zero; joint_weights (D,) (default ones). The other
    arguments as in Crowd.solve(method="dls"). Float64 throughout; each pass of the loop below is
    one pass of the kernel's per-character loop, over every character still running. (The kernel
    also voids a step whose float32 Cholesky meets a non-positive pivot; in float64 with lam > 0
    that cannot happen.) rotations (N, E, 4) x y z w full rotation targets of the effector joints' world
    rotations with rotation_weights (N, E) (0 or a zero row: none), or None.
    """
    joint_w = np.ones(rig.n_dof) if joint_weights is None else np.asarray(joint_weights, np.float64)
    settings = dls_settings(rig, damping, joint_w)
    R = _Rig(rig, settings, root=root_weight is not None)
    if R.root:
        joint_w = np.concatenate([joint_w, np.where(np.arange(3) < rig.dim, float(root_weight), 0.0)])
    root_pos = np.asarray(root_pos, np.float64)
    N, E, D = root_pos.shape[0], rig.n_effectors, R.n_col
    yaw = np.asarray(root_yaw, np.float64)
    tgt = np.asarray(targets, np.float64) - root_pos[:, None, :]
    weights = np.ones((N, E)) if weights is None else np.broadcast_to(np.asarray(weights, np.float64), (N, E))
    orient = np.zeros((N, E, 3)) if orientations is None else np.asarray(orientations, np.float64)
    length, lam0, eff_lim = settings["length"], settings["damping"], settings["eff_lim"].astype(np.float64)
    rest_w, vel_w, bal_w = float(rest_weight), float(velocity_weight), float(balance_weight)
    null = rest_w > 0 or vel_w > 0 or bal_w > 0  # the secondary terms in the null space of the targets
    band = NULL_BAND * tolerance
    if bal_w > 0 and not settings["has_feet"]:
        raise ValueError("balance_weight: the rig has no foot effectors")
    rot_t = rot_w = None
    if rotations is not None:
        rot_t = np.asarray(rotations, np.float64).reshape(N, E, 4)
        rot_w = np.ones((N, E)) if rotation_weights is None else np.broadcast_to(
            np.asarray(rotation_weights, np.float64), (N, E))
        rot_w = np.where(np.sum(rot_t * rot_t, -1) > 0, rot_w, 0.0)
    obj_args = (tgt, weights, orient, eff_lim, length, rest_w, vel_w, bal_w)

    def rot_of(ids):
        return (None, None) if rot_w is None else (rot_t[ids], rot_w[ids])

    rot = np.array(rot, np.float64)
    theta = np.zeros((N, D))
    for j, jt in enumerate(R.joints):
        if jt["angle"]:
            theta[:, jt["s"] : jt["s"] + jt["k"]] = joint_angles(jt["k"], jt["axes"], rot[:, j])
    pos, wrot = _fk(rig, yaw, rot)
    # the first pass applies a zero step: the start pose projected onto the DOFs and limits
    st = _apply(R, dict(theta=theta, theta0=theta, rot=rot, q0=rot, pos=pos, wrot=wrot, yaw=yaw), np.zeros((N, D)))
    st["theta0"], st["q0"] = st["theta"].copy(), st["rot"].copy()
    # (N, 5): F, max position error, max(orientation error * L, balance error), S, orientation error * L
    obj = np.stack(_objective(R, st, *obj_args, *rot_of(slice(None))), axis=1)
    ref_f, ref_s, ref_acc = obj[:, 0].copy(), obj[:, 3].copy(), np.zeros(N, np.int32)
    lam = np.full(N, lam0)
    accepted = np.zeros(N, np.int32)
    attempts = np.zeros(N, np.int32)
    bad = np.zeros(N, np.int32)
    stop = np.zeros(N, bool)
    kick = np.zeros(N, bool)  # the pending step is an escape kick
    esc = np.zeros(N, bool)  # on probation after a kick
    esc_left = np.zeros(N, np.int32)
    escapes = np.zeros(N, np.int32)
    saved = dict(theta=st["theta"].copy(), rot=st["rot"].copy(), obj=obj.copy(), accepted=accepted.copy())
    free = np.ones((N, D))
    step = np.zeros((N, D))
    max_attempts = 2 * max_iterations + 8
    go = np.zeros(N, bool)
    zon = np.ones(N)  # 0 once the secondary terms are dropped

    def restore_saved(ids):
        st["theta"][ids], st["rot"][ids] = saved["theta"][ids], saved["rot"][ids]
        st["pos"][ids], st["wrot"][ids] = _fk(rig, yaw[ids], st["rot"][ids])
        obj[ids], accepted[ids] = saved["obj"][ids], saved["accepted"][ids]
        esc[ids] = False
        ref_f[ids], ref_s[ids], ref_acc[ids] = obj[ids, 0], obj[ids, 3], accepted[ids]

    def plan(ids):
        """Next step of the characters ids: an escape kick, or the LM step with the active set."""
        attempts[ids] += 1
        k = ids[kick[ids]]
        step[k] = _kick(R, st["theta"][k], free[k], joint_w)
        m = ids[~kick[ids]]
        if m.size == 0:
            return
        sub = _take(st, m)
        jac, err, g = _build(R, sub, tgt[m], weights[m], orient[m], eff_lim, length, rest_w, vel_w, bal_w,
                             *rot_of(m))
        fr = np.ones((m.size, D))
        lam2 = lam[m] ** 2
        sec = dict(bal_row=5 * E if bal_w > 0 else None, zmax=zon[m] * NULL_STEP * lam0 / lam[m],
                   mu2=(DAMPING_MIN * length) ** 2) if null else {}
        stp = _solve(jac, err, g, lam2, fr, joint_w, rest_w, vel_w, **sec)
        for _ in range(D + 1):
            changed = _freeze(R, sub["theta"], stp, fr)
            if not changed.any():
                break
            c = np.flatnonzero(changed)
            if null:
                sec["zmax"] = zon[m[c]] * NULL_STEP * lam0 / lam[m[c]]
            stp[c] = _solve(jac[c], err[c], g[c], lam2[c], fr[c], joint_w, rest_w, vel_w, **sec)
        step[m], free[m] = stp, fr

    def decide(ids):
        """Stall and escape bookkeeping, the stopping test, and the next step for those that go on."""
        stalled_now = (bad[ids] >= STALL_AFTER) | (lam[ids] > LAM_CAP * length)
        back = stalled_now & esc[ids]  # a stalled escape goes back to the pose before its kick
        stop[ids[back]] = True
        if null:  # the secondary step held the targets off: go on with the targets alone
            drop = stalled_now & ~esc[ids] & (zon[ids] > 0) & ((obj[ids, 1] > tolerance) | (obj[ids, 4] > tolerance))
            zon[ids[drop]], bad[ids[drop]], lam[ids[drop]] = 0.0, 0, lam0
            stalled_now &= ~drop
        fresh = ids[stalled_now & ~esc[ids] & (escapes[ids] < MAX_ESCAPES)]
        can = fresh[np.any(_kick(R, st["theta"][fresh], free[fresh], joint_w) != 0, axis=1)]
        for key in ("theta", "rot"):
            saved[key][can] = st[key][can]
        saved["obj"][can], saved["accepted"][can] = obj[can], accepted[can]
        kick[can], escapes[can], bad[can], lam[can] = True, escapes[can] + 1, 0, lam0
        stop[np.setdiff1d(ids[stalled_now & ~esc[ids]], can)] = True
        spent = esc[ids] & (esc_left[ids] <= 0) & ~back
        stop[ids[spent]] = True
        back |= spent
        conv = (obj[ids, 1] <= tolerance) & (obj[ids, 2] <= tolerance)
        cont = (accepted[ids] < max_iterations) & (attempts[ids] < max_attempts) & ~stop[ids] & ~conv
        back |= ~cont & esc[ids]
        restore_saved(ids[back])
        conv = (obj[ids, 1] <= tolerance) & (obj[ids, 2] <= tolerance)
        stop[ids[~cont & ~stop[ids] & ~conv & (accepted[ids] < max_iterations)]] = True  # attempts ran out
        go[:] = False
        go[ids[cont]] = True
        plan(ids[cont])

    decide(np.arange(N))
    while go.any():
        idx = np.flatnonzero(go)
        trial = _apply(R, _take(st, idx), step[idx])
        new = np.stack(_objective(R, trial, tgt[idx], weights[idx], orient[idx], *obj_args[3:], *rot_of(idx)),
                       axis=1)
        kicked = kick[idx]
        better = new[:, 0] < obj[idx, 0]
        flat = obj[idx, 0] - new[:, 0] < FLAT * obj[idx, 0]
        if null:  # also taken when S falls while every target error stays in the band
            better |= (new[:, 3] < obj[idx, 3]) & (new[:, 1] <= band) & (new[:, 4] <= band)
            flat &= obj[idx, 3] - new[:, 3] < FLAT * obj[idx, 3]
        better |= kicked
        flat &= ~kicked & better
        acc = idx[better]
        for key in ("theta", "rot", "pos", "wrot"):
            st[key][acc] = trial[key][better]
        obj[acc] = new[better]
        accepted[acc] += 1
        if null:  # back in the band: the secondary step resumes
            zon[acc[(obj[acc, 1] <= band) & (obj[acc, 4] <= band)]] = 1.0
        lam[acc] = np.where(kicked[better], lam0, np.maximum(0.5 * lam[acc], lam0))
        bad[idx] = np.where(better & ~flat, 0, bad[idx] + 1)
        lam[idx[~better]] *= 4.0
        esc[idx[kicked]], esc_left[idx[kicked]], kick[idx] = True, ESCAPE_ATTEMPTS, False
        # too slow: F fell by less than PROGRESS over the last WINDOW accepted steps
        plain = idx[better & ~kicked]
        due = plain[accepted[plain] - ref_acc[plain] >= WINDOW]
        slow = obj[due, 0] > (1.0 - PROGRESS) * ref_f[due]
        if null:  # S's progress counts once the targets are within tolerance
            slow &= ((obj[due, 3] >= (1.0 - PROGRESS) * ref_s[due]) | (obj[due, 1] > tolerance)
                     | (obj[due, 4] > tolerance))
        bad[due[slow]] = STALL_AFTER
        ref_f[due], ref_s[due], ref_acc[due] = obj[due, 0], obj[due, 3], accepted[due]
        k = idx[kicked]
        ref_f[k], ref_s[k], ref_acc[k] = obj[k, 0], obj[k, 3], accepted[k]
        # on probation: kept once it beats the pose before the kick (or converges)
        probe = idx[esc[idx] & ~kicked]
        conv = (obj[probe, 1] <= tolerance) & (obj[probe, 2] <= tolerance)
        esc[probe[(obj[probe, 0] < saved["obj"][probe, 0]) | conv]] = False
        esc_left[probe] -= 1
        decide(idx)
    roots = root_pos + (st["theta"][:, rig.n_dof :] if R.root else 0.0)
    world_pos = st["pos"] + roots[:, None, :]
    out = st["rot"], world_pos, obj[:, 1].copy(), accepted, stop.astype(np.int32)
    return out + (roots,) if R.root else out


def balance_rows(rig: Rig, root_yaw, rot, balance_weight: float = 1.0, joint_weights=None):
    """(aimed error (N, 2), rows (N, 2, D)): the solver's balance rows at local rotations rot (N, J, 4).

    The columns are the solver's (angle DOFs, or world-axis rotations of quaternion-mode ball joints).
    """
    settings = dls_settings(rig, None, joint_weights)
    R = _Rig(rig, settings)
    rot = np.asarray(rot, np.float64)
    N, E = rot.shape[0], rig.n_effectors
    yaw = np.asarray(root_yaw, np.float64)
    theta = np.zeros((N, rig.n_dof))
    for j, jt in enumerate(R.joints):
        if jt["angle"]:
            theta[:, jt["s"] : jt["s"] + jt["k"]] = joint_angles(jt["k"], jt["axes"], rot[:, j])
    pos, wrot = _fk(rig, yaw, rot)
    st = dict(theta=theta, theta0=theta, rot=rot, q0=rot, pos=pos, wrot=wrot, yaw=yaw)
    jac, err, _ = _build(R, st, np.zeros((N, E, 3)), np.zeros((N, E)), np.zeros((N, E, 3)),
                         settings["eff_lim"].astype(np.float64), settings["length"], 0.0, 0.0, float(balance_weight))
    return err[:, 5 * E :], jac[:, 5 * E :]


__all__ = ["dls_solve", "dls_settings", "balance_weights", "balance_offset", "balance_rows", "qlog", "qexp",
           "swing_vector"]
