"""Taichi kernels of a SolveReport: the world rotations of chosen joints copied out for the host, and the
characters' statuses.

Crowd._report measures rotation errors on the host (crowd_ik/solvers/errors.py) from the world rotations of the
effectors that have an orientation or rotation target; copying just those rows (instead of every joint's, by
Taichi's own parallel to_numpy kernel) keeps the read-back small and, for a small crowd, on one thread. `statuses`
applies Crowd's status rule in one pass over the characters (NumPy's fancy indexing and reach test took 1.1 ms
for 10,000 humanoids, more than a tenth of a warm game solve).
"""

import taichi as ti

ndarray = ti.types.ndarray
vec3 = ti.math.vec3

# crowd_ik.crowd.Status's codes
CONVERGED, UNREACHABLE, STALLED, MAX_ITERATIONS = 0, 1, 2, 3


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


@ti.kernel
def statuses(
    error: ndarray(ndim=1),
    turn: ndarray(ndim=1),
    tolerance: ti.f32,
    rotation_tolerance: ti.f32,
    targets: ndarray(dtype=vec3, ndim=2),
    weights: ndarray(ndim=2),
    base: ndarray(dtype=vec3, ndim=1),
    bound_sq: ndarray(dtype=ti.f64, ndim=1),
    stalled: ndarray(dtype=ti.i32, ndim=1),
    free_root: ti.i32,
    status: ndarray(dtype=ti.i8, ndim=1),
    serial: ti.template(),
):
    """status (N,) <- Crowd's rule, in order of precedence: CONVERGED where error <= tolerance and turn <=
    rotation_tolerance; else UNREACHABLE where a positively weighted target lies farther from the root joint base
    (N, 3) than bound_sq (E,) (Rig.beyond_reach: the squared distance in float64 of the float32 difference; never
    with free_root != 0); else STALLED where stalled != 0; else MAX_ITERATIONS."""
    ti.loop_config(serialize=serial)
    for n in range(error.shape[0]):
        s = CONVERGED
        if error[n] > tolerance or turn[n] > rotation_tolerance:
            far = 0
            if free_root == 0:
                for e in range(targets.shape[1]):
                    d = targets[n, e] - base[n]
                    x, y, z = ti.cast(d.x, ti.f64), ti.cast(d.y, ti.f64), ti.cast(d.z, ti.f64)
                    if weights[n, e] > 0.0 and x * x + y * y + z * z > bound_sq[e]:
                        far = 1
            s = UNREACHABLE if far else (STALLED if stalled[n] != 0 else MAX_ITERATIONS)
        status[n] = ti.cast(s, ti.i8)
