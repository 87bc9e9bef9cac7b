"""Forward kinematics of every joint of every character, and joint angles <-> local rotations.

Arrays: N characters, J joints, D DOFs. Positions in metres, world frame (y up).
"""

import taichi as ti

from crowd_ik.kernels.quat import joint_angles, joint_quat, qmul, qrot, yaw_quat, vec3, vec4

ndarray = ti.types.ndarray


@ti.func
def fk_character(i, parent: ti.template(), offset: ti.template(), root_pos: ti.template(), root_yaw: ti.template(), local_rot: ti.template(), world_pos: ti.template(), world_rot: ti.template()):
    """World transforms of character i's joints: p_j = p_parent + R_parent o_j, R_j = R_parent q_j."""
    q_root = yaw_quat(root_yaw[i])
    for j in range(parent.shape[0]):
        p = parent[j]
        base_pos = root_pos[i]
        base_rot = q_root
        if p >= 0:
            base_pos = world_pos[i, p]
            base_rot = world_rot[i, p]
        world_pos[i, j] = base_pos + qrot(base_rot, offset[j])
        world_rot[i, j] = qmul(base_rot, local_rot[i, j])


@ti.kernel
def forward_kinematics(
    parent: ndarray(dtype=ti.i32, ndim=1),
    offset: ndarray(dtype=vec3, ndim=1),
    root_pos: ndarray(dtype=vec3, ndim=1),
    root_yaw: ndarray(ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
):
    """world_pos (N, J, 3), world_rot (N, J, 4) from root_pos (N, 3), root_yaw (N,) and local_rot (N, J, 4)."""
    for i in range(root_pos.shape[0]):
        fk_character(i, parent, offset, root_pos, root_yaw, local_rot, world_pos, world_rot)


@ti.kernel
def angles_to_rotations(
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    angles: ndarray(ndim=2),
    local_rot: ndarray(dtype=vec4, ndim=2),
):
    """local_rot (N, J, 4) from angles (N, D) radians (ball joints: intrinsic XYZ Euler)."""
    for i, j in ti.ndrange(local_rot.shape[0], local_rot.shape[1]):
        k = kind[j]
        s = dof_start[j]
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        if k >= 1:
            a0 = angles[i, s]
        if k >= 2:
            a1 = angles[i, s + 1]
        if k >= 3:
            a2 = angles[i, s + 2]
        local_rot[i, j] = joint_quat(k, axes[j, 0], axes[j, 1], a0, a1, a2)


@ti.kernel
def rotations_to_angles(
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    angles: ndarray(ndim=2),
):
    """angles (N, D) radians from local_rot (N, J, 4)."""
    for i, j in ti.ndrange(local_rot.shape[0], local_rot.shape[1]):
        k = kind[j]
        s = dof_start[j]
        a = joint_angles(k, axes[j, 0], axes[j, 1], local_rot[i, j])
        for d in range(k):
            angles[i, s + d] = a[d]
