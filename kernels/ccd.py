"""Cyclic coordinate descent (Wang & Chen 1991; Kenwright 2012) with joint limits and several effectors.

One character per thread. Each iteration (a "sweep") visits the joints from the deepest to the
root (reverse topological order), skipping joints with no active effector below them. At each joint
it finds the rotation that turns the effectors below it toward their targets, about the joint:

- hinge: the exact best angle about its axis for all effectors below,
  atan2(sum w a.(u x v), sum w u.v) with u, v the joint->effector and joint->target vectors
  projected off the axis (this minimises sum w |R u - v|^2);
- ball / universal: the swing taking u to v for one effector; for several (a humanoid's pelvis,
  spine, chest) a few rounds of the weighted average of their swings, each effector weighted by
  w |u| |v| (its lever: a far effector moves more per radian).

Two rules replace that step where plain CCD is known to lock up:

- reach step: a hinge below a ball joint that serves only its one effector (elbow under shoulder,
  knee under hip) sets the bend that makes |effector - ball| = |target - ball| (law of cosines);
  the ball joint then aims. Plain CCD cannot bend a straight limb whose target lies on its line.
- straighten step: when every effector below a joint is out of the whole chain's reach (farther
  from the root joint than its bone path), a joint inside a serial run (its parent has no other
  child, it has one active child) lines its child bone up with its parent bone. Deepest first, one
  sweep leaves the run straight and the joint above it aims it; plain CCD keeps any fold (a fixed
  point of CCD) and unbends slowly.

Each result is clamped to the joint's limits (cone, then box); the effectors below the joint turn
with it, and FK runs once at the end of the sweep, so the pose is always FK(rotations): bone
lengths are exact and limits hold. After the sweep, orientation targets on effector joints swing
those joints' local axes onto the target directions, in topological order (parents first, so a
later turn cannot undo them).
"""

import taichi as ti

from crowd_ik.kernels.ccd_rotation import limb_weights, shift_targets, turn_to_rotations
from crowd_ik.kernels.ccd_steps import (
    constrain_joint, fk_after, hinge_reach_step, hinge_step, joint_active, relative_error, straighten_step,
    swing_step,
)
from crowd_ik.kernels.quat import qconj, qmul, qnormalize, qrot, swing, vec3, vec4, yaw_quat
from crowd_ik.kernels.rotation_goals import rotation_error, turn_error
from crowd_ik.kernels.work_split import skipped, spread_stride
from crowd_ik.solvers.settings import CCD_FLAT as FLAT
from crowd_ik.solvers.settings import CCD_STALL_AFTER as STALL_AFTER

ndarray = ti.types.ndarray



@ti.func
def ccd_sweep(i, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
              lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
              dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(), eff_joint: ti.template(),
              eff_axis: ti.template(), below: ti.template(), reach: ti.template(), root_yaw: ti.template(),
              local_rot: ti.template(), world_pos: ti.template(), world_rot: ti.template(), rel_t: ti.template(),
              eff_pos: ti.template(), weights: ti.template(), orient: ti.template(), goals: ti.template(),
              goal_t: ti.template(), rot_t: ti.template(), rot_w: ti.template(), eff_move: ti.template(),
              limb_len: ti.template(), aim_w: ti.template()):
    """One CCD sweep of character i, deepest joint first, then the orientation pass (goals 1: axis targets;
    goals 2: full rotation targets, see shift_targets and turn_to_rotations).

    world_pos holds positions relative to the character's root here (see ccd_solve); the pose stays
    FK(local_rot). The joints aim at goal_t: rel_t, or with goals 2 the shifted targets shift_targets writes.
    """
    J = parent.shape[0]
    q_root = yaw_quat(root_yaw[i])
    for e in range(eff_joint.shape[0]):
        eff_pos[i, e] = world_pos[i, eff_joint[e]]
    if ti.static(goals & 2):
        shift_targets(i, parent, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                      eff_joint, below, q_root, local_rot, world_pos, world_rot, rel_t, goal_t, eff_pos, weights,
                      rot_t, rot_w, eff_move)
    for jj in range(J):
        j = J - 1 - jj
        k = kind[j]
        if k > 0 and joint_active(i, j, below, weights) != 0:
            p = parent[j]
            base_rot = q_root
            if p >= 0:
                base_rot = world_rot[i, p]
            inv_base = qconj(base_rot)
            pos_j = world_pos[i, j]
            q = local_rot[i, j]
            # effectors served: how many below j, below its parent, and whether all lie out of reach
            n_j = 0
            n_p = 0
            single = -1
            out_of_reach = 1
            for e in range(eff_joint.shape[0]):
                if weights[i, e] > 0.0 and below[j, e] != 0:
                    n_j += 1
                    single = e
                    if (goal_t[i, e] - world_pos[i, 0]).norm() <= reach[e]:
                        out_of_reach = 0
                if p >= 0 and weights[i, e] > 0.0 and below[p, e] != 0:
                    n_p += 1
            only_child = -1
            n_active_children = 0
            for cc in range(child_start[j], child_start[j + 1]):
                if joint_active(i, child_list[cc], below, weights) != 0:
                    only_child = child_list[cc]
                    n_active_children += 1
            serial = 0
            if p >= 0 and n_active_children == 1:
                if child_start[p + 1] - child_start[p] == 1:
                    serial = 1
            if ti.static(goals & 4):  # the limbs' terms damped at the joints above them (limb_weights)
                limb_weights(i, j, eff_joint, eff_move, limb_len, below, weights, rot_w, world_pos, goal_t, aim_w)
            if out_of_reach != 0 and serial != 0:
                q = straighten_step(k, q, axes[j, 0], qrot(inv_base, world_pos[i, only_child] - pos_j),
                                    qrot(inv_base, pos_j - world_pos[i, p]))
            elif k == 1 and p >= 0 and n_j == 1 and n_p == 1 and kind[p] == 3:
                s = dof_start[j]
                q = hinge_reach_step(i, q, axes[j, 0], lo[s], hi[s], inv_base, pos_j, world_pos[i, p], single,
                                     eff_joint, goal_t, eff_pos)
            elif k == 1:
                q = hinge_step(i, j, q, axes[j, 0], inv_base, pos_j, below, eff_joint, goal_t,
                               aim_w if ti.static(goals & 4) else weights, eff_pos)
            else:
                q = swing_step(i, j, q, inv_base, pos_j, below, eff_joint, goal_t,
                               aim_w if ti.static(goals & 4) else weights, eff_pos)
            q = constrain_joint(i, j, q, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                                below, weights)
            # carry the effectors below j along with its turn (world turn = base q_new q_old^-1 base^-1)
            turn = qmul(qmul(base_rot, qmul(q, qconj(local_rot[i, j]))), inv_base)
            for e in range(eff_joint.shape[0]):
                if below[j, e] != 0:
                    eff_pos[i, e] = pos_j + qrot(turn, eff_pos[i, e] - pos_j)
            local_rot[i, j] = q
    # FK once per sweep: a joint's own position and its parent's rotation only change when an
    # ancestor turns, which happens after it in this order, so the sweep never reads a stale one
    world_pos[i, 0] = qrot(q_root, offset[0])
    world_rot[i, 0] = qmul(q_root, local_rot[i, 0])
    fk_after(i, 0, parent, offset, local_rot, world_pos, world_rot)
    # orientation targets: swing each effector joint's local axis onto its target direction
    for j in range(J if ti.static(goals & 1) else 0):
        if kind[j] > 0:
            for e in range(eff_joint.shape[0]):
                if eff_joint[e] == j and weights[i, e] > 0.0 and orient[i, e].norm_sqr() > 0.0:
                    p = parent[j]
                    base_rot = q_root
                    if p >= 0:
                        base_rot = world_rot[i, p]
                    q = local_rot[i, j]
                    cur = qrot(q, eff_axis[e])
                    want = qrot(qconj(base_rot), orient[i, e])
                    q = qnormalize(qmul(swing(cur, want), q))
                    q = constrain_joint(i, j, q, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start,
                                        child_list, below, weights)
                    local_rot[i, j] = q
                    world_rot[i, j] = qmul(base_rot, q)
                    fk_after(i, j, parent, offset, local_rot, world_pos, world_rot)
    if ti.static(goals & 2):
        turn_to_rotations(i, parent, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                          eff_joint, below, q_root, local_rot, world_pos, world_rot, weights, rot_t, rot_w, eff_move)


@ti.kernel
def ccd_solve(
    parent: ndarray(dtype=ti.i32, ndim=1),
    offset: ndarray(dtype=vec3, ndim=1),
    kind: ndarray(dtype=ti.i32, ndim=1),
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
    below: ndarray(dtype=ti.i32, ndim=2),
    reach: ndarray(ndim=1),
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
    eff_move: ndarray(dtype=ti.i32, ndim=2),
    rel_t: ndarray(dtype=vec3, ndim=2),
    aim_t: ndarray(dtype=vec3, ndim=2),
    eff_pos: ndarray(dtype=vec3, ndim=2),
    limb_len: ndarray(ndim=2),
    aim_w: ndarray(ndim=2),
    max_iterations: ti.i32,
    tolerance: ti.f32,
    rotation_tolerance: ti.f32,
    goals: ti.template(),
    error: ndarray(ndim=1),
    iterations: ndarray(dtype=ti.i32, ndim=1),
    stalled: ndarray(dtype=ti.i32, ndim=1),
):
    """Solve every character (N = root_pos.shape[0]) in place by CCD: local_rot, world_pos, world_rot updated.

    below (J, E) int: 1 where effector e's joint lies in joint j's subtree (j included); reach (E,):
    bone-path length from the root joint to each effector. world_pos and world_rot are recomputed
    from local_rot on entry. targets (N, E, 3) world metres; weights (N, E); orient (N, E, 3) unit
    directions or zero; rel_t, eff_pos (N, E, 3) scratch: targets and effectors relative to the
    roots. Outputs: error (N,) final max effector distance, iterations (N,) sweeps applied, stalled
    (N,) 1 if it stopped improving. goals (compile time) bits: 1 axis targets in orient, and then
    the sweeps go on until their angle (kernels/rotation_goals.turn_error) is <= rotation_tolerance too; 2 full
    rotation targets rot_t (N, E, 4) where rot_w (N, E) > 0: the joints above each effector's moving joint
    eff_move (E,) aim it at its shifted target (aim_t (N, E, 3) scratch; shift_targets), it then turns onto the
    rotation (turn_to_rotations), and the sweeps go on until 2 acos |<q, q_target>| <= rotation_tolerance too.
    With goals 0 none of orient, rot_t, rot_w, eff_move, aim_t is read.
    """
    stride = spread_stride(root_pos.shape[0])
    for slot in range(root_pos.shape[0] * stride):  # (kernels/work_split.py: small crowds on every thread)
        if skipped(slot, stride):
            continue
        i = slot // stride
        # work relative to the root, so a character's result does not depend on where it stands
        q_root = yaw_quat(root_yaw[i])
        world_pos[i, 0] = qrot(q_root, offset[0])
        world_rot[i, 0] = qmul(q_root, local_rot[i, 0])
        fk_after(i, 0, parent, offset, local_rot, world_pos, world_rot)
        for e in range(eff_joint.shape[0]):
            rel_t[i, e] = targets[i, e] - root_pos[i]
        err = relative_error(i, eff_joint, rel_t, weights, world_pos)
        turn = 0.0
        if ti.static(goals & 1):
            turn = turn_error(i, eff_joint, eff_axis, weights, orient, world_rot)
        if ti.static(goals & 2):
            turn = ti.max(turn, rotation_error(i, eff_joint, rot_t, rot_w, world_rot))
        it = 0
        flat = 0
        stop = 0
        while it < max_iterations and (err > tolerance or turn > rotation_tolerance) and stop == 0:
            if ti.static(goals & 2):  # one call site per compile: aim at the shifted targets
                ccd_sweep(i, parent, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                          eff_joint, eff_axis, below, reach, root_yaw, local_rot, world_pos, world_rot, rel_t,
                          eff_pos, weights, orient, goals, aim_t, rot_t, rot_w, eff_move, limb_len, aim_w)
            else:
                ccd_sweep(i, parent, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                          eff_joint, eff_axis, below, reach, root_yaw, local_rot, world_pos, world_rot, rel_t,
                          eff_pos, weights, orient, goals, rel_t, rot_t, rot_w, eff_move, limb_len, aim_w)
            new_err = relative_error(i, eff_joint, rel_t, weights, world_pos)
            new_turn = 0.0
            if ti.static(goals & 1):
                new_turn = turn_error(i, eff_joint, eff_axis, weights, orient, world_rot)
            if ti.static(goals & 2):
                new_turn = ti.max(new_turn, rotation_error(i, eff_joint, rot_t, rot_w, world_rot))
            it += 1
            # stalled: four sweeps in a row that improved neither error by 0.01 %
            if new_err > err * (1.0 - FLAT) and new_turn >= turn * (1.0 - FLAT):
                flat += 1
            else:
                flat = 0
            err = new_err
            turn = new_turn
            if flat >= STALL_AFTER:
                stop = 1
        for j in range(parent.shape[0]):
            world_pos[i, j] += root_pos[i]
        error[i] = err
        iterations[i] = it
        stalled[i] = stop
