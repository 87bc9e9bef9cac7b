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

from crowd_ik.kernels.quat import (
    constrain_rotation, qconj, qmul, qnormalize, qrot, swing, twist_angle, vec3, vec4, wrap_angle, yaw_quat,
)
from crowd_ik.kernels.rotation_goals import turn_error

ndarray = ti.types.ndarray

# rounds of swing averaging at a joint with several effectors below it
MULTI_ROUNDS = 4


@ti.func
def joint_active(i, j, below: ti.template(), weights: ti.template()):
    """1 if an effector with positive weight lies in joint j's subtree (j included), else 0."""
    active = 0
    for e in range(below.shape[1]):
        if below[j, e] != 0 and weights[i, e] > 0.0:
            active = 1
    return active


@ti.func
def relative_error(i, eff_joint: ti.template(), rel_t: ti.template(), weights: ti.template(),
                   world_pos: ti.template()):
    """Max over effectors with positive weight of |effector - target|, world_pos relative to the root."""
    err = 0.0
    for e in range(eff_joint.shape[0]):
        if weights[i, e] > 0.0:
            err = ti.max(err, (world_pos[i, eff_joint[e]] - rel_t[i, e]).norm())
    return err


@ti.func
def turn_about(ax, angle, q):
    """R(ax, angle) q."""
    h = 0.5 * angle
    sh = ti.sin(h)
    return qnormalize(qmul(vec4(ax.x * sh, ax.y * sh, ax.z * sh, ti.cos(h)), q))


@ti.func
def fk_after(i, j0, parent: ti.template(), offset: ti.template(), local_rot: ti.template(),
             world_pos: ti.template(), world_rot: ti.template()):
    """Recompute world transforms of joints j0+1 .. J-1 from their (already current) parents."""
    for j in range(j0 + 1, parent.shape[0]):
        p = parent[j]
        world_pos[i, j] = world_pos[i, p] + qrot(world_rot[i, p], offset[j])
        world_rot[i, j] = qmul(world_rot[i, p], local_rot[i, j])


@ti.func
def hinge_step(i, j, q, ax, inv_base, pos_j, below: ti.template(), eff_joint: ti.template(),
               rel_t: ti.template(), weights: ti.template(), eff_pos: ti.template()):
    """q turned about the hinge axis ax (parent frame) by the best angle for the effectors below j."""
    s_cross = 0.0
    s_dot = 0.0
    for e in range(eff_joint.shape[0]):
        w = weights[i, e]
        if below[j, e] != 0 and w > 0.0:
            u = qrot(inv_base, eff_pos[i, e] - pos_j)
            v = qrot(inv_base, rel_t[i, e] - pos_j)
            u = u - u.dot(ax) * ax
            v = v - v.dot(ax) * ax
            s_cross += w * ax.dot(ti.math.cross(u, v))
            s_dot += w * u.dot(v)
    out = q
    if s_cross != 0.0 or s_dot != 0.0:
        out = turn_about(ax, ti.atan2(s_cross, s_dot), q)
    return out


@ti.func
def hinge_reach_step(i, q, ax, lo_j, hi_j, inv_base, pos_j, pos_p, e, eff_joint: ti.template(),
                     rel_t: ti.template(), eff_pos: ti.template()):
    """q turned about the hinge axis so that |effector - parent| = |target - parent| (clamped to what it spans).

    Of the two bends (+-phi) it takes the one inside the hinge's limits, else the one nearer to them,
    and on a tie the smaller turn.
    """
    r = qrot(inv_base, pos_j - pos_p)
    u = qrot(inv_base, eff_pos[i, e] - pos_j)
    d_t = (rel_t[i, e] - pos_p).norm()
    r_par = r.dot(ax)
    u_par = u.dot(ax)
    r_perp = r - r_par * ax
    u_perp = u - u_par * ax
    m = 2.0 * r_perp.norm() * u_perp.norm()
    out = q
    if m > 1e-12:
        # |r + R u|^2 = |r|^2 + |u|^2 + 2 r_par u_par + m cos(phi), phi = angle from r_perp to R u_perp about ax
        c = ti.math.clamp((d_t * d_t - r.dot(r) - u.dot(u) - 2.0 * r_par * u_par) / m, -1.0, 1.0)
        phi = ti.acos(c)
        phi0 = ti.atan2(ax.dot(ti.math.cross(r_perp, u_perp)), r_perp.dot(u_perp))
        theta0 = twist_angle(q, ax)
        d1 = wrap_angle(phi - phi0)
        d2 = wrap_angle(-phi - phi0)
        t1 = wrap_angle(theta0 + d1)
        t2 = wrap_angle(theta0 + d2)
        v1 = ti.max(lo_j - t1, 0.0) + ti.max(t1 - hi_j, 0.0)
        v2 = ti.max(lo_j - t2, 0.0) + ti.max(t2 - hi_j, 0.0)
        dlt = d1
        if v2 < v1 or (v2 == v1 and ti.abs(d2) < ti.abs(d1)):
            dlt = d2
        out = turn_about(ax, dlt, q)
    return out


@ti.func
def swing_step(i, j, q, inv_base, pos_j, below: ti.template(), eff_joint: ti.template(), rel_t: ti.template(),
               weights: ti.template(), eff_pos: ti.template()):
    """q preceded by the (averaged) swing turning the effectors below j toward their targets (parent frame)."""
    n_eff = 0
    for e in range(eff_joint.shape[0]):
        if below[j, e] != 0 and weights[i, e] > 0.0:
            if (eff_pos[i, e] - pos_j).norm_sqr() > 1e-18:
                n_eff += 1
    delta = vec4(0.0, 0.0, 0.0, 1.0)
    rounds = 1
    if n_eff > 1:
        rounds = MULTI_ROUNDS
    if n_eff > 0:
        for _ in range(rounds):
            acc = vec4(0.0)
            for e in range(eff_joint.shape[0]):
                w = weights[i, e]
                if below[j, e] != 0 and w > 0.0:
                    u = qrot(delta, qrot(inv_base, eff_pos[i, e] - pos_j))
                    v = qrot(inv_base, rel_t[i, e] - pos_j)
                    nu = u.norm()
                    nv = v.norm()
                    if nu > 1e-9 and nv > 1e-9:
                        sw = swing(u / nu, v / nv)
                        if sw.w < 0.0:
                            sw = -sw
                        acc += (w * nu * nv) * sw
            if acc.norm_sqr() > 0.0:
                delta = qnormalize(qmul(qnormalize(acc), delta))
    return qnormalize(qmul(delta, q))


@ti.func
def straighten_step(k, q, ax, u, v):
    """q turned so that the child bone u lines up with the parent bone v (both in the parent frame)."""
    out = q
    if k == 1:
        u_p = u - u.dot(ax) * ax
        v_p = v - v.dot(ax) * ax
        s_cross = ax.dot(ti.math.cross(u_p, v_p))
        s_dot = u_p.dot(v_p)
        if s_cross != 0.0 or s_dot != 0.0:
            out = turn_about(ax, ti.atan2(s_cross, s_dot), q)
    elif u.norm_sqr() > 0.0 and v.norm_sqr() > 0.0:
        out = qnormalize(qmul(swing(u.normalized(), v.normalized()), q))
    return out


@ti.func
def constrain_joint(i, j, q, offset: ti.template(), kind: ti.template(), axes: ti.template(), lo: ti.template(),
                    hi: ti.template(), lim_p: ti.template(), cone: ti.template(), dof_start: ti.template(),
                    child_start: ti.template(), child_list: ti.template(), below: ti.template(),
                    weights: ti.template()):
    """q clamped to joint j's limits; the cone limits the first child bone leading to an active effector."""
    first_bone = vec3(0.0)
    found = 0
    for cc in range(child_start[j], child_start[j + 1]):
        c = child_list[cc]
        if found == 0 and joint_active(i, c, below, weights) != 0:
            first_bone = offset[c].normalized()
            found = 1
    return constrain_rotation(kind[j], axes[j, 0], axes[j, 1], q, lo, hi, lim_p, dof_start[j], cone[j], first_bone)


@ti.func
def ccd_sweep(i, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
              lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
              dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(), eff_joint: ti.template(),
              eff_axis: ti.template(), below: ti.template(), reach: ti.template(), root_yaw: ti.template(),
              local_rot: ti.template(), world_pos: ti.template(), world_rot: ti.template(), rel_t: ti.template(),
              eff_pos: ti.template(), weights: ti.template(), orient: ti.template(), goals: ti.template(),
              goal_t: ti.template(), rot_t: ti.template(), rot_w: ti.template(), eff_move: ti.template()):
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
            if out_of_reach != 0 and serial != 0:
                q = straighten_step(k, q, axes[j, 0], qrot(inv_base, world_pos[i, only_child] - pos_j),
                                    qrot(inv_base, pos_j - world_pos[i, p]))
            elif k == 1 and p >= 0 and n_j == 1 and n_p == 1 and kind[p] == 3:
                s = dof_start[j]
                q = hinge_reach_step(i, q, axes[j, 0], lo[s], hi[s], inv_base, pos_j, world_pos[i, p], single,
                                     eff_joint, goal_t, eff_pos)
            elif k == 1:
                q = hinge_step(i, j, q, axes[j, 0], inv_base, pos_j, below, eff_joint, goal_t, weights, eff_pos)
            else:
                q = swing_step(i, j, q, inv_base, pos_j, below, eff_joint, goal_t, weights, eff_pos)
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
    of what is left (q_target q^-1), and m turns again."""
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
                            local_rot[i, b] = qb
                            world_rot[i, b] = qmul(bb, qb)
                            fk_after(i, b, parent, offset, local_rot, world_pos, world_rot)


@ti.func
def rotation_error(i, eff_joint: ti.template(), rot_t: ti.template(), rot_w: ti.template(), world_rot: ti.template()):
    """Max over effectors with a rotation target (rot_w > 0) of 2 acos |<q, q_target>|, radians."""
    err = 0.0
    for e in range(eff_joint.shape[0]):
        if rot_w[i, e] > 0.0:
            c = ti.abs(world_rot[i, eff_joint[e]].dot(rot_t[i, e]))
            err = ti.max(err, 2.0 * ti.acos(ti.min(c, 1.0)))
    return err


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
    for i in range(root_pos.shape[0]):
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
                          eff_pos, weights, orient, goals, aim_t, rot_t, rot_w, eff_move)
            else:
                ccd_sweep(i, parent, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start, child_list,
                          eff_joint, eff_axis, below, reach, root_yaw, local_rot, world_pos, world_rot, rel_t,
                          eff_pos, weights, orient, goals, rel_t, rot_t, rot_w, eff_move)
            new_err = relative_error(i, eff_joint, rel_t, weights, world_pos)
            new_turn = 0.0
            if ti.static(goals & 1):
                new_turn = turn_error(i, eff_joint, eff_axis, weights, orient, world_rot)
            if ti.static(goals & 2):
                new_turn = ti.max(new_turn, rotation_error(i, eff_joint, rot_t, rot_w, world_rot))
            it += 1
            # stalled: four sweeps in a row that improved neither error by 0.01 %
            if new_err > err * (1.0 - 1e-4) and new_turn >= turn * (1.0 - 1e-4):
                flat += 1
            else:
                flat = 0
            err = new_err
            turn = new_turn
            if flat >= 4:
                stop = 1
        for j in range(parent.shape[0]):
            world_pos[i, j] += root_pos[i]
        error[i] = err
        iterations[i] = it
        stalled[i] = stop
