"""Forward kinematics of every joint of every character, and joint angles <-> local rotations.

Arrays: N characters, J joints, D DOFs. Positions in metres, world frame (y up).
"""

import taichi as ti

from crowd_ik.kernels.local_arrays import get3, get4, put
from crowd_ik.kernels.quat import joint_angles, joint_quat, qmul, qrot, yaw_quat, vec3, vec4
from crowd_ik.kernels.serial_loops import JOINT, serial_for

ndarray = ti.types.ndarray


@ti.func
def joint_fk_local(j, p, base_root, offset: ti.template(), rot: ti.template(), pos: ti.template()):
    """pos[j] (relative to the character's root point) from its parent p's position and world rotation held in local
    arrays (kernels/local_arrays.py): p_j = p_parent + R_parent o_j. Returns R_parent (base_root for the root)."""
    base_rot = base_root
    base_pos = vec3(0.0)
    if p >= 0:
        base_rot = get4(rot, p)
        base_pos = get3(pos, p)
    put(pos, j, base_pos + qrot(base_rot, offset[j]))
    return base_rot


@ti.func
def character_fk(i, parent: ti.template(), offset: ti.template(), root_pos: ti.template(), root_yaw: ti.template(),
                 local_rot: ti.template(), world_pos: ti.template(), world_rot: ti.template(), n_joints: ti.template()):
    """Character i's world pose from its root and local rotations: fk_kernel's body (FABRIK's restarts use it too)."""
    pos = ti.Matrix.zero(ti.f32, n_joints, 3)
    rot = ti.Matrix.zero(ti.f32, n_joints, 4)
    q_root = yaw_quat(root_yaw[i])
    for j in range(n_joints):
        put(rot, j, qmul(joint_fk_local(j, parent[j], q_root, offset, rot, pos), local_rot[i, j]))
    for j in range(n_joints):
        world_pos[i, j] = root_pos[i] + get3(pos, j)
        world_rot[i, j] = get4(rot, j)



def forward_kinematics(parent, offset, root_pos, root_yaw, local_rot, world_pos, world_rot, which, n_joints: int):
    """world_pos, world_rot of the characters `which` (K,) from their roots and local_rot (fk_kernel), on the
    launching thread when K characters are few (kernels/serial_loops.py)."""
    fk_kernel(parent, offset, root_pos, root_yaw, local_rot, world_pos, world_rot, which, n_joints,
              serial_for(which.shape[0] * n_joints, JOINT))


@ti.kernel
def fk_kernel(
    parent: ndarray(dtype=ti.i32, ndim=1),
    offset: ndarray(dtype=vec3, ndim=1),
    root_pos: ndarray(dtype=vec3, ndim=1),
    root_yaw: ndarray(ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    which: ndarray(dtype=ti.i32, ndim=1),
    n_joints: ti.template(),
    serial: ti.template(),
):
    """world_pos (N, J, 3), world_rot (N, J, 4) from root_pos (N, 3), root_yaw (N,) and local_rot (N, J, 4), for the
    characters listed in `which` (K,).

    p_j = p_parent + R_parent o_j, R_j = R_parent q_j, relative to the root point, which is added last (as
    the solvers do: a character's pose does not depend on where it stands); each character's transforms are
    built in local arrays (n_joints = J, a Python int) and written out once (see kernels/local_arrays.py):
    1.9 -> 1.5 ms for 10,000 humanoids.
    """
    ti.loop_config(serialize=serial)
    for k in range(which.shape[0]):
        character_fk(which[k], parent, offset, root_pos, root_yaw, local_rot, world_pos, world_rot, n_joints)


@ti.func
def row_joint_quat(kind: ti.template(), axes: ti.template(), dof_start: ti.template(), angles: ti.template(), row, j):
    """Joint j's local rotation from its angles in angles[row] (D,) radians (ball joints: intrinsic XYZ Euler)."""
    k = kind[j]
    s = dof_start[j]
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    if k >= 1:
        a0 = angles[row, s]
    if k >= 2:
        a1 = angles[row, s + 1]
    if k >= 3:
        a2 = angles[row, s + 2]
    return joint_quat(k, axes[j, 0], axes[j, 1], a0, a1, a2)


@ti.func
def put_row_angles(kind: ti.template(), axes: ti.template(), dof_start: ti.template(), q, angles: ti.template(), row,
                   j):
    """Joint j's angles of local rotation q into angles[row] (D,) radians."""
    k = kind[j]
    a = joint_angles(k, axes[j, 0], axes[j, 1], q)
    for d in range(k):
        angles[row, dof_start[j] + d] = a[d]


@ti.kernel
def angles_to_rotations(
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    angles: ndarray(ndim=2),
    local_rot: ndarray(dtype=vec4, ndim=2),
    serial: ti.template(),
):
    """local_rot (N, J, 4) from angles (N, D) radians (ball joints: intrinsic XYZ Euler); serial: on the launching
    thread (kernels/serial_loops.py)."""
    ti.loop_config(serialize=serial)
    for i, j in ti.ndrange(local_rot.shape[0], local_rot.shape[1]):
        local_rot[i, j] = row_joint_quat(kind, axes, dof_start, angles, i, j)


@ti.kernel
def rotations_to_angles(
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    angles: ndarray(ndim=2),
    serial: ti.template(),
):
    """angles (N, D) radians from local_rot (N, J, 4); serial as in angles_to_rotations."""
    ti.loop_config(serialize=serial)
    for i, j in ti.ndrange(local_rot.shape[0], local_rot.shape[1]):
        put_row_angles(kind, axes, dof_start, local_rot[i, j], angles, i, j)
