"""CCD with full rotation targets: where an effector's moving joint must stand (the shifted target), the weights the
joints above a limb give its effector (limb_weights), and the turn onto the rotation after each sweep, with the
swivel of the limb's ball joint and its parent's share of what that joint's limits keep (pass_up_swivel)."""

import taichi as ti

from crowd_ik.kernels.ccd_steps import constrain_joint, fk_after, turn_about
from crowd_ik.kernels.quat import qconj, qmul, qnormalize, qrot, twist_angle

ndarray = ti.types.ndarray

# with rotation targets, a limb's term at the joints above its own ball joint is scaled by LIMB_DAMP while its
# aimed joint lies within LIMB_REACH of the limb's length from that ball joint (limb_weights)
LIMB_DAMP = 0.05
LIMB_REACH = 0.98
# gain of the parent's turn for the twist a swivel joint's limits keep (pass_up_swivel)
PASS_UP = 2.0


@ti.func
def wanted_rotation(i, e, j, base_rot, offset: ti.template(), kind: ti.template(), axes: ti.template(),
                    lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
                    dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
                    eff_joint: ti.template(), below: ti.template(), world_rot: ti.template(), weights: ti.template(),
                    rot_t: ti.template()):
    """Local rotation of effector e's moving joint j (parent's world rotation base_rot) that turns the effector
    joint's world rotation onto rot_t[i, e], clamped to j's limits. Between j and the effector joint all joints
    are fixed, so their turn L = world_rot[j]^-1 world_rot[eff_joint[e]] is a constant of the rig's pose."""
    turn = qmul(qconj(world_rot[i, j]), world_rot[i, eff_joint[e]])
    q = qnormalize(qmul(qconj(base_rot), qmul(rot_t[i, e], qconj(turn))))
    return constrain_joint(i, j, q, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                           below, weights)


@ti.func
def shift_targets(i, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
                  lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
                  dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
                  eff_joint: ti.template(), below: ti.template(), q_root, local_rot: ti.template(),
                  world_pos: ti.template(), world_rot: ti.template(), rel_t: ti.template(), goal_t: ti.template(),
                  eff_pos: ti.template(), weights: ti.template(), rot_t: ti.template(), rot_w: ti.template(),
                  eff_move: ti.template()):
    """Where the joints above aim (goals 2): an effector with a rotation target is reached by its moving joint m
    (eff_move[e], the nearest joint with DOFs at or above it) standing at t - R_m v, R_m the world rotation m
    takes for the target (clamped to its limits) and v the fixed offset from m to the effector in m's frame;
    the joints above aim m's position at that point (a joint at m itself then has no lever for it), and
    turn_to_rotations turns m afterwards. The others aim at rel_t as before."""
    for e in range(eff_joint.shape[0]):
        goal_t[i, e] = rel_t[i, e]
        if rot_w[i, e] > 0.0:
            m = eff_move[e, 0]
            k = eff_joint[e]
            if m >= 0 and m != k:
                base_rot = q_root
                if parent[m] >= 0:
                    base_rot = world_rot[i, parent[m]]
                q = wanted_rotation(i, e, m, base_rot, offset, kind, axes, lo, hi, lim_p, cone, dof_start,
                                    child_start, child_list, eff_joint, below, world_rot, weights, rot_t)
                v = qrot(qconj(world_rot[i, m]), world_pos[i, k] - world_pos[i, m])
                goal_t[i, e] = rel_t[i, e] - qrot(qmul(base_rot, q), v)
                eff_pos[i, e] = world_pos[i, m]


@ti.func
def pass_up_swivel(i, b, a, ang, old_b, q_root, parent: ti.template(), offset: ti.template(), kind: ti.template(),
                   axes: ti.template(), lo: ti.template(), hi: ti.template(), lim_p: ti.template(),
                   cone: ti.template(), dof_start: ti.template(), child_start: ti.template(),
                   child_list: ti.template(), below: ti.template(), local_rot: ti.template(),
                   world_pos: ti.template(), world_rot: ti.template(), weights: ti.template()):
    """The swivel ball joint b was asked to turn ang about the world axis a (from its world rotation old_b) and its
    limits kept part of it: its parent, if a ball joint (the pelvis above a hip, the chest above a shoulder), turns
    PASS_UP times the shortfall about a, clamped, FK below it. The positions this moves are the next sweep's to
    mend; without it a hip at its limit leaves the foot's twist unmet however long CCD runs."""
    pp = parent[b]
    if pp >= 0 and kind[pp] == 3:
        short = ang - twist_angle(qmul(world_rot[i, b], qconj(old_b)), a)
        if ti.abs(short) > 1e-6:
            pbase = q_root
            if parent[pp] >= 0:
                pbase = world_rot[i, parent[pp]]
            qp = qmul(qconj(pbase), turn_about(a, PASS_UP * short, world_rot[i, pp]))
            qp = constrain_joint(i, pp, qp, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start,
                                 child_list, below, weights)
            local_rot[i, pp] = qp
            world_rot[i, pp] = qmul(pbase, qp)
            fk_after(i, pp, parent, offset, local_rot, world_pos, world_rot)


@ti.func
def turn_to_rotations(i, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
                      lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
                      dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
                      eff_joint: ti.template(), below: ti.template(), q_root, local_rot: ti.template(),
                      world_pos: ti.template(), world_rot: ti.template(), weights: ti.template(),
                      rot_t: ti.template(), rot_w: ti.template(), eff_move: ti.template()):
    """After the sweep (goals 2): each effector's moving joint m takes the rotation that meets its rotation target
    (clamped to its limits), parents first; FK below it. Where m cannot turn about every axis (a universal wrist
    or ankle) or its limits stop it, the ball joint b above it that serves only this effector (eff_move[e, 1]: a
    shoulder, a hip) swivels about the line b -> m, which keeps m where it stands, by the twist about that line
    of what is left (q_target q^-1), its parent takes the part b's limits keep (pass_up_swivel), and m turns
    again."""
    for j in range(parent.shape[0]):
        for e in range(eff_joint.shape[0]):
            if eff_move[e, 0] == j and rot_w[i, e] > 0.0:
                for rnd in range(2):
                    base_rot = q_root
                    if parent[j] >= 0:
                        base_rot = world_rot[i, parent[j]]
                    q = wanted_rotation(i, e, j, base_rot, offset, kind, axes, lo, hi, lim_p, cone, dof_start,
                                        child_start, child_list, eff_joint, below, world_rot, weights, rot_t)
                    local_rot[i, j] = q
                    world_rot[i, j] = qmul(base_rot, q)
                    fk_after(i, j, parent, offset, local_rot, world_pos, world_rot)
                    b = eff_move[e, 1]
                    if rnd == 0 and b >= 0:
                        a = world_pos[i, j] - world_pos[i, b]
                        if a.norm_sqr() > 1e-12:
                            a = a.normalized()
                            left = qmul(rot_t[i, e], qconj(world_rot[i, eff_joint[e]]))
                            ang = twist_angle(left, a)
                            bb = q_root
                            if parent[b] >= 0:
                                bb = world_rot[i, parent[b]]
                            qb = qmul(qconj(bb), turn_about(a, ang, world_rot[i, b]))
                            qb = constrain_joint(i, b, qb, offset, kind, axes, lo, hi, lim_p, cone, dof_start,
                                                 child_start, child_list, below, weights)
                            old_b = world_rot[i, b]
                            local_rot[i, b] = qb
                            world_rot[i, b] = qmul(bb, qb)
                            fk_after(i, b, parent, offset, local_rot, world_pos, world_rot)
                            pass_up_swivel(i, b, a, ang, old_b, q_root, parent, offset, kind, axes, lo, hi, lim_p,
                                           cone, dof_start, child_start, child_list, below, local_rot, world_pos,
                                           world_rot, weights)


@ti.func
def limb_weights(i, j, eff_joint: ti.template(), eff_move: ti.template(), limb_len: ti.template(),
                 below: ti.template(), weights: ti.template(), rot_w: ti.template(), world_pos: ti.template(),
                 goal_t: ti.template(), aim_w: ti.template()):
    """aim_w[i, e]: the weight effector e's term gets at joint j (goals 4). An effector with a limb of its own below j
    (the ball joint b = eff_move[e, 1] lies under j: a hand under the chest, a foot under the pelvis) whose aimed joint
    (the moving joint with a rotation target, else the effector joint) lies within LIMB_REACH of the limb's bone path
    from b (limb_len[e, 1], else limb_len[e, 0]) counts LIMB_DAMP of its weight there: the limb reaches it from where
    b stands, so the shared joints serve the effectors that have no limb (the head, whose neck is taken by its
    rotation target) instead of a compromise that moves everything a little per sweep."""
    for e in range(eff_joint.shape[0]):
        w = weights[i, e]
        b = eff_move[e, 1]
        if w > 0.0 and below[j, e] != 0 and b > j:
            length = limb_len[e, 0]
            if rot_w[i, e] > 0.0:
                length = limb_len[e, 1]
            if (goal_t[i, e] - world_pos[i, b]).norm() < LIMB_REACH * length:
                w *= LIMB_DAMP
        aim_w[i, e] = w
