"""Row moves for FABRIK's windowed solve (crowd_ik/solvers/fabrik_restart.py): the joint angles of listed characters
read and written, and their local rotations saved and put back. No solver arithmetic: the windows themselves are
launches of kernels/fabrik.py."""

import taichi as ti

from crowd_ik.kernels.quat import joint_angles, joint_quat, vec3, vec4

ndarray = ti.types.ndarray


@ti.kernel
def read_angles(
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
    which: ndarray(dtype=ti.i32, ndim=1),
    angles: ndarray(ndim=2),
):
    """angles (K, D) radians of the characters which (K,), from local_rot (N, J) (as kernels/fk.py's
    rotations_to_angles: ball joints intrinsic XYZ Euler)."""
    for k, j in ti.ndrange(which.shape[0], local_rot.shape[1]):
        kd = kind[j]
        a = joint_angles(kd, axes[j, 0], axes[j, 1], local_rot[which[k], j])
        for d in range(kd):
            angles[k, dof_start[j] + d] = a[d]


@ti.kernel
def write_angles(
    kind: ndarray(dtype=ti.i32, ndim=1),
    axes: ndarray(dtype=vec3, ndim=2),
    dof_start: ndarray(dtype=ti.i32, ndim=1),
    angles: ndarray(ndim=2),
    which: ndarray(dtype=ti.i32, ndim=1),
    local_rot: ndarray(dtype=vec4, ndim=2),
):
    """local_rot of the characters which (K,) from angles (K, D); fixed joints keep their rotation."""
    for k, j in ti.ndrange(which.shape[0], local_rot.shape[1]):
        kd = kind[j]
        if kd > 0:
            s = dof_start[j]
            a0 = angles[k, s]
            a1 = 0.0
            a2 = 0.0
            if kd >= 2:
                a1 = angles[k, s + 1]
            if kd >= 3:
                a2 = angles[k, s + 2]
            local_rot[which[k], j] = joint_quat(kd, axes[j, 0], axes[j, 1], a0, a1, a2)


@ti.kernel
def gather_rows(local_rot: ndarray(dtype=vec4, ndim=2), which: ndarray(dtype=ti.i32, ndim=1),
                out: ndarray(dtype=vec4, ndim=2)):
    """out[which[k]] = local_rot[which[k]] for each listed character (out is (N, J), like local_rot)."""
    for k, j in ti.ndrange(which.shape[0], local_rot.shape[1]):
        out[which[k], j] = local_rot[which[k], j]


@ti.kernel
def scatter_rows(src: ndarray(dtype=vec4, ndim=2), which: ndarray(dtype=ti.i32, ndim=1),
                 local_rot: ndarray(dtype=vec4, ndim=2)):
    """local_rot[which[k]] = src[which[k]] for each listed character."""
    for k, j in ti.ndrange(which.shape[0], local_rot.shape[1]):
        local_rot[which[k], j] = src[which[k], j]
