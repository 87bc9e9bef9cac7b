"""CCD for a Crowd: cyclic coordinate descent (kernels/ccd.py), one sweep per iteration, deepest joint first."""

from __future__ import annotations

import numpy as np

from crowd_ik.solvers import bundles


def solve(crowd, req) -> None:
    ti, rig = crowd.ti, crowd.rig
    # below[j, e] = 1 where effector e's joint lies in joint j's subtree (j included)
    below_np = np.zeros((rig.n_joints, rig.n_effectors), np.int32)
    for e, eff in enumerate(rig.effectors):
        below_np[rig.path_to_root(eff.joint), e] = 1
    below = crowd.scratch("ccd_below", ti.i32, below_np.shape)
    below.from_numpy(below_np)
    reach = crowd.scratch("ccd_reach", ti.f32, (rig.n_effectors,))
    reach.from_numpy(rig.reach.astype(np.float32))
    from crowd_ik.kernels import ccd

    b = crowd.buffers
    goals = int(not b.orient_zero)  # compile time: the plain sweep stays as it was
    ccd.ccd_solve(
        *bundles.limited_rig(crowd), below, reach, *bundles.pose(crowd), *bundles.goal(crowd),
        crowd.scratch("ccd_rel_t", ti.math.vec3, (crowd.n, rig.n_effectors)),
        crowd.scratch("ccd_eff_pos", ti.math.vec3, (crowd.n, rig.n_effectors)),
        req.max_iterations, req.tolerance, req.rotation_tolerance, goals, *bundles.result(crowd),
    )
