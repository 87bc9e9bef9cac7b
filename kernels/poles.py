"""Pole hints after a solve: the limb above an effector swivels about the line from its pivot to the effector
so that its bend joint turns toward the pole (one character per thread, its own kernel: the solvers' common
path does not grow).

For effector e: k = pole_joint[e], the nearest hinge above the effector (the elbow for a hand, the knee for
a foot; on a path without a hinge, the effector joint's parent), and p = pivot[e], the nearest moving joint
above k (the shoulder, the hip). The turn about the unit axis a = (effector - p) / |effector - p| that best
aims k at the pole, atan2(a.(u x v), u.v) with u = k - p and v = pole - p projected off a, leaves the
effector where it is; p is clamped to its limits (cone and box) and the turn is kept only if no effector's
position error grows past max(its solve's error, tolerance) + POLE_SLACK (a clamp or a branch of p, such as
the arms on the chest, can move them). A nearly straight limb (|u off a| < POLE_MIN_BEND |u|) has no bend plane to turn and is left.
Twin: crowd_ik/reference/poles.py.
"""

import taichi as ti

from crowd_ik.kernels.quat import axis_angle, best_angle_about, constrain_rotation, qconj, qmul, qnormalize, qrot, \
    vec3, vec4, yaw_quat
from crowd_ik.solvers.settings import POLE_MIN_BEND, POLE_SLACK

ndarray = ti.types.ndarray


@ti.func
def fk_below(i, e, pivot: ti.template(), below: ti.template(), parent: ti.template(), offset: ti.template(),
             root_pos: ti.template(), root_yaw: ti.template(), local_rot: ti.template(), world_pos: ti.template(),
             world_rot: ti.template()):
    """FK of the joints a turn of pivot[e] moves: the pivot and its descendants (below[e, j] = 1), in
    topological order; the other joints keep their pose."""
    q_root = yaw_quat(root_yaw[i])
    for j in range(pivot[e], parent.shape[0]):
        if below[e, j] != 0:
            p = parent[j]
            base_pos = root_pos[i]
            base_rot = q_root
            if p >= 0:
                base_pos = world_pos[i, p]
                base_rot = world_rot[i, p]
            world_pos[i, j] = base_pos + qrot(base_rot, offset[j])
            world_rot[i, j] = qmul(base_rot, local_rot[i, j])


@ti.func
def errors_of(i, eff_joint: ti.template(), targets: ti.template(), weights: ti.template(), world_pos: ti.template(),
              e_pos: ti.template()):
    """Per effector of character i: its position error (weight > 0; else 0) into e_pos[i, e]."""
    for e in range(eff_joint.shape[0]):
        d = 0.0
        if weights[i, e] > 0.0:
            d = (world_pos[i, eff_joint[e]] - targets[i, e]).norm()
        e_pos[i, e] = d


@ti.kernel
def pole_swivel(
    parent: ndarray(dtype=ti.i32, ndim=1),
    offset: ndarray(dtype=vec3, ndim=1),
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    lo: ndarray(ndim=1),
    hi: ndarray(ndim=1),
    lim_p: ndarray(ndim=2),
    cone: ndarray(ndim=1),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    eff_joint: ndarray(dtype=ti.i32, ndim=1),
    pole_joint: ndarray(dtype=ti.i32, ndim=1),
    pivot: ndarray(dtype=ti.i32, ndim=1),
    below: ndarray(dtype=ti.i32, ndim=2),
    root_pos: ndarray(dtype=vec3, ndim=1),
    root_yaw: ndarray(ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    targets: ndarray(dtype=vec3, ndim=2),
    weights: ndarray(ndim=2),
    poles: ndarray(dtype=vec3, ndim=2),
    pole_on: ndarray(dtype=ti.i32, ndim=2),
    e_pos: ndarray(ndim=2),
    tolerance: ti.f32,
    error: ndarray(ndim=1),
    serial: ti.template(),
):
    """Swivel every character's limbs toward their poles (N = root_pos.shape[0]); the pose stays FK(local_rot).

    pole_joint, pivot (E,) int32 (-1: the effector has no limb to swivel); below (E, J) int32 1 for the pivot and
    the joints under it (the ones its turn moves); poles (N, E, 3) world; pole_on (N, E)
    1 where a pole is given; e_pos (N, E) scratch. error (N,) in: the solve's max position error; out: the final pose's.
    """
    ti.loop_config(serialize=serial)
    for i in range(root_pos.shape[0]):
        errors_of(i, eff_joint, targets, weights, world_pos, e_pos)
        for e in range(eff_joint.shape[0]):
            k = pole_joint[e]
            p = pivot[e]
            if pole_on[i, e] != 0 and k >= 0 and p >= 0:
                pos_p = world_pos[i, p]
                a = world_pos[i, eff_joint[e]] - pos_p
                u = world_pos[i, k] - pos_p
                v = poles[i, e] - pos_p
                if a.norm() > 1e-9:
                    a = a.normalized()
                    u_off = u - u.dot(a) * a
                    v_off = v - v.dot(a) * a
                    if u_off.norm() > POLE_MIN_BEND * u.norm() and v_off.norm() > 1e-9:
                        ang = best_angle_about(a, u, v)
                        if ti.abs(ang) > 1e-6:
                            base = yaw_quat(root_yaw[i])
                            if parent[p] >= 0:
                                base = world_rot[i, parent[p]]
                            old = local_rot[i, p]
                            turned = qnormalize(qmul(qconj(base), qmul(axis_angle(a, ang), qmul(base, old))))
                            local_rot[i, p] = constrain_rotation(kind[p], axes[p, 0], axes[p, 1], turned, lo, hi,
                                                                 lim_p, dof_start[p], cone[p], offset[k].normalized())
                            fk_below(i, e, pivot, below, parent, offset, root_pos, root_yaw, local_rot, world_pos, world_rot)
                            # keep the turn only if no effector's error grew past what the solve left
                            worse = 0
                            for f in range(eff_joint.shape[0]):
                                d = 0.0
                                if weights[i, f] > 0.0:
                                    d = (world_pos[i, eff_joint[f]] - targets[i, f]).norm()
                                if d > ti.max(e_pos[i, f], tolerance) + POLE_SLACK:
                                    worse = 1
                            if worse != 0:
                                local_rot[i, p] = old
                                fk_below(i, e, pivot, below, parent, offset, root_pos, root_yaw, local_rot, world_pos, world_rot)
                            else:
                                errors_of(i, eff_joint, targets, weights, world_pos, e_pos)
        err = 0.0
        for e in range(eff_joint.shape[0]):
            err = ti.max(err, e_pos[i, e])
        error[i] = err
