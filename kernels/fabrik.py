"""FABRIK with joint constraints and several effectors (Aristidou & Lasenby 2011), one character per thread.

Each iteration: (1) backward pass from the targets to the root; a sub-base (a joint several effector
chains meet at) goes to the weighted centroid of what its chains propose (paper, section 4);
(2) forward pass from the fixed root with exact bone lengths; (3) in topological order, recover each
joint's rotation from the proposed positions (the minimal swing, so a ball joint keeps its twist;
the best angle about the axis for a hinge), clamp it to the joint's limits, and run FK. The pose is
therefore always FK(rotations): bone lengths are exact and limits hold after every iteration.
"""

import taichi as ti

from crowd_ik.kernels.fabrik_limbs import twist_for_hinge_child, two_bone_swing
from crowd_ik.kernels.fabrik_pass_up import pass_up
from crowd_ik.kernels.fabrik_rotation import extended_toward, turn_onto_targets
from crowd_ik.kernels.quat import (
    align_axis, constrain_rotation, qconj, qmul, qnormalize, qrot, safe_normalize, swing, yaw_quat, vec3, vec4,
)
from crowd_ik.kernels.rotation_goals import rotation_error
from crowd_ik.solvers.settings import (
    FABRIK_FLAT as FLAT, FABRIK_SLOW as SLOW, FABRIK_STALL_AFTER as STALL_AFTER, FABRIK_WINDOW as WINDOW, SWING_ROUNDS,
)

ndarray = ti.types.ndarray


@ti.func
def effector_error(i, eff_joint: ti.template(), targets: ti.template(), weights: ti.template(),
                   world_pos: ti.template()):
    """Max over effectors with positive weight of |effector - target|."""
    err = 0.0
    for e in range(eff_joint.shape[0]):
        if weights[i, e] > 0.0:
            err = ti.max(err, (world_pos[i, eff_joint[e]] - targets[i, e]).norm())
    return err


@ti.func
def orientation_error(i, eff_joint: ti.template(), eff_axis: ti.template(), weights: ti.template(),
                      orient: ti.template(), world_rot: ti.template()):
    """Max over effectors with an orientation target of 1 - cos(angle between its axis and the target)."""
    err = 0.0
    for e in range(eff_joint.shape[0]):
        if weights[i, e] > 0.0 and orient[i, e].norm_sqr() > 0.0:
            err = ti.max(err, 1.0 - qrot(world_rot[i, eff_joint[e]], eff_axis[e]).dot(orient[i, e]))
    return err


@ti.func
def seed_targets(i, eff_joint: ti.template(), targets: ti.template(), weights: ti.template(), work: ti.template(),
                 acc_w: ti.template()):
    """Start of the backward pass: work[i, j] = sum of weighted targets at joint j, acc_w[i, j] their weight."""
    for j in range(work.shape[1]):
        work[i, j] = vec3(0.0)
        acc_w[i, j] = 0.0
    for e in range(eff_joint.shape[0]):
        w = weights[i, e]
        if w > 0.0:
            k = eff_joint[e]
            work[i, k] += w * targets[i, e]
            acc_w[i, k] += w


@ti.func
def backward_joint(i, j, p, length, fallback, world_pos: ti.template(), work: ti.template(), acc_w: ti.template()):
    """Joint j of the backward pass: its proposal is the centroid of what reached it; it proposes its parent p."""
    w = acc_w[i, j]
    if w > 0.0:
        pj = work[i, j] / w
        work[i, j] = pj
        toward = safe_normalize(world_pos[i, p] - pj, fallback)
        work[i, p] += w * (pj + length * toward)
        acc_w[i, p] += w


@ti.func
def forward_joint(i, j, p, length, fallback, work: ti.template(), acc_w: ti.template()):
    """Joint j of the forward pass: an active joint goes to its bone length from its parent p's new place."""
    if acc_w[i, j] > 0.0:
        d = safe_normalize(work[i, j] - work[i, p], fallback)
        work[i, j] = work[i, p] + length * d


@ti.func
def backward_pass(i, parent: ti.template(), offset: ti.template(), kind: ti.template(), eff_joint: ti.template(),
                  targets: ti.template(), weights: ti.template(), local_rot: ti.template(), world_pos: ti.template(),
                  work: ti.template(), acc_w: ti.template(), rot_t: ti.template(), rot_w: ti.template(),
                  use_rot: ti.template()):
    """Targets -> root. Afterwards work[i, j] holds joint j's proposed position, acc_w[i, j] > 0 on active joints.
    With rotation targets (use_rot) a fixed effector joint proposes its parent where the target rotation puts it."""
    J = parent.shape[0]
    seed_targets(i, eff_joint, targets, weights, work, acc_w)
    for jj in range(J - 1):
        j = J - 1 - jj
        length = offset[j].norm()
        if ti.static(use_rot):
            if acc_w[i, j] > 0.0:
                p = parent[j]
                w = acc_w[i, j]
                pj = work[i, j] / w
                toward = safe_normalize(world_pos[i, p] - pj, -offset[j] / length)
                toward = extended_toward(i, j, length, toward, kind, offset, eff_joint, local_rot, rot_t, rot_w)
                work[i, j] = pj
                work[i, p] += w * (pj + length * toward)
                acc_w[i, p] += w
        else:
            backward_joint(i, j, parent[j], length, -offset[j] / length, world_pos, work, acc_w)
    if acc_w[i, 0] > 0.0:
        work[i, 0] = work[i, 0] / acc_w[i, 0]


@ti.func
def forward_pass(i, parent: ti.template(), offset: ti.template(), world_pos: ti.template(), work: ti.template(),
                 acc_w: ti.template()):
    """Root (fixed where it stands) -> leaves, putting each active joint at its bone length from its parent."""
    work[i, 0] = world_pos[i, 0]
    for j in range(1, parent.shape[0]):
        length = offset[j].norm()
        forward_joint(i, j, parent[j], length, offset[j] / length, work, acc_w)


@ti.func
def swing_round(i, q, c0, c1, inv_base, pos_j, offset: ti.template(), child_list: ti.template(),
                work: ti.template(), acc_w: ti.template()):
    """One round of a ball joint's recovery: q turned by the weighted mean of the minimal swings that aim each
    active child c (child_list[c0:c1]) at its proposed position."""
    acc = vec4(0.0)
    for cc in range(c0, c1):
        c = child_list[cc]
        wc = acc_w[i, c]
        if wc > 0.0:
            cur = qrot(q, offset[c]).normalized()
            want = safe_normalize(qrot(inv_base, work[i, c] - pos_j), cur)
            sw = swing(cur, want)
            if sw.w < 0.0:
                sw = -sw
            acc += wc * sw
    return qnormalize(qmul(qnormalize(acc), q))


@ti.func
def recover_and_constrain(i, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
                          lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
                          dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
                          eff_joint: ti.template(), eff_axis: ti.template(), root_pos: ti.template(),
                          root_yaw: ti.template(),
                          local_rot: ti.template(), world_pos: ti.template(), world_rot: ti.template(),
                          weights: ti.template(), orient: ti.template(), work: ti.template(), acc_w: ti.template(),
                          use_orient, rot_t: ti.template(), rot_w: ti.template(), eff_move: ti.template(),
                          use_rot: ti.template()):
    """Rotations from the proposed positions, clamped to the limits, then FK, in one topological sweep."""
    q_root = yaw_quat(root_yaw[i])
    for j in range(parent.shape[0]):
        p = parent[j]
        base_pos = root_pos[i]
        base_rot = q_root
        if p >= 0:
            base_pos = world_pos[i, p]
            base_rot = world_rot[i, p]
        pos_j = base_pos + qrot(base_rot, offset[j])
        world_pos[i, j] = pos_j
        q = local_rot[i, j]
        k = kind[j]
        if k > 0 and acc_w[i, j] > 0.0:
            inv_base = qconj(base_rot)
            c0 = child_start[j]
            c1 = child_start[j + 1]
            first_bone = vec3(0.0)
            n_active = 0
            if k == 1:
                # best hinge angle for all active children: atan2(sum w a.(u x v), sum w u.v), u, v projected
                ax = axes[j, 0]
                s_cross = 0.0
                s_dot = 0.0
                for cc in range(c0, c1):
                    c = child_list[cc]
                    wc = acc_w[i, c]
                    if wc > 0.0:
                        u = qrot(q, offset[c])
                        u = u - u.dot(ax) * ax
                        v = qrot(inv_base, work[i, c] - pos_j)
                        v = v - v.dot(ax) * ax
                        s_cross += wc * ax.dot(ti.math.cross(u, v))
                        s_dot += wc * u.dot(v)
                if s_cross != 0.0 or s_dot != 0.0:
                    h = 0.5 * ti.atan2(s_cross, s_dot)
                    q = qnormalize(qmul(vec4(ax.x * ti.sin(h), ax.y * ti.sin(h), ax.z * ti.sin(h), ti.cos(h)), q))
            else:
                for cc in range(c0, c1):
                    if acc_w[i, child_list[cc]] > 0.0:
                        n_active += 1
                        if n_active == 1:
                            first_bone = offset[child_list[cc]].normalized()
                limb = 0
                if n_active == 1 and k == 3:
                    q, limb = two_bone_swing(i, j, q, inv_base, pos_j, kind, axes, offset, lo, hi, lim_p, cone,
                                             dof_start, child_start, child_list, local_rot, work, acc_w)
                rounds = 1 if n_active <= 1 else SWING_ROUNDS
                for _ in range(rounds):
                    if n_active > 0 and limb == 0:
                        q = swing_round(i, q, c0, c1, inv_base, pos_j, offset, child_list, work, acc_w)
                if n_active == 1 and k == 3 and limb == 0:
                    q = twist_for_hinge_child(i, j, q, inv_base, pos_j, kind, axes, offset, lo, hi, dof_start,
                                              child_start, child_list, work, acc_w)
            # an orientation target on this joint's effector overrides the swing of its local axis
            for e in range(eff_joint.shape[0] if use_orient else 0):
                if eff_joint[e] == j and weights[i, e] > 0.0 and orient[i, e].norm_sqr() > 0.0:
                    q = align_axis(k, axes[j, 0], axes[j, 1], q, eff_axis[e], qrot(inv_base, orient[i, e]))
            if ti.static(use_rot):
                q = turn_onto_targets(i, j, q, inv_base, pos_j, eff_joint, world_pos, world_rot, rot_t, rot_w,
                                      eff_move)
            q_want = q
            q = constrain_rotation(k, axes[j, 0], axes[j, 1], q, lo, hi, lim_p, dof_start[j], cone[j], first_bone)
            # a sub-base (the humanoid's chest); not with rotation targets, whose twin agreement it breaks (issue 15)
            if k == 3 and p > 0 and n_active >= 2 and not ti.static(use_rot):
                q, base_rot, pos_j = pass_up(i, j, q_want, q, parent, offset, kind, axes, lo, hi, lim_p, cone,
                                             dof_start, child_start, first_bone, local_rot, world_pos, world_rot)
                world_pos[i, j] = pos_j
            local_rot[i, j] = q
        world_rot[i, j] = qmul(base_rot, q)


@ti.func
def solve_one(i, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
              lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(),
              dof_start: ti.template(), child_start: ti.template(), child_list: ti.template(),
              eff_joint: ti.template(), eff_axis: ti.template(), root_pos: ti.template(), root_yaw: ti.template(),
              local_rot: ti.template(), world_pos: ti.template(), world_rot: ti.template(), targets: ti.template(),
              weights: ti.template(), orient: ti.template(), work: ti.template(), acc_w: ti.template(), cap,
              tolerance, recover_each_iteration, use_orient, rot_t: ti.template(), rot_w: ti.template(),
              eff_move: ti.template(), rotation_tolerance, use_rot: ti.template(), mode, ref):
    """fabrik_solve for character i, at most `cap` updates; returns (error, updates, stop). With mode 1 the updates
    run in windows of WINDOW: a window that leaves more than SLOW of the error it started with (for the first, of
    `ref`) ends the solve (stop 2), one that does not is followed by the next as a fresh launch would follow it (the
    stall count restarted); stop 1: stalled."""
    err = effector_error(i, eff_joint, targets, weights, world_pos)
    turn = 0.0
    if use_orient:
        turn = orientation_error(i, eff_joint, eff_axis, weights, orient, world_rot)
    rturn = 0.0
    if ti.static(use_rot):
        rturn = rotation_error(i, eff_joint, rot_t, rot_w, world_rot)
    it = 0
    flat = 0
    stop = 0
    done = 0
    window_err = ref  # what the current window's error is judged against (mode 1)
    while done == 0:
        # orientation targets keep it going until they are met to ~1.4 mrad (1 - cos < 1e-6)
        iterate = it < cap and (err > tolerance or turn > 1e-6) and stop == 0
        if ti.static(use_rot):
            iterate = iterate or (it < cap and rturn > rotation_tolerance and stop == 0)
        if iterate:
            backward_pass(i, parent, offset, kind, eff_joint, targets, weights, local_rot, world_pos, work, acc_w,
                          rot_t, rot_w, use_rot)
            forward_pass(i, parent, offset, world_pos, work, acc_w)
            if not recover_each_iteration:
                for j in range(parent.shape[0]):
                    if acc_w[i, j] > 0.0:
                        world_pos[i, j] = work[i, j]
        # one call site (each inlined copy of this sweep costs ~20 s of compile time): every iteration of
        # a constrained rig, or once after the last iteration of a constraint-free one
        if (iterate and recover_each_iteration) or (not iterate and not recover_each_iteration and it > 0):
            recover_and_constrain(i, parent, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start,
                                  child_list, eff_joint, eff_axis, root_pos, root_yaw, local_rot, world_pos,
                                  world_rot, weights, orient, work, acc_w, use_orient, rot_t, rot_w, eff_move,
                                  use_rot)
        if iterate:
            new_err = effector_error(i, eff_joint, targets, weights, world_pos)
            new_turn = 0.0
            if use_orient:
                new_turn = orientation_error(i, eff_joint, eff_axis, weights, orient, world_rot)
            new_rturn = 0.0
            if ti.static(use_rot):
                new_rturn = rotation_error(i, eff_joint, rot_t, rot_w, world_rot)
            it += 1
            # stalled: four updates in a row that improved neither error by one part in a million
            flat_now = new_err > err * (1.0 - FLAT) and new_turn >= turn * (1.0 - FLAT)
            if ti.static(use_rot):
                flat_now = flat_now and new_rturn >= rturn * (1.0 - FLAT)
            if flat_now:
                flat += 1
            else:
                flat = 0
            err = new_err
            turn = new_turn
            rturn = new_rturn
            if flat >= STALL_AFTER:
                stop = 1
            if stop == 0 and mode == 1 and it % WINDOW == 0:  # a window's end (solvers/fabrik_restart.py)
                if err > SLOW * window_err:
                    stop = 2
                else:
                    window_err = err
                    flat = 0
        else:
            if not recover_each_iteration and it > 0:
                err = effector_error(i, eff_joint, targets, weights, world_pos)
            done = 1
    return err, it, stop


@ti.kernel
def fabrik_solve(
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
    root_pos: ndarray(dtype=vec3, ndim=1),
    root_yaw: ndarray(ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    targets: ndarray(dtype=vec3, ndim=2),
    weights: ndarray(ndim=2),
    orient: ndarray(dtype=vec3, ndim=2),
    work: ndarray(dtype=vec3, ndim=2),
    acc_w: ndarray(ndim=2),
    max_iterations: ti.i32,
    tolerance: ti.f32,
    recover_each_iteration: ti.i32,
    use_orient: ti.i32,
    rot_t: ndarray(dtype=vec4, ndim=2),
    rot_w: ndarray(ndim=2),
    eff_move: ndarray(dtype=ti.i32, ndim=2),
    rotation_tolerance: ti.f32,
    use_rot: ti.template(),
    error: ndarray(ndim=1),
    iterations: ndarray(dtype=ti.i32, ndim=1),
    stalled: ndarray(dtype=ti.i32, ndim=1),
):
    """Solve every character (N = root_pos.shape[0]) in place: local_rot, world_pos and world_rot are updated.

    targets (N, E, 3) world metres; weights (N, E); orient (N, E, 3) unit directions or zero (read only
    when use_orient is 1); rot_t (N, E, 4) x y z w rotation targets of the effector joints' world rotations,
    rot_w (N, E) > 0 where one counts, eff_move (E, 2) each effector's moving joint and limb ball joint
    (solvers/ccd.moving_joints), read only when use_rot is 1 (kernels/fabrik_rotation.py). use_rot is a
    compile-time bit: with 0 the kernel compiles to the code it was without rotation targets.
    Outputs: error (N,) final max effector distance, iterations (N,), stalled (N,) 1 if it stopped improving.
    recover_each_iteration 0 is for rigs without constraints (free ball joints, no orientation targets):
    on a chain the recovered rotations reproduce the FABRIK positions exactly, so recovering them once
    after the last iteration gives the same pose for a fraction of the work. (At a sub-base FABRIK moves
    the children independently, and one rotation fits them only on average: there the final pose is the
    fit of the last positions, not of each iteration's, and the error reported is the fitted pose's.)
    recover_each_iteration 2 is 1 for FABRIK's windowed solve (solvers/fabrik_restart.py): on entry iterations[i] is
    character i's budget (at most max_iterations; 0: the character is left alone, its outputs unwritten), stalled[i]
    its mode and error[i] its first window's reference (solve_one); on exit stalled[i] is 2 where a slow window
    ended the solve.
    """
    for i in range(root_pos.shape[0]):
        cap = max_iterations
        mode = 0
        ref = 0.0
        if recover_each_iteration == 2:
            cap = ti.min(max_iterations, iterations[i])
            mode = stalled[i]
            ref = error[i]
        if cap > 0 or recover_each_iteration != 2:
            err, it, stop = solve_one(i, parent, offset, kind, axes, lo, hi, lim_p, cone, dof_start, child_start,
                                      child_list, eff_joint, eff_axis, root_pos, root_yaw, local_rot, world_pos,
                                      world_rot, targets, weights, orient, work, acc_w, cap, tolerance,
                                      recover_each_iteration, use_orient, rot_t, rot_w, eff_move, rotation_tolerance,
                                      use_rot, mode, ref)
            error[i] = err
            iterations[i] = it
            stalled[i] = stop
