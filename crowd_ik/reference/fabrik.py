"""NumPy twin of kernels/fabrik.py, vectorised over characters: the tests' oracle and the benchmark baseline.

The same three steps per iteration (backward pass with weighted sub-base centroids, forward pass from
the fixed root, rotation recovery with limits and FK); characters that have converged or stalled are
frozen by masks, as the kernel's per-character loop exits.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.quat import (
    align_axis, axis_angle, best_angle_about, constrain_rotation, qconj, qmul, qnormalize, qrot, safe_normalize,
    swing, twist_angle, wrap_angle,
)
from crowd_ik.geometry.fk import yaw_quat
from crowd_ik.reference import fabrik_rotation as rt
from crowd_ik.rig import Rig

# The solver's constants live in crowd_ik/solvers/settings.py, shared with kernels/fabrik.py.
from crowd_ik.solvers.settings import (
    FABRIK_FLAT as FLAT, FABRIK_STALL_AFTER as STALL_AFTER, SWING_ROUNDS, TWIST_FULL_BEND, TWIST_MIN_BEND,
)


def _error(rig: Rig, pos: np.ndarray, targets: np.ndarray, weights: np.ndarray) -> np.ndarray:
    d = np.linalg.norm(pos[:, rig.arrays["eff_joint"]] - targets, axis=-1)
    return np.max(np.where(weights > 0, d, 0.0), axis=1)


def _turn(rig: Rig, wrot: np.ndarray, weights: np.ndarray, orient: np.ndarray) -> np.ndarray:
    arr = rig.arrays
    axis = qrot(wrot[:, arr["eff_joint"]], np.broadcast_to(arr["eff_axis"].astype(np.float64), orient.shape))
    has = (weights > 0) & (np.sum(orient * orient, -1) > 0)
    return np.max(np.where(has, 1.0 - np.sum(axis * orient, -1), 0.0), axis=1)


def _passes(rig: Rig, pos: np.ndarray, targets: np.ndarray, weights: np.ndarray, rot=None, rot_t=None, rot_w=None):
    N, J = pos.shape[:2]
    offset = rig.arrays["offset"].astype(np.float64)
    length = np.linalg.norm(offset, axis=1)
    work = np.zeros((N, J, 3))
    acc = np.zeros((N, J))
    for e, eff in enumerate(rig.effectors):
        w = weights[:, e]
        work[:, eff.joint] += w[:, None] * targets[:, e]
        acc[:, eff.joint] += w
    for j in range(J - 1, 0, -1):
        w = acc[:, j]
        on = w > 0
        pj = work[:, j] / np.where(on, w, 1.0)[:, None]
        work[:, j] = np.where(on[:, None], pj, work[:, j])
        p = rig.joints[j].parent
        toward = safe_normalize(pos[:, p] - pj, -offset[j] / length[j])
        if rot_t is not None:
            toward = rt.extended_toward(rig, j, length[j], toward, rot, rot_t, rot_w)
        work[:, p] += np.where(on[:, None], w[:, None] * (pj + length[j] * toward), 0.0)
        acc[:, p] += np.where(on, w, 0.0)
    work[:, 0] = pos[:, 0]
    for j in range(1, J):
        on = acc[:, j] > 0
        p = rig.joints[j].parent
        d = safe_normalize(work[:, j] - work[:, p], offset[j] / length[j])
        work[:, j] = np.where(on[:, None], work[:, p] + length[j] * d, work[:, j])
    return work, acc


def _hinge_twist(rig, j, q, inv_base, pos_j, work, acc):
    """Twin of fabrik.twist_for_hinge_child for ball joint j over all characters."""
    arr = rig.arrays
    kids = [c for c in rig.children[j]]
    c = np.full(q.shape[0], -1)
    for k in kids:
        c = np.where(acc[:, k] > 0, k, c)
    out = q.copy()
    for k in kids:
        if rig.joints[k].kind != "hinge":
            continue
        sel = c == k
        g = np.full(q.shape[0], -1)
        for gg in rig.children[k]:
            g = np.where(acc[:, gg] > 0, gg, g)
        sel &= g >= 0
        if not np.any(sel):
            continue
        gi = np.maximum(g, 0)
        rows = np.arange(q.shape[0])
        b = qrot(q, np.broadcast_to(arr["offset"][k].astype(np.float64), q.shape[:-1] + (3,)))
        b = b / np.linalg.norm(b, axis=-1, keepdims=True)
        u = qrot(inv_base, work[:, k] - pos_j)
        v = qrot(inv_base, work[rows, gi] - work[:, k])
        n = np.cross(u, v)
        nn = np.linalg.norm(n, axis=-1)
        bend = nn / np.maximum(np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1), 1e-12)
        sel &= bend > TWIST_MIN_BEND
        n = n / np.maximum(nn, 1e-30)[:, None]
        axis = qrot(q, np.broadcast_to(np.array(rig.joints[k].axes[0]), q.shape[:-1] + (3,)))
        lo, hi = rig.joints[k].lo[0], rig.joints[k].hi[0]
        if lo >= 0:
            sign = np.ones(q.shape[0])
        elif hi <= 0:
            sign = -np.ones(q.shape[0])
        else:
            sign = np.where(np.sum(axis * n, -1) < 0, -1.0, 1.0)
        n = sign[:, None] * n
        a_p = axis - np.sum(axis * b, -1, keepdims=True) * b
        n_p = n - np.sum(n * b, -1, keepdims=True) * b
        sel &= (np.linalg.norm(a_p, axis=-1) > 1e-6) & (np.linalg.norm(n_p, axis=-1) > 1e-6)
        ramp = np.minimum(1.0, (bend - TWIST_MIN_BEND) / (TWIST_FULL_BEND - TWIST_MIN_BEND))
        ang = ramp * np.arctan2(np.sum(b * np.cross(a_p, n_p), -1), np.sum(a_p * n_p, -1))
        turned = qnormalize(qmul(axis_angle(b, ang), q))
        out = np.where(sel[:, None], turned, out)
    return out


def _two_bone(rig, j, q, inv_base, pos_j, rot, work, acc):
    """Twin of fabrik.two_bone_swing for ball joint j over all characters: (rotations, mask of those it solved)."""
    arr = rig.arrays
    N = q.shape[0]
    rows = np.arange(N)
    offset = arr["offset"].astype(np.float64)
    lo_all, hi_all = arr["lo"].astype(np.float64), arr["hi"].astype(np.float64)
    c = np.full(N, -1)
    for k in rig.children[j]:
        c = np.where(acc[:, k] > 0, k, c)
    out, ok = q.copy(), np.zeros(N, bool)
    for k in rig.children[j]:
        if rig.joints[k].kind != "hinge":
            continue
        g = np.full(N, -1)
        n_g = np.zeros(N, int)
        for gg in rig.children[k]:
            g = np.where(acc[:, gg] > 0, gg, g)
            n_g += acc[:, gg] > 0
        gi = np.maximum(g, 0)
        # a rigid leaf past g (the hand past the wrist) ends the limb instead, at g's current angles
        end = gi.copy()
        b = offset[gi]
        for gg in rig.children[k]:
            n_h = sum((acc[:, hh] > 0).astype(int) for hh in rig.children[gg])
            for hh in rig.children[gg]:
                if rig.joints[hh].kind == "fixed" and not rig.children[hh]:
                    use = (g == gg) & (n_h == 1) & (acc[:, hh] > 0)
                    b_h = offset[gg] + qrot(rot[:, gg], np.broadcast_to(offset[hh], (N, 3)))
                    end = np.where(use, hh, end)
                    b = np.where(use[:, None], b_h, b)
        want = qrot(inv_base, work[rows, end] - pos_j)
        d2 = np.sum(want * want, -1)
        ax = np.array(rig.joints[k].axes[0], np.float64)
        a = offset[k]
        b_par = (b @ ax)[:, None] * ax
        b_perp = b - b_par
        A = b_perp @ a
        B = np.cross(ax, b_perp) @ a
        C = b_par @ a
        D = 0.5 * (d2 - a @ a - np.sum(b * b, -1))
        R = np.sqrt(A * A + B * B)
        sel = (c == k) & (n_g == 1) & (R > 1e-9) & (d2 > 1e-12)
        if not np.any(sel):
            continue
        s = rig.dof_start[k]
        phi = np.arctan2(B, A)
        spread = np.arccos(np.clip((D - C) / np.maximum(R, 1e-30), -1.0, 1.0))
        now = twist_angle(rot[:, k], ax)
        t, best = np.zeros(N), np.full(N, 1e30)
        for sign in (1.0, -1.0):
            cand = np.clip(wrap_angle(phi + sign * spread), lo_all[s], hi_all[s])
            score = np.abs(C + A * np.cos(cand) + B * np.sin(cand) - D) * 1e3 + np.abs(cand - now)
            t = np.where(score < best, cand, t)
            best = np.minimum(score, best)
        w = want / np.sqrt(np.maximum(d2, 1e-30))[:, None]
        v = a + qrot(axis_angle(np.broadcast_to(ax, (N, 3)), t), b)
        cur = qrot(q, v)
        swung = qnormalize(qmul(swing(cur / np.linalg.norm(cur, axis=-1, keepdims=True), w), q))
        # the swivel toward the proposed hinge position, kept where the limits allow it
        u_now = qrot(swung, np.broadcast_to(a, (N, 3)))
        u_now = u_now - np.sum(u_now * w, -1, keepdims=True) * w
        u_want = qrot(inv_base, work[:, k] - pos_j)
        shin = work[rows, end] - work[:, k]
        bend = np.linalg.norm(np.cross(u_want, qrot(inv_base, shin)), axis=-1) / np.maximum(
            np.linalg.norm(u_want, axis=-1) * np.linalg.norm(shin, axis=-1), 1e-12)
        u_want = u_want - np.sum(u_want * w, -1, keepdims=True) * w
        bend = np.minimum(bend, np.linalg.norm(u_now, axis=-1) / np.linalg.norm(a))
        ramp = np.minimum(1.0, (bend - TWIST_MIN_BEND) / (TWIST_FULL_BEND - TWIST_MIN_BEND))
        turn = ramp * best_angle_about(w, u_now, u_want)
        poled = qnormalize(qmul(axis_angle(w, turn), swung))
        sj = rig.dof_start[j]
        axes = np.array([ax, ax])
        first = a / np.linalg.norm(a)
        cone = rig.joints[j].cone or 0.0
        kept = constrain_rotation(3, axes, swung, lo_all[sj : sj + 3], hi_all[sj : sj + 3], cone, first)
        turned = constrain_rotation(3, axes, poled, lo_all[sj : sj + 3], hi_all[sj : sj + 3], cone, first)
        better = (np.linalg.norm(qrot(turned, v) - want, axis=-1)
                  <= np.linalg.norm(qrot(kept, v) - want, axis=-1) + 1e-4)
        use_pole = ((bend > TWIST_MIN_BEND) & (np.linalg.norm(u_want, axis=-1) > 1e-9) & (np.abs(turn) > 1e-5)
                    & better)
        chosen = np.where(use_pole[:, None], poled, swung)
        out = np.where(sel[:, None], chosen, out)
        # where g goes when the limb ends past it, so that the hinge recovers t and g keeps its angles
        moved = sel & (end != gi)
        lands = pos_j + qrot(qconj(inv_base), qrot(chosen, a + qrot(axis_angle(np.broadcast_to(ax, (N, 3)), t),
                                                                   offset[gi])))
        work[rows[moved], gi[moved]] = lands[moved]
        ok |= sel
    return out, ok


def _pass_up(rig, j, q_want, q, active, rot, pos, wrot, first_bone):
    """kernels/fabrik_pass_up.py: sub-base j (a ball joint with several active children) asked for q_want and was clamped to q; its parent (a ball joint with
    this one child, not the root) takes the excess within its limits (rot, wrot, pos updated in place) and j is
    re-clamped under it. Returns (j's rotation, its base rotation)."""
    arr = rig.arrays
    p = rig.joints[j].parent
    base_rot = wrot[:, p]
    par = rig.joints[p]
    if p <= 0 or par.kind != "ball" or len(rig.children[p]) != 1:
        return q, base_rot
    d = qmul(q_want, qconj(q))
    moved = active & (np.sum(d[:, :3] ** 2, -1) > 1e-12)
    if not np.any(moved):
        return q, base_rot
    lo_all, hi_all = arr["lo"].astype(np.float64), arr["hi"].astype(np.float64)
    offset = arr["offset"].astype(np.float64)
    joint = rig.joints[j]
    sp, s = rig.dof_start[p], rig.dof_start[j]
    q_p = rot[:, p]
    q_p2 = constrain_rotation(par.dof, np.array(par.axes or [(0, 0, 1)] * 2), qmul(q_p, d), lo_all[sp : sp + par.dof],
                              hi_all[sp : sp + par.dof], par.cone or 0.0, offset[j] / np.linalg.norm(offset[j]))
    q_p2 = np.where(moved[:, None], q_p2, q_p)
    rot[:, p] = q_p2
    wrot[:, p] = qmul(wrot[:, par.parent], q_p2)
    base_rot = wrot[:, p]
    pos[:, j] = np.where(moved[:, None], pos[:, p] + qrot(base_rot, np.broadcast_to(offset[j], pos[:, j].shape)),
                         pos[:, j])
    q2 = constrain_rotation(joint.dof, np.array(joint.axes or [(0, 0, 1)] * 2), qmul(qconj(q_p2), qmul(q_p, q_want)),
                            lo_all[s : s + joint.dof], hi_all[s : s + joint.dof], joint.cone or 0.0, first_bone)
    return np.where(moved[:, None], q2, q), base_rot


def _recover(rig, root_pos, q_root, rot, pos, wrot, work, acc, weights, orient, rot_goal=None):
    arr = rig.arrays
    offset = arr["offset"].astype(np.float64)
    lo_all, hi_all = arr["lo"].astype(np.float64), arr["hi"].astype(np.float64)
    N = rot.shape[0]
    for j, joint in enumerate(rig.joints):
        base_pos, base_rot = (root_pos, q_root) if joint.parent < 0 else (pos[:, joint.parent], wrot[:, joint.parent])
        pos_j = base_pos + qrot(base_rot, np.broadcast_to(offset[j], (N, 3)))
        pos[:, j] = pos_j
        q = rot[:, j]
        active = acc[:, j] > 0
        if joint.dof > 0 and np.any(active):
            inv_base = qconj(base_rot)
            kids = rig.children[j]
            first_bone = np.zeros(3)
            if joint.kind == "hinge":
                ax = np.array(joint.axes[0])
                s_cross = np.zeros(N)
                s_dot = np.zeros(N)
                for c in kids:
                    wc = acc[:, c]
                    u = qrot(q, np.broadcast_to(offset[c], (N, 3)))
                    u = u - (u @ ax)[:, None] * ax
                    v = qrot(inv_base, work[:, c] - pos_j)
                    v = v - (v @ ax)[:, None] * ax
                    s_cross += np.where(wc > 0, wc * (np.cross(u, v) @ ax), 0.0)
                    s_dot += np.where(wc > 0, wc * np.sum(u * v, -1), 0.0)
                turn = (s_cross != 0) | (s_dot != 0)
                new_q = qnormalize(qmul(axis_angle(ax, np.arctan2(s_cross, s_dot)), q))
                q = np.where(turn[:, None], new_q, q)
            else:
                n_active = np.zeros(N, int)
                for c in kids:
                    n_active += acc[:, c] > 0
                actives = [c for c in kids]
                firsts = np.full(N, -1)
                for c in reversed(actives):
                    firsts = np.where(acc[:, c] > 0, c, firsts)
                if len(kids) and np.all(firsts == firsts[0]) and firsts[0] >= 0:
                    first_bone = offset[firsts[0]] / np.linalg.norm(offset[firsts[0]])
                limb = np.zeros(N, bool)
                if joint.kind == "ball":
                    solved, limb = _two_bone(rig, j, q, inv_base, pos_j, rot, work, acc)
                    limb &= n_active == 1
                    q = np.where(limb[:, None], solved, q)
                rounds = np.where(n_active <= 1, 1, SWING_ROUNDS)
                for r in range(SWING_ROUNDS):
                    go = (n_active > 0) & (r < rounds) & ~limb
                    if not np.any(go):
                        break
                    total = np.zeros((N, 4))
                    for c in kids:
                        wc = acc[:, c]
                        cur = qrot(q, np.broadcast_to(offset[c], (N, 3)))
                        cur = cur / np.linalg.norm(cur, axis=-1, keepdims=True)
                        want = safe_normalize(qrot(inv_base, work[:, c] - pos_j), cur)
                        sw = swing(cur, want)
                        sw = np.where(sw[:, 3:] < 0, -sw, sw)
                        total += np.where((wc > 0)[:, None], wc[:, None] * sw, 0.0)
                    q = np.where(go[:, None], qnormalize(qmul(qnormalize(total), q)), q)
                if joint.kind == "ball":
                    twisted = _hinge_twist(rig, j, q, inv_base, pos_j, work, acc)
                    q = np.where(((n_active == 1) & ~limb)[:, None], twisted, q)
            for e, eff in enumerate(rig.effectors):
                if eff.joint != j:
                    continue
                has = (weights[:, e] > 0) & (np.sum(orient[:, e] ** 2, -1) > 0)
                if not np.any(has):  # an effector without an axis (eff_axis 0) has no rotation target to align
                    continue
                aligned = align_axis(joint.dof, np.array(joint.axes or [(0, 0, 1)] * 2), q,
                                     arr["eff_axis"][e].astype(np.float64), qrot(inv_base, orient[:, e]))
                q = np.where(has[:, None], aligned, q)
            if rot_goal is not None:
                q = rt.turn_onto_targets(rig, j, q, inv_base, pos_j, pos, wrot, *rot_goal)
            s = rig.dof_start[j]
            q_want = q
            q = constrain_rotation(joint.dof, np.array(joint.axes or [(0, 0, 1)] * 2), q,
                                   lo_all[s : s + joint.dof], hi_all[s : s + joint.dof], joint.cone or 0.0, first_bone)
            if joint.kind == "ball" and joint.parent > 0 and rot_goal is None:  # a sub-base, no rotation targets
                q, base_rot = _pass_up(rig, j, q_want, q, active & (n_active >= 2), rot, pos, wrot, first_bone)
            rot[:, j] = np.where(active[:, None], q, rot[:, j])
        wrot[:, j] = qmul(base_rot, rot[:, j])


def fabrik_solve(rig: Rig, root_pos, root_yaw, rot, targets, weights=None, orientations=None, max_iterations=20,
                 tolerance=1e-3, rotations=None, rotation_weights=None, rotation_tolerance=1e-2):
    """Solve N characters from local rotations rot (N, J, 4); returns (rot, pos, error, iterations, stalled).

    root_pos (N, 3), root_yaw (N,), targets (N, E, 3) world; weights (N, E); orientations (N, E, 3) or None;
    rotations (N, E, 4) x y z w targets of the effector joints' world rotations or None, rotation_weights (N, E)
    (default ones; 0: none).
    """
    from crowd_ik.geometry.fk import forward_kinematics

    rot = np.array(rot, np.float64)
    root_pos = np.asarray(root_pos, np.float64)
    N, E = rot.shape[0], rig.n_effectors
    targets = np.asarray(targets, np.float64)
    weights = np.ones((N, E)) if weights is None else np.broadcast_to(np.asarray(weights, np.float64), (N, E))
    orient = np.zeros((N, E, 3)) if orientations is None else np.asarray(orientations, np.float64)
    q_root = yaw_quat(root_yaw)
    pos, wrot = forward_kinematics(rig, root_pos, root_yaw, rot)
    err = _error(rig, pos, targets, weights)
    turn = _turn(rig, wrot, weights, orient)
    if rotations is not None:
        from crowd_ik.solvers.ccd import moving_joints

        rot_t = np.asarray(rotations, np.float64)
        rot_w = (np.ones((N, E)) if rotation_weights is None
                 else np.broadcast_to(np.asarray(rotation_weights, np.float64), (N, E)))
        move = moving_joints(rig)
        rturn = rt.rotation_error(rig, wrot, rot_t, rot_w)
    else:
        rturn = np.zeros(N)
    deferred = rig.constraint_free and orientations is None and rotations is None
    last_work = np.zeros(pos.shape) if deferred else None
    last_acc = np.zeros(pos.shape[:2]) if deferred else None
    iters = np.zeros(N, np.int32)
    flat = np.zeros(N, np.int32)
    stalled = np.zeros(N, bool)
    for _ in range(max_iterations):
        live = ((err > tolerance) | (turn > 1e-6) | (rturn > np.float32(rotation_tolerance))) & ~stalled
        if not np.any(live):
            break
        idx = np.nonzero(live)[0]
        r, p, w = rot[idx], pos[idx], wrot[idx]
        goal = None if rotations is None else (rot_t[idx], rot_w[idx], move)
        work, acc = _passes(rig, p, targets[idx], weights[idx], *((r,) + goal[:2] if goal else ()))
        if deferred:  # as the kernel: a constraint-free rig recovers its rotations once, after the last iteration
            p = np.where((acc > 0)[..., None], work, p)
            last_work[idx], last_acc[idx] = work, acc
        else:
            _recover(rig, root_pos[idx], q_root[idx], r, p, w, work, acc, weights[idx], orient[idx], goal)
        rot[idx], pos[idx], wrot[idx] = r, p, w
        new_err = _error(rig, p, targets[idx], weights[idx])
        new_turn = _turn(rig, w, weights[idx], orient[idx])
        new_rturn = np.zeros(len(idx)) if goal is None else rt.rotation_error(rig, w, goal[0], goal[1])
        iters[idx] += 1
        flat_now = ((new_err > err[idx] * (1 - FLAT)) & (new_turn >= turn[idx] * (1 - FLAT))
                    & (new_rturn >= rturn[idx] * (1 - FLAT)))
        flat[idx] = np.where(flat_now, flat[idx] + 1, 0)
        err[idx] = new_err
        turn[idx] = new_turn
        rturn[idx] = new_rturn
        stalled[idx] = flat[idx] >= STALL_AFTER
    if deferred and np.any(iters > 0):
        idx = np.nonzero(iters > 0)[0]
        r, p, w = rot[idx], pos[idx], wrot[idx]
        _recover(rig, root_pos[idx], q_root[idx], r, p, w, last_work[idx], last_acc[idx], weights[idx], orient[idx])
        rot[idx], pos[idx], wrot[idx] = r, p, w
        err[idx] = _error(rig, p, targets[idx], weights[idx])
    return rot, pos, err, iters, stalled
