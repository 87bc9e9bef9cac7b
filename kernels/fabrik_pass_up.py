"""FABRIK's limit clamp with the excess passed up (issue 15): when a sub-base's (a ball joint with several active
children) clamp removes part of the rotation its recovery asked for, its parent (a ball joint with this one child, not the root) takes that part, within its own
limits, and the joint is re-clamped against the turned parent. On the humanoid the chest's small box then lends its
bend to the spine instead of the solve stalling with the chest against its limit.
"""

import taichi as ti

from crowd_ik.kernels.quat import constrain_rotation, qconj, qmul, qrot


@ti.func
def pass_up(i, j, q_want, q, parent: ti.template(), offset: ti.template(), kind: ti.template(), axes: ti.template(),
            lo: ti.template(), hi: ti.template(), lim_p: ti.template(), cone: ti.template(), dof_start: ti.template(),
            child_start: ti.template(), first_bone, local_rot: ti.template(), world_pos: ti.template(),
            world_rot: ti.template()):
    """Sub-base j (a ball joint) asked for q_want and was clamped to q. Returns (j's rotation, its new base rotation, its new
    position); the parent's local_rot and world_rot are updated in place when it takes the excess."""
    p = parent[j]
    out = q
    base_rot = world_rot[i, p]
    pos_j = world_pos[i, j]
    d = qmul(q_want, qconj(q))  # the part the clamp removed, in j's base frame
    if p > 0 and kind[p] == 3 and child_start[p + 1] - child_start[p] == 1 and d.xyz.norm_sqr() > 1e-12:
        q_p = local_rot[i, p]
        q_p2 = constrain_rotation(3, axes[p, 0], axes[p, 1], qmul(q_p, d), lo, hi, lim_p, dof_start[p], cone[p],
                                  offset[j].normalized())
        local_rot[i, p] = q_p2
        base_rot = qmul(world_rot[i, parent[p]], q_p2)
        world_rot[i, p] = base_rot
        pos_j = world_pos[i, p] + qrot(base_rot, offset[j])
        # j's request, re-expressed under the turned parent (the same world rotation), clamped again
        out = constrain_rotation(kind[j], axes[j, 0], axes[j, 1], qmul(qconj(q_p2), qmul(q_p, q_want)), lo, hi,
                                 lim_p, dof_start[j], cone[j], first_bone)
    return out, base_rot, pos_j
