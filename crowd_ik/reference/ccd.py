"""NumPy twin of kernels/ccd.py: cyclic coordinate descent, vectorised over characters.

Written for clarity, in float64: loops over sweeps, joints and effectors; every character advances
together, and a character that has converged or stalled keeps its pose (masked updates). The
branches mirror the kernel's one for one, so both give the same pose to float32 rounding.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.fk import forward_kinematics, yaw_quat
from crowd_ik.geometry.quat import (
    axis_angle, cone_within_box, euler_xyz_to_quat, joint_angles, joint_quat, qconj, qmul, qrot, quat_to_euler_xyz,
    twist_angle,
    wrap_angle,
)
from crowd_ik.reference.rotation_goals import turn_error
from crowd_ik.rig import Rig
from crowd_ik.solvers.settings import CCD_FLAT, CCD_MULTI_ROUNDS as MULTI_ROUNDS, CCD_STALL_AFTER
LIMB_DAMP = 0.05
LIMB_REACH = 0.98
PASS_UP = 2.0
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


def _normalize_q(q: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(n > 1e-12, q / np.maximum(n, 1e-300), _IDENTITY)


def swing(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 4) minimal rotations taking unit vectors u to v (a half turn about a fixed perpendicular if opposite)."""
    d = _dot(u, v)
    c = np.cross(u, v)
    regular = _normalize_q(np.concatenate([c, (1.0 + d)[..., None]], axis=-1))
    axis = np.cross(u, np.array([1.0, 0.0, 0.0]))
    axis = np.where((_dot(axis, axis) < 1e-8)[..., None], np.cross(u, np.array([0.0, 1.0, 0.0])), axis)
    axis = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-300)
    half_turn = np.concatenate([axis, np.zeros(d.shape + (1,))], axis=-1)
    return np.where((d < -0.999999)[..., None], half_turn, regular)


def constrain_rotation(joint, lo: np.ndarray, hi: np.ndarray, q: np.ndarray, bone: np.ndarray) -> np.ndarray:
    """Twin of quat.constrain_rotation for one joint (lo, hi: its DOF limits) over rotations q (N, 4)."""
    axes = np.array(joint.axes or [(0.0, 0.0, 1.0)] * 2)
    if joint.kind == "hinge":
        return axis_angle(axes[0], np.clip(twist_angle(q, axes[0]), lo[0], hi[0]))
    if joint.kind == "universal":
        return joint_quat(2, axes, np.clip(joint_angles(2, axes, q), lo, hi))
    out = q
    cone = joint.cone or 0.0
    if cone > 0.0:
        has_bone = _dot(bone, bone) > 0.0
        cur = qrot(out, bone)
        ang = np.arccos(np.clip(_dot(cur, bone), -1.0, 1.0))
        axis = np.cross(cur, bone)
        n = np.linalg.norm(axis, axis=-1, keepdims=True)
        axis = np.where(n > 1e-9, axis / np.maximum(n, 1e-300), np.array([0.0, 0.0, 1.0]))
        back = qmul(axis_angle(axis, ang - cone), out)
        out = np.where((has_bone & (ang > cone))[..., None], back, out)
    if np.any(np.isfinite(lo)) or np.any(np.isfinite(hi)):
        c = np.clip(quat_to_euler_xyz(out), lo, hi)
        out = euler_xyz_to_quat(c)
        if cone > 0.0:
            out = np.where(has_bone[..., None], cone_within_box(out, c, lo, hi, cone, bone), out)
    return out


def _rotate_about(ax: np.ndarray, angle: np.ndarray, q: np.ndarray) -> np.ndarray:
    return _normalize_q(qmul(axis_angle(ax, angle), q))


def ccd_solve(rig: Rig, root_pos, root_yaw, rot, targets, weights=None, orient=None, max_iterations: int = 20,
              tolerance: float = 1e-3, rotation_tolerance: float = 1e-2, rotations=None, rotation_weights=None):
    """CCD of N characters of ``rig`` from local rotations ``rot`` (N, J, 4).

    root_pos (N, 3), root_yaw (N,), targets (N, E, 3) world, weights (N, E) (default ones), orient
    (N, E, 3) unit directions or zero. Returns dict(rot, pos, wrot, error, iterations, stalled):
    the final local rotations (N, J, 4), FK positions (N, J, 3) and world rotations (N, J, 4),
    error (N,) max effector distance, iterations (N,) sweeps applied, stalled (N,) bool. With axis targets
    the sweeps go on until their angle is within rotation_tolerance too (kernels/rotation_goals.py).
    rotations (N, E, 4) x y z w full rotation targets of the effector joints' world rotations where
    rotation_weights (N, E) > 0 (default ones; zero rows: none): as kernels/ccd.py (shift_targets,
    turn_to_rotations), the joints above each effector's moving joint aim it at its shifted target, it turns
    onto the rotation, a ball joint serving only that effector swivels for the twist it lacks.
    """
    rot = np.array(rot, np.float64)
    N, J = rot.shape[:2]
    E = rig.n_effectors
    root_pos = np.asarray(root_pos, np.float64).reshape(N, 3)
    root_yaw = np.asarray(root_yaw, np.float64).reshape(N)
    targets = np.asarray(targets, np.float64).reshape(N, E, 3)
    weights = np.ones((N, E)) if weights is None else np.broadcast_to(np.asarray(weights, np.float64), (N, E))
    has_orient = orient is not None and np.any(np.asarray(orient) != 0)
    orient = np.zeros((N, E, 3)) if orient is None else np.asarray(orient, np.float64).reshape(N, E, 3)
    eff_joint = np.array([e.joint for e in rig.effectors])
    eff_axis = np.array([e.axis or (0.0, 0.0, 0.0) for e in rig.effectors], np.float64)
    below = np.zeros((J, E), bool)
    for e, eff in enumerate(rig.effectors):
        below[rig.path_to_root(eff.joint), e] = True
    on = weights > 0.0  # (N, E)
    active = np.einsum("je,ne->nj", below.astype(np.int64), on.astype(np.int64)) > 0  # (N, J)
    lo_all, hi_all = rig.angle_limits()
    q_root = yaw_quat(root_yaw)

    pos, wrot = forward_kinematics(rig, root_pos, root_yaw, rot)
    has_rot = np.zeros((N, E), bool)
    if rotations is not None:
        from crowd_ik.solvers.ccd import limb_lengths, moving_joints

        rot_t = np.asarray(rotations, np.float64).reshape(N, E, 4)
        rw = np.ones((N, E)) if rotation_weights is None else np.broadcast_to(
            np.asarray(rotation_weights, np.float64), (N, E))
        has_rot = (rw > 0) & (np.sum(rot_t * rot_t, -1) > 0)
        move = moving_joints(rig)
        limb_len = limb_lengths(rig, move)

    def error_of(pos):
        d = np.linalg.norm(pos[:, eff_joint] - targets, axis=-1)
        return np.max(np.where(on, d, 0.0), axis=1)

    reach = rig.reach
    n_children = [len(c) for c in rig.children]

    def finish(j, q, base, rot, pos, wrot, live):
        """Clamp q to joint j's limits, store it where `live`, and update FK below j."""
        joint = rig.joints[j]
        s = rig.dof_start[j]
        bone = np.zeros((N, 3))
        found = np.zeros(N, bool)
        for c in rig.children[j]:
            take = active[:, c] & ~found
            direction = np.array(rig.joints[c].offset) / np.linalg.norm(rig.joints[c].offset)
            bone = np.where(take[:, None], direction, bone)
            found |= take
        q = constrain_rotation(joint, lo_all[s : s + joint.dof], hi_all[s : s + joint.dof], q, bone)
        rot[:, j] = np.where(live[:, None], q, rot[:, j])
        wrot[:, j] = qmul(base, rot[:, j])
        for k in range(j + 1, J):
            pk = rig.joints[k].parent
            pos[:, k] = pos[:, pk] + qrot(wrot[:, pk], np.broadcast_to(np.array(rig.joints[k].offset), (N, 3)))
            wrot[:, k] = qmul(wrot[:, pk], rot[:, k])

    def wanted(e, j, base, rot, wrot, live):
        """Local rotation of effector e's moving joint j turning its effector joint's frame onto the target."""
        turn = qmul(qconj(wrot[:, j]), wrot[:, eff_joint[e]])
        q = _normalize_q(qmul(qconj(base), qmul(rot_t[:, e], qconj(turn))))
        scratch = rot.copy(), pos.copy(), wrot.copy()
        finish(j, q, base, *scratch, live)  # only for its clamp: the pose is not changed here
        return scratch[0][:, j]

    def limb_weights(j, pos, goal):
        """(N, E) the effectors' weights at joint j: kernels/ccd_rotation.limb_weights."""
        out = weights.copy()
        for e in range(E):
            b = move[e, 1]
            if b > j and below[j, e]:
                length = np.where(has_rot[:, e], limb_len[e, 1], limb_len[e, 0])
                near = np.linalg.norm(goal[:, e] - pos[:, b], axis=-1) < LIMB_REACH * length
                out[:, e] = np.where(on[:, e] & near, weights[:, e] * LIMB_DAMP, weights[:, e])
        return out

    def sweep(rot, pos, wrot):
        rot, pos, wrot = rot.copy(), pos.copy(), wrot.copy()
        rows = np.arange(N)
        aim = np.broadcast_to(eff_joint, (N, E)).copy()  # the joint whose position each effector's term moves
        goal = targets.copy()
        for e in range(E):
            m = move[e, 0] if rotations is not None else -1
            if m < 0 or m == eff_joint[e] or not has_rot[:, e].any():
                continue
            p = rig.joints[m].parent
            base = q_root if p < 0 else wrot[:, p]
            q = wanted(e, m, base, rot, wrot, has_rot[:, e])
            v = qrot(qconj(wrot[:, m]), pos[:, eff_joint[e]] - pos[:, m])
            shifted = targets[:, e] - qrot(qmul(base, q), v)
            goal[:, e] = np.where(has_rot[:, e, None], shifted, goal[:, e])
            aim[:, e] = np.where(has_rot[:, e], m, aim[:, e])
        pos0 = pos.copy()  # the kernel's world_pos during the sweep (FK runs at its end)
        for j in reversed(range(J)):
            joint = rig.joints[j]
            if joint.dof == 0 or not active[:, j].any():
                continue
            p = joint.parent
            base = q_root if p < 0 else wrot[:, p]
            inv_base = qconj(base)
            pos_j = pos[:, j]
            q = rot[:, j]
            axes = np.array(joint.axes or [(0.0, 0.0, 1.0)] * 2)
            ax = axes[0]
            mine = on & below[j]  # (N, E) effectors this joint serves
            aim_w = weights if rotations is None else limb_weights(j, pos0, goal)
            far = np.linalg.norm(goal - pos[:, :1], axis=-1) > reach  # (N, E) out of the whole chain's reach
            out_of_reach = np.all(far | ~mine, axis=1)
            kids = [c for c in rig.children[j]]
            n_kids = np.sum([active[:, c] for c in kids], axis=0) if kids else np.zeros(N, int)
            only_child = np.zeros(N, int)
            for c in kids:
                only_child = np.where(active[:, c], c, only_child)
            serial = (p >= 0) and n_children[max(p, 0)] == 1
            straighten = out_of_reach & (n_kids == 1) & serial

            # plain CCD step
            if joint.kind == "hinge":
                s_cross = np.zeros(N)
                s_dot = np.zeros(N)
                for e in range(E):
                    u = qrot(inv_base, pos[rows, aim[:, e]] - pos_j)
                    v = qrot(inv_base, goal[:, e] - pos_j)
                    u = u - _dot(u, ax)[:, None] * ax
                    v = v - _dot(v, ax)[:, None] * ax
                    w = np.where(mine[:, e], aim_w[:, e], 0.0)
                    s_cross += w * _dot(ax, np.cross(u, v))
                    s_dot += w * _dot(u, v)
                turned = _rotate_about(ax, np.arctan2(s_cross, s_dot), q)
                q_new = np.where(((s_cross != 0.0) | (s_dot != 0.0))[:, None], turned, q)
                if p >= 0 and rig.joints[p].kind == "ball":
                    use = (mine.sum(1) == 1) & ((on & below[p]).sum(1) == 1)
                    e_one = E - 1 - np.argmax(mine[:, ::-1], axis=1)  # the (last) effector served
                    s = rig.dof_start[j]
                    reached = _hinge_reach(q, ax, lo_all[s], hi_all[s], qrot(inv_base, pos_j - pos[:, p]),
                                           qrot(inv_base, pos[rows, aim[rows, e_one]] - pos_j),
                                           np.linalg.norm(goal[rows, e_one] - pos[:, p], axis=-1))
                    q_new = np.where(use[:, None], reached, q_new)
            else:
                lever = np.linalg.norm(pos[rows[:, None], aim] - pos_j[:, None], axis=-1)  # (N, E)
                n_eff = np.sum(mine & (lever**2 > 1e-18), axis=1)
                delta = np.tile(_IDENTITY, (N, 1))
                for r in range(MULTI_ROUNDS):
                    acc = np.zeros((N, 4))
                    for e in range(E):
                        u = qrot(delta, qrot(inv_base, pos[rows, aim[:, e]] - pos_j))
                        v = qrot(inv_base, goal[:, e] - pos_j)
                        nu = np.linalg.norm(u, axis=-1)
                        nv = np.linalg.norm(v, axis=-1)
                        ok = mine[:, e] & (nu > 1e-9) & (nv > 1e-9)
                        sw = swing(u / np.maximum(nu, 1e-300)[:, None], v / np.maximum(nv, 1e-300)[:, None])
                        sw = np.where((sw[:, 3] < 0.0)[:, None], -sw, sw)
                        acc += np.where(ok, aim_w[:, e] * nu * nv, 0.0)[:, None] * sw
                    step = (n_eff > 0) & (r < np.where(n_eff > 1, MULTI_ROUNDS, 1)) & (_dot(acc, acc) > 0.0)
                    delta = np.where(step[:, None], _normalize_q(qmul(_normalize_q(acc), delta)), delta)
                q_new = _normalize_q(qmul(delta, q))
            if straighten.any():
                q_new = np.where(straighten[:, None],
                                 _straighten(joint.kind, q, ax, qrot(inv_base, pos[rows, only_child] - pos_j),
                                             qrot(inv_base, pos_j - pos[:, p])), q_new)
            finish(j, q_new, base, rot, pos, wrot, active[:, j])
        # orientation targets, parents first
        for j in range(J):
            joint = rig.joints[j]
            if joint.dof == 0:
                continue
            for e in range(E):
                if eff_joint[e] != j:
                    continue
                has = on[:, e] & (_dot(orient[:, e], orient[:, e]) > 0.0)
                if not has.any():
                    continue
                p = joint.parent
                base = q_root if p < 0 else wrot[:, p]
                q = rot[:, j]
                cur = qrot(q, np.broadcast_to(eff_axis[e], (N, 3)))
                want = qrot(qconj(base), orient[:, e])
                finish(j, _normalize_q(qmul(swing(cur, want), q)), base, rot, pos, wrot, has)
        # full rotation targets, parents first: the moving joint turns, the ball joint above swivels for the twist
        for j in range(J if rotations is not None else 0):
            for e in range(E):
                if move[e, 0] != j or not has_rot[:, e].any():
                    continue
                live = has_rot[:, e]
                for rnd in range(2):
                    p = rig.joints[j].parent
                    base = q_root if p < 0 else wrot[:, p]
                    finish(j, wanted(e, j, base, rot, wrot, live), base, rot, pos, wrot, live)
                    b = move[e, 1]
                    if rnd == 0 and b >= 0:
                        a = pos[:, j] - pos[:, b]
                        na = np.linalg.norm(a, axis=-1, keepdims=True)
                        ok = live & (na[:, 0] ** 2 > 1e-12)
                        a = a / np.maximum(na, 1e-300)
                        left = qmul(rot_t[:, e], qconj(wrot[:, eff_joint[e]]))
                        ang = 2.0 * np.arctan2(_dot(left[:, :3], a), left[:, 3])
                        ang = np.arctan2(np.sin(ang), np.cos(ang))
                        pb = rig.joints[b].parent
                        bb = q_root if pb < 0 else wrot[:, pb]
                        half = 0.5 * ang
                        turn = np.concatenate([a * np.sin(half)[:, None], np.cos(half)[:, None]], axis=-1)
                        qb = qmul(qconj(bb), _normalize_q(qmul(turn, wrot[:, b])))
                        old_b = wrot[:, b].copy()
                        finish(b, qb, bb, rot, pos, wrot, ok)
                        pp = rig.joints[b].parent
                        if pp >= 0 and rig.joints[pp].kind == "ball":
                            did = qmul(wrot[:, b], qconj(old_b))
                            got = 2.0 * np.arctan2(_dot(did[:, :3], a), did[:, 3])
                            short = ang - np.arctan2(np.sin(got), np.cos(got))
                            half = 0.5 * PASS_UP * short
                            turn = np.concatenate([a * np.sin(half)[:, None], np.cos(half)[:, None]], axis=-1)
                            ppp = rig.joints[pp].parent
                            pbase = q_root if ppp < 0 else wrot[:, ppp]
                            finish(pp, qmul(qconj(pbase), _normalize_q(qmul(turn, wrot[:, pp]))), pbase, rot, pos,
                                   wrot, ok & (np.abs(short) > 1e-6))
        return rot, pos, wrot

    def turn_of(wrot):
        out = turn_error(rig, wrot, weights, orient) if has_orient else np.zeros(N)
        if rotations is not None:
            dot = np.abs(np.sum(wrot[:, eff_joint] * rot_t, -1))
            ang = 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))
            out = np.maximum(out, np.max(np.where(has_rot, ang, 0.0), axis=1))
        return out

    err = error_of(pos)
    turn = turn_of(wrot)
    iters = np.zeros(N, np.int32)
    flat = np.zeros(N, np.int32)
    stalled = np.zeros(N, bool)
    for _ in range(max_iterations):
        running = ((err > tolerance) | (turn > rotation_tolerance)) & ~stalled
        if not running.any():
            break
        new_rot, new_pos, new_wrot = sweep(rot, pos, wrot)
        rot = np.where(running[:, None, None], new_rot, rot)
        pos = np.where(running[:, None, None], new_pos, pos)
        wrot = np.where(running[:, None, None], new_wrot, wrot)
        new_err = error_of(pos)
        new_turn = turn_of(wrot)
        iters += running
        # stalled: four sweeps in a row that improved neither error by 0.01 %
        flat = np.where(running, np.where((new_err > err * (1.0 - CCD_FLAT)) & (new_turn >= turn * (1.0 - CCD_FLAT)),
                                          flat + 1, 0), flat)
        err = np.where(running, new_err, err)
        turn = np.where(running, new_turn, turn)
        stalled |= running & (flat >= CCD_STALL_AFTER)
    return dict(rot=rot, pos=pos, wrot=wrot, error=err, iterations=iters, stalled=stalled)


def _straighten(kind: str, q, ax, u, v):
    """Twin of ccd.straighten_step: turn q so that the child bone u lines up with the parent bone v."""
    if kind == "hinge":
        u_p = u - _dot(u, ax)[:, None] * ax
        v_p = v - _dot(v, ax)[:, None] * ax
        s_cross = _dot(ax, np.cross(u_p, v_p))
        s_dot = _dot(u_p, v_p)
        turned = _rotate_about(ax, np.arctan2(s_cross, s_dot), q)
        return np.where(((s_cross != 0.0) | (s_dot != 0.0))[:, None], turned, q)
    nu = np.linalg.norm(u, axis=-1, keepdims=True)
    nv = np.linalg.norm(v, axis=-1, keepdims=True)
    sw = swing(u / np.maximum(nu, 1e-300), v / np.maximum(nv, 1e-300))
    return np.where(((nu > 0) & (nv > 0)), _normalize_q(qmul(sw, q)), q)


def _hinge_reach(q, ax, lo, hi, r, u, d_t):
    """Twin of ccd.hinge_reach_step: turn q about ax so that |r + R u| = d_t, picking the in-limit bend."""
    r_par = _dot(r, ax)
    u_par = _dot(u, ax)
    r_perp = r - r_par[:, None] * ax
    u_perp = u - u_par[:, None] * ax
    m = 2.0 * np.linalg.norm(r_perp, axis=-1) * np.linalg.norm(u_perp, axis=-1)
    c = np.clip((d_t**2 - _dot(r, r) - _dot(u, u) - 2.0 * r_par * u_par) / np.maximum(m, 1e-300), -1.0, 1.0)
    phi = np.arccos(c)
    phi0 = np.arctan2(_dot(ax, np.cross(r_perp, u_perp)), _dot(r_perp, u_perp))
    theta0 = twist_angle(q, ax)
    d1 = wrap_angle(phi - phi0)
    d2 = wrap_angle(-phi - phi0)
    t1 = wrap_angle(theta0 + d1)
    t2 = wrap_angle(theta0 + d2)
    v1 = np.maximum(lo - t1, 0.0) + np.maximum(t1 - hi, 0.0)
    v2 = np.maximum(lo - t2, 0.0) + np.maximum(t2 - hi, 0.0)
    dlt = np.where((v2 < v1) | ((v2 == v1) & (np.abs(d2) < np.abs(d1))), d2, d1)
    return np.where((m > 1e-12)[:, None], _rotate_about(ax, dlt, q), q)
