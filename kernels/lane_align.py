"""Orientation targets on lane packets: kernels/quat.py's align_axis and fabrik.orientation_error with one character
per lane.

align_axis turns a joint's local rotation so that a local direction u of its effector points along a target
direction t (both in the parent's frame): a ball joint by the minimal swing, a hinge by its best angle, a universal
joint by four rounds of alternating best angles about its two axes (block coordinate descent). Every lane of a
packet holds the same joint, so the joint's kind and axes are scalars; the angles' trigonometry is kernels/
lane_trig.py's element-wise polynomials, the rest the same operations in the same order as the twin.
"""

import taichi as ti
from crowd_ik.kernels import lane_math as lm
from crowd_ik.kernels import lane_trig as lt

UNIVERSAL_ROUNDS = 4  # quat.align_axis's rounds for a universal joint


@ti.func
def align_axis(kind, ax0, ax1, qx, qy, qz, qw, u, tx, ty, tz):
    """quat.align_axis per lane: q (four lane vectors) turned so that u (a scalar vec3) points along t."""
    ox, oy, oz, ow = qx, qy, qz, qw
    if kind == 3:
        cx, cy, cz = lm.normalized(*lm.qrot(qx, qy, qz, qw, u.x, u.y, u.z))
        ox, oy, oz, ow = lm.qnormalize(*lm.qmul(*lm.swing(cx, cy, cz, tx, ty, tz), qx, qy, qz, qw))
    elif kind == 1:
        cx, cy, cz = lm.qrot(qx, qy, qz, qw, u.x, u.y, u.z)
        h = lt.best_angle_about(ax0.x, ax0.y, ax0.z, cx, cy, cz, tx, ty, tz)
        ox, oy, oz, ow = lm.qnormalize(*lm.qmul(*lt.axis_angle(ax0.x, ax0.y, ax0.z, h), qx, qy, qz, qw))
    elif kind == 2:
        # quat.joint_angles of a universal joint: the angle about ax0 that turns ax1 to R ax1, the rest about ax1
        vx, vy, vz = lm.qrot(qx, qy, qz, qw, ax1.x, ax1.y, ax1.z)
        cx, cy, cz = lm.cross(ax1.x, ax1.y, ax1.z, vx, vy, vz)
        a0 = lt.atan2(lm.dot3(ax0.x, ax0.y, ax0.z, cx, cy, cz), lm.dot3(ax1.x, ax1.y, ax1.z, vx, vy, vz))
        rx, ry, rz, rw = lt.axis_angle(ax0.x, ax0.y, ax0.z, a0)
        a1 = lt.twist_angle(*lm.qmul(-rx, -ry, -rz, rw, qx, qy, qz, qw), ax1.x, ax1.y, ax1.z)
        for _ in range(UNIVERSAL_ROUNDS):  # a loop, not unrolled: each copy costs compile time
            bx, by, bz, bw = lt.axis_angle(ax1.x, ax1.y, ax1.z, a1)
            a0 = lt.best_angle_about(ax0.x, ax0.y, ax0.z, *lm.qrot(bx, by, bz, bw, u.x, u.y, u.z), tx, ty, tz)
            bx, by, bz, bw = lt.axis_angle(ax0.x, ax0.y, ax0.z, -a0)
            a1 = lt.best_angle_about(ax1.x, ax1.y, ax1.z, u.x, u.y, u.z, *lm.qrot(bx, by, bz, bw, tx, ty, tz))
        # quat.joint_quat of a universal joint
        ox, oy, oz, ow = lm.qmul(*lt.axis_angle(ax0.x, ax0.y, ax0.z, a0), *lt.axis_angle(ax1.x, ax1.y, ax1.z, a1))
    return ox, oy, oz, ow
