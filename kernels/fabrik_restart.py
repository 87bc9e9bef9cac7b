"""Row moves for FABRIK's windowed solve (crowd_ik/solvers/fabrik_restart.py): the joint angles of listed characters
read, new start angles written (the pose before saved first where asked), and saved poses put back, each followed by
the characters' forward kinematics (kernels/fk.py character_fk). No solver arithmetic: the solves themselves are
launches of kernels/fabrik.py's fabrik_solve (recover_each_iteration 2: per-character budgets and windows).

The characters are which[:count] of buffers sized for the whole crowd (so that a prepared launch binds the same
arrays every time, crowd_ik/prepared.py); `serial` (kernels/serial_loops.py) runs a few characters' moves on the
launching thread.
"""

import taichi as ti

from crowd_ik.kernels.fk import character_fk, put_row_angles, row_joint_quat
from crowd_ik.kernels.quat import vec3, vec4

ndarray = ti.types.ndarray


@ti.kernel
def read_angles(
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    rotations: ndarray(dtype=vec4, ndim=2),
    which: ndarray(dtype=ti.i32, ndim=1),
    count: ti.i32,
    angles: ndarray(ndim=2),
    serial: ti.template(),
):
    """angles[k] (D,) radians of character which[k]'s rotations (N, J), k < count (as kernels/fk.py's
    rotations_to_angles: ball joints intrinsic XYZ Euler)."""
    ti.loop_config(serialize=serial)
    for k, j in ti.ndrange(count, rotations.shape[1]):
        put_row_angles(kind, axes, dof_start, rotations[which[k], j], angles, k, j)


@ti.kernel
def write_starts(
    parent: ndarray(dtype=ti.i32, ndim=1),
    offset: ndarray(dtype=vec3, ndim=1),
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    root_pos: ndarray(dtype=vec3, ndim=1),
    root_yaw: ndarray(ndim=1),
    angles: ndarray(ndim=2),
    which: ndarray(dtype=ti.i32, ndim=1),
    save: ndarray(dtype=ti.i32, ndim=1),
    count: ti.i32,
    saved: ndarray(dtype=vec4, ndim=2),
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    n_joints: ti.template(),
    serial: ti.template(),
):
    """For k < count, character i = which[k]: its local rotations first copied to saved[i] where save[k] is 1, then
    set from angles[k] (fixed joints keep theirs), then its FK."""
    ti.loop_config(serialize=serial)
    for k in range(count):
        i = which[k]
        for j in range(n_joints):
            if save[k] == 1:
                saved[i, j] = local_rot[i, j]
            if kind[j] > 0:
                local_rot[i, j] = row_joint_quat(kind, axes, dof_start, angles, k, j)
        character_fk(i, parent, offset, root_pos, root_yaw, local_rot, world_pos, world_rot, n_joints)


@ti.kernel
def put_back(
    parent: ndarray(dtype=ti.i32, ndim=1),
    offset: ndarray(dtype=vec3, ndim=1),
    root_pos: ndarray(dtype=vec3, ndim=1),
    root_yaw: ndarray(ndim=1),
    saved: ndarray(dtype=vec4, ndim=2),
    which: ndarray(dtype=ti.i32, ndim=1),
    count: ti.i32,
    local_rot: ndarray(dtype=vec4, ndim=2),
    world_pos: ndarray(dtype=vec3, ndim=2),
    world_rot: ndarray(dtype=vec4, ndim=2),
    n_joints: ti.template(),
    serial: ti.template(),
):
    """For k < count, character i = which[k]: local_rot[i] = saved[i], then its FK."""
    ti.loop_config(serialize=serial)
    for k in range(count):
        i = which[k]
        for j in range(n_joints):
            local_rot[i, j] = saved[i, j]
        character_fk(i, parent, offset, root_pos, root_yaw, local_rot, world_pos, world_rot, n_joints)
