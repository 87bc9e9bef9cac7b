"""FABRIK for a Crowd: which kernel solves a request, and its launch.

A constraint-free rig without orientation targets runs the lane kernels (solvers/fabrik_free.py,
kernels/fabrik_lanes.py: characters as SIMD lanes, or on CUDA a stream of characters per GPU thread, then the
rotations recovered in a second pass). Any other rig whose characters all weight the same effectors (or none), with
or without orientation targets, runs kernels/fabrik_limited_lanes.py on the CPU (settings.limited_lanes: how closely
it agrees with the general kernel; CROWD_IK_LIMITED_LANES=0 turns it off); everything else (rotation targets,
weights that differ in which effectors they switch off, CUDA's rigs with limits or orientation targets), the
general one-character-per-thread kernel (kernels/fabrik.py), which also solves full rotation targets
(kernels/fabrik_rotation.py).
"""

from __future__ import annotations

import numpy as np

from crowd_ik.prepared import prepared
from crowd_ik.solvers import bundles, root_frame, settings
from crowd_ik.solvers.ccd import moving_joints
from crowd_ik.solvers.fabrik_free import solve_free
from crowd_ik.solvers.lane_pattern import active_joints, weighted_effectors


def solve(crowd, req) -> None:
    if req.rotations is not None:
        _general(crowd, req.max_iterations, req.tolerance, recover_each_iteration=1, req=req)
        return
    if crowd.rig.constraint_free and crowd.buffers.orient_zero:
        if settings.free_lanes():
            solve_free(crowd, req.max_iterations, req.tolerance)
        else:  # one character per thread, the rotations recovered once
            _general(crowd, req.max_iterations, req.tolerance, recover_each_iteration=0)
        return
    active = lane_active(crowd, req)
    if active is not None:
        solve_limited(crowd, active, req.max_iterations, req.tolerance)
    else:
        _general(crowd, req.max_iterations, req.tolerance, recover_each_iteration=1)


def lane_active(crowd, req):
    """The joints' activity (J,) int32 when the limited lane kernel reproduces this request: CPU lanes switched on
    (settings.limited_lanes), no rotation targets (orientation targets are fine), and the same effectors positively weighted for
    every character that weights any (a game's and the bench's requests; solvers/fabrik_restart.py's windows,
    which give the characters that are done zero weights: those do no iterations in either kernel); else None.
    Poles are fine: solvers/poles.py swivels the limbs after whichever kernel solved."""
    if settings.limited_lanes() <= 1 or req.rotations is not None:
        return None
    weighted = weighted_effectors(crowd.buffers.weights)
    return None if weighted is None else active_joints(crowd, weighted)


def solve_limited(crowd, active: np.ndarray, max_iterations: int, tolerance: float) -> None:
    """FABRIK with joint limits, characters as SIMD lanes (kernels/fabrik_limited_lanes.py)."""
    from crowd_ik.kernels import fabrik_limited_lanes, lane_plan

    ra, L = crowd.rig_arrays, settings.limited_lanes()
    prepared(fabrik_limited_lanes.limited_solver(L, lane_plan.capacity(crowd.rig.n_joints),
                                                 lane_plan.capacity(crowd.rig.n_effectors)))(
        *bundles.limited_rig(crowd), ra["lim_h"], ra["bone"], active, *bundles.pose(crowd), *bundles.goal(crowd),
        int(not crowd.buffers.orient_zero), lane_plan.streams(crowd.n, L), max_iterations, tolerance,
        *bundles.result(crowd),
    )


def _general(crowd, max_iterations: int, tolerance: float, recover_each_iteration: int, req=None) -> None:
    """kernels/fabrik.py: one character per thread, any rig and target; recover_each_iteration 0 only for
    constraint-free rigs without orientation targets (the rotations of the final positions, once); req with
    rotations: the full rotation targets (kernels/fabrik_rotation.py), else none. The kernel solves in each
    character's root frame (solvers/root_frame.py)."""
    from crowd_ik.kernels import fabrik

    ti, J, b = crowd.ti, crowd.rig.n_joints, crowd.buffers
    work = crowd.scratch("fabrik_pos", ti.math.vec3, (crowd.n, J))
    acc_w = crowd.scratch("fabrik_w", ti.f32, (crowd.n, J))
    use_rot = int(req is not None and req.rotations is not None)
    cache = crowd.__dict__.setdefault("_fabrik_eff_move", {})
    if "move" not in cache:
        cache["move"] = moving_joints(crowd.rig)
    with root_frame.shifted(crowd) as (origins, rel_targets):
        prepared(fabrik.fabrik_solve)(
            *bundles.limited_rig(crowd), origins, *bundles.pose(crowd)[1:], rel_targets, b.weights, b.orient, work,
            acc_w, max_iterations, tolerance, recover_each_iteration, int(not b.orient_zero),
            *bundles.rotation_goal(crowd), cache["move"], req.rotation_tolerance if use_rot else 0.0, use_rot,
            *bundles.result(crowd),
        )
