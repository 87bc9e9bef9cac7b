"""Analytic Jacobians of effector positions and orientations, built up the chain (the lecture's method).

For a DOF with world rotation axis w at joint position p_n, an effector at p_k below it moves by
dp/dtheta = w x (p_k - p_n) and turns by dOmega/dtheta = w. The axes per joint kind:
hinge w = R_parent a0; universal w0 = R_parent a0, w1 = R_parent R(a0, t0) a1; ball, Euler XYZ
(ball_mode 0): w = R_parent x, R_parent Rx(a) y, R_parent Rx(a) Ry(b) z; ball, quaternion (ball_mode 1):
the world x, y, z axes (the derivative of exp(w dtheta) q, the update a quaternion solver applies).
"""

import taichi as ti

from crowd_ik.kernels.quat import axis_angle, joint_angles, qmul, qrot, yaw_quat, vec3, vec4

ndarray = ti.types.ndarray


@ti.func
def dof_axes(kind, ax0, ax1, base_rot, q_local, ball_mode):
    """World rotation axes (as columns of a 3x3, one per DOF) of a joint whose parent frame is base_rot."""
    a = joint_angles(kind, ax0, ax1, q_local)
    w0 = vec3(0.0)
    w1 = vec3(0.0)
    w2 = vec3(0.0)
    if kind == 1:
        w0 = qrot(base_rot, ax0)
    elif kind == 2:
        w0 = qrot(base_rot, ax0)
        w1 = qrot(qmul(base_rot, axis_angle(ax0, a.x)), ax1)
    elif kind == 3:
        if ball_mode == 0:
            ex = vec3(1.0, 0.0, 0.0)
            ey = vec3(0.0, 1.0, 0.0)
            ez = vec3(0.0, 0.0, 1.0)
            rx = qmul(base_rot, axis_angle(ex, a.x))
            w0 = qrot(base_rot, ex)
            w1 = qrot(rx, ey)
            w2 = qrot(qmul(rx, axis_angle(ey, a.y)), ez)
        else:
            w0 = vec3(1.0, 0.0, 0.0)
            w1 = vec3(0.0, 1.0, 0.0)
            w2 = vec3(0.0, 0.0, 1.0)
    return ti.Matrix.cols([w0, w1, w2])


@ti.func
def jacobian_character(i, parent: ti.template(), kind: ti.template(), axes: ti.template(), dof_start: ti.template(), eff_joint: ti.template(), root_yaw: ti.template(), local_rot: ti.template(), world_pos: ti.template(), world_rot: ti.template(),
                       ball_mode, jac: ti.template()):
    """Fill jac[i] (6E, D): rows 6e..6e+2 position of effector e, 6e+3..6e+5 its orientation."""
    for r, d in ti.ndrange(jac.shape[1], jac.shape[2]):
        jac[i, r, d] = 0.0
    q_root = yaw_quat(root_yaw[i])
    for e in range(eff_joint.shape[0]):
        k = eff_joint[e]
        p_eff = world_pos[i, k]
        n = k
        while n >= 0:
            kd = kind[n]
            if kd > 0:
                p = parent[n]
                base_rot = q_root
                if p >= 0:
                    base_rot = world_rot[i, p]
                w = dof_axes(kd, axes[n, 0], axes[n, 1], base_rot, local_rot[i, n], ball_mode)
                lever = p_eff - world_pos[i, n]
                s = dof_start[n]
                for c in range(kd):
                    col = vec3(w[0, c], w[1, c], w[2, c])
                    dp = ti.math.cross(col, lever)  # zero lever for the effector's own joint
                    for r in ti.static(range(3)):
                        jac[i, 6 * e + r, s + c] = dp[r]
                        jac[i, 6 * e + 3 + r, s + c] = col[r]
            n = parent[n]


@ti.kernel
def compute_jacobian(
    parent: ndarray(dtype=ti.i32, ndim=1),
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    eff_joint: ndarray(dtype=ti.i32, ndim=1),
    root_yaw: ndarray(ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    ball_mode: ti.i32,
    jac: ndarray(ndim=3),
):
    """jac (N, 6E, D) of every character, from its current FK (world_pos, world_rot)."""
    for i in range(jac.shape[0]):
        jacobian_character(i, parent, kind, axes, dof_start, eff_joint, root_yaw, local_rot, world_pos, world_rot,
                           ball_mode, jac)
