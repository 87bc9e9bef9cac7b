"""Taichi kernel of a SolveReport's read-back: the world rotations of chosen joints, copied out for the host.

Crowd._report measures rotation errors on the host (crowd_ik/solvers/errors.py) from the world rotations of the
effectors that have an orientation or rotation target; copying just those rows (instead of every joint's, by
Taichi's own parallel to_numpy kernel) keeps the read-back small and, for a small crowd, on one thread.
"""

import taichi as ti

ndarray = ti.types.ndarray


@ti.kernel
def joint_rotations(
    world_rot: ndarray(dtype=ti.math.vec4, ndim=2),
    joints: ndarray(dtype=ti.i32, ndim=1),
    out: ndarray(ndim=3),
    serial: ti.template(),
):
    """out (N, K, 4) <- world_rot (N, J, 4) at the joints (K,): out[n, k] = world_rot[n, joints[k]], bit for bit."""
    ti.loop_config(serialize=serial)
    for n, k in ti.ndrange(out.shape[0], out.shape[1]):
        q = world_rot[n, joints[k]]
        for c in ti.static(range(4)):
            out[n, k, c] = q[c]
