"""A free root for FABRIK and CCD (Crowd.solve(root_weight=w)): the sub-base rule, as one kernel launch.

FABRIK's backward pass from a target beyond reach pulls the chain's base toward the target by the distance
the target lies beyond the chain's reach; a free root (a sub-base with no anchor) takes the weighted mean of
the moves its chains ask for. Before the solve, ROOT_SHIFT_ROUNDS times, the root moves by

    frac * sum_e w_e b_e u_e / sum_e w_e      over the effectors e with b_e > 0,
    b_e = |t_e - base| - (1 - ROOT_SHIFT_SLACK) reach_e,   u_e = (t_e - base) / |t_e - base|,

frac = min(w, 1) (crowd_ik/solvers/settings.py holds the constants); the effectors inside their reach ask
for nothing, and a later round pulls back a root that moved one of them out of it. Targets within reach
leave the root where it is. Only the first `dim` components move (a planar rig's root stays in its plane).
"""

import taichi as ti

from crowd_ik.kernels.quat import vec3
from crowd_ik.solvers.settings import ROOT_SHIFT_ROUNDS, ROOT_SHIFT_SLACK

ndarray = ti.types.ndarray


@ti.kernel
def shift_roots(
    reach: ndarray(ndim=1),
    root_pos: ndarray(dtype=vec3, ndim=1),
    base: ndarray(dtype=vec3, ndim=1),
    targets: ndarray(dtype=vec3, ndim=2),
    weights: ndarray(ndim=2),
    frac: ti.f32,
    dim: ti.i32,
):
    """Move root_pos (N,) in place by the rule above; base (N,) the root joints' world positions before it."""
    for i in range(root_pos.shape[0]):
        shift = vec3(0.0)
        for _ in range(ROOT_SHIFT_ROUNDS):
            acc = vec3(0.0)
            wsum = 0.0
            b0 = base[i] + shift
            for e in range(reach.shape[0]):
                w = weights[i, e]
                if w > 0.0:
                    r = targets[i, e] - b0
                    dist = r.norm()
                    beyond = dist - (1.0 - ROOT_SHIFT_SLACK) * reach[e]
                    if beyond > 0.0:
                        acc += w * beyond / dist * r
                        wsum += w
            if wsum > 0.0:
                shift += frac * acc / wsum
        if dim == 2:
            shift.z = 0.0
        root_pos[i] += shift
