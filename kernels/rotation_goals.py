"""The orientation errors the solvers iterate on: axis targets (turn_error; CCD, which stopped on positions
alone and reported CONVERGED while an axis target was 33 degrees off, issue 15) and full rotation targets
(rotation_error; FABRIK and CCD). Twin: crowd_ik/reference/rotation_goals.py; the report's own measure is
crowd_ik/solvers/errors.py.
"""

import taichi as ti

from crowd_ik.kernels.quat import qrot


@ti.func
def turn_error(i, eff_joint: ti.template(), eff_axis: ti.template(), weights: ti.template(), orient: ti.template(),
               world_rot: ti.template()):
    """Max over effectors with an axis target (weight > 0, orient != 0) of the angle between its world axis and
    the target, radians."""
    err = 0.0
    for e in range(eff_joint.shape[0]):
        if weights[i, e] > 0.0 and orient[i, e].norm_sqr() > 0.0:
            q = world_rot[i, eff_joint[e]]
            err = ti.max(err, ti.acos(ti.math.clamp(qrot(q, eff_axis[e]).dot(orient[i, e]), -1.0, 1.0)))
    return err


@ti.func
def rotation_error(i, eff_joint: ti.template(), rot_t: ti.template(), rot_w: ti.template(), world_rot: ti.template()):
    """Max over effectors with a rotation target (rot_w > 0) of 2 acos |<q, q_target>|, radians."""
    err = 0.0
    for e in range(eff_joint.shape[0]):
        if rot_w[i, e] > 0.0:
            c = ti.abs(world_rot[i, eff_joint[e]].dot(rot_t[i, e]))
            err = ti.max(err, 2.0 * ti.acos(ti.min(c, 1.0)))
    return err
