"""FABRIK with full rotation targets (issue 15): the "extended target" steps kernels/fabrik.py takes when a request
has rotations. Twin: crowd_ik/reference/fabrik_rotation.py.

An effector e with a rotation target R_t (rot_w[i, e] > 0) fixes more than its joint's position:
- backward pass: a fixed effector joint (a hand, the head) proposes its parent not along the line toward the
  parent's current place but where the target rotation puts it, t - R_t F^-1 offset (F the fixed joint's own
  local rotation), so the last bone points the way the target rotation says;
- recovery: the effector's moving joint m (eff_move[e, 0], the nearest joint with DOFs at or above it) takes the
  local rotation that turns the effector's frame onto R_t, before its limits clamp it;
- a ball joint b serving only that limb (eff_move[e, 1], a shoulder or a hip) swivels about the line b -> m by
  the twist about that line of what m's clamp left over in the last pose (a universal wrist or ankle has no
  twist of its own); the swivel keeps m where it stands.
"""

import taichi as ti

from crowd_ik.kernels.quat import axis_angle, qconj, qmul, qnormalize, qrot, twist_angle


@ti.func
def extended_toward(i, j, length, toward, kind: ti.template(), offset: ti.template(), eff_joint: ti.template(),
                    local_rot: ti.template(), rot_t: ti.template(), rot_w: ti.template()):
    """The unit direction from fixed effector joint j's proposal to its parent's: -R_p offset[j] / length with
    R_p = R_t local_rot[j]^-1 the parent's world rotation the target implies; `toward` where j has none."""
    out = toward
    if kind[j] == 0:
        for e in range(eff_joint.shape[0]):
            if eff_joint[e] == j and rot_w[i, e] > 0.0:
                out = -qrot(qmul(rot_t[i, e], qconj(local_rot[i, j])), offset[j]) / length
    return out


@ti.func
def turn_onto_targets(i, j, q, inv_base, pos_j, eff_joint: ti.template(), world_pos: ti.template(),
                      world_rot: ti.template(), rot_t: ti.template(), rot_w: ti.template(),
                      eff_move: ti.template()):
    """Joint j's local rotation q (parent's inverse world rotation inv_base) before its clamp: turned onto the
    rotation targets of the effectors it moves (eff_move[e, 0] == j) and swivelled for those it serves as the
    limb's ball joint (eff_move[e, 1] == j). world_pos and world_rot below j still hold the last pose."""
    out = q
    for e in range(eff_joint.shape[0]):
        if rot_w[i, e] > 0.0:
            k = eff_joint[e]
            if eff_move[e, 0] == j:
                # between j and the effector joint all joints are fixed: their turn is a constant of the pose
                turn = qmul(qconj(world_rot[i, j]), world_rot[i, k])
                out = qnormalize(qmul(inv_base, qmul(rot_t[i, e], qconj(turn))))
            elif eff_move[e, 1] == j:
                m = eff_move[e, 0]
                a = world_pos[i, m] - pos_j
                if a.norm_sqr() > 1e-12:
                    a = a.normalized()
                    ang = twist_angle(qmul(rot_t[i, e], qconj(world_rot[i, k])), a)
                    out = qnormalize(qmul(axis_angle(qrot(inv_base, a), ang), out))
    return out
