"""CCD for a Crowd: cyclic coordinate descent (kernels/ccd.py), one sweep per iteration, deepest joint first.

A request whose characters all weight the same effectors (or none), without full rotation targets, runs
kernels/ccd_lanes.py on the CPU (characters as SIMD lanes): its constraint-free kernel for a constraint-free rig with
position targets only, its limited one (settings.limited_lanes' width) for joint limits or orientation targets;
anything else, and CUDA (one lane), the one-character kernel (kernels/ccd.py)."""

from __future__ import annotations

import numpy as np

from crowd_ik.prepared import prepared
from crowd_ik.solvers import bundles, settings
from crowd_ik.solvers.lane_pattern import active_joints, weighted_effectors


def moving_joints(rig) -> np.ndarray:
    """(E, 2) int32: per effector [m, b]: m the nearest joint with DOFs at or above its joint (the joint that turns
    the effector's frame: a hand's wrist, an ankle itself), b the nearest ball joint above m whose subtree holds
    no other effector (a shoulder, a hip: it swivels the limb for the twist m lacks); -1 where none."""
    out = np.full((rig.n_effectors, 2), -1, np.int32)
    kind = rig.arrays["kind"]
    holds = np.zeros((rig.n_joints, rig.n_effectors), bool)
    for e, eff in enumerate(rig.effectors):
        holds[rig.path_to_root(eff.joint), e] = True
    for e, eff in enumerate(rig.effectors):
        path = rig.path_to_root(eff.joint)
        for n, j in enumerate(path):
            if kind[j] > 0:
                out[e, 0] = j
                for b in path[n + 1 :]:
                    if holds[b].sum() > 1:
                        break
                    if kind[b] == 3:
                        out[e, 1] = b
                        break
                break
    return out


def limb_lengths(rig, move: np.ndarray) -> np.ndarray:
    """(E, 2) float64: per effector the bone path from its limb's ball joint b = move[e, 1] to the effector joint and
    to its moving joint move[e, 0] (kernels/ccd_rotation.limb_weights); 0 where it has no such b."""
    out = np.zeros((rig.n_effectors, 2))
    bone = np.linalg.norm(rig.arrays["offset"].astype(np.float64), axis=-1)
    for e, eff in enumerate(rig.effectors):
        b = move[e, 1]
        if b < 0:
            continue
        for c, start in enumerate((eff.joint, move[e, 0])):
            k = start
            while k > b:
                out[e, c] += bone[k]
                k = rig.joints[k].parent
    return out


def _rig_constants(crowd) -> tuple:
    """The rig's CCD constants as ndarrays, uploaded once per crowd: below (J, E) 1 where effector e's joint lies in
    joint j's subtree (j included), reach (E,), eff_move (E, 2) (moving_joints) and limb_len (E, 2) (limb_lengths)."""
    rig = crowd.rig

    def values():
        below = np.zeros((rig.n_joints, rig.n_effectors), np.int32)
        for e, eff in enumerate(rig.effectors):
            below[rig.path_to_root(eff.joint), e] = 1
        move = moving_joints(rig)
        return below, rig.reach.astype(np.float32), move, limb_lengths(rig, move).astype(np.float32)

    return crowd.constants(("ccd_below", "ccd_reach", "ccd_eff_move", "ccd_limb_len"), values)


def solve(crowd, req) -> None:
    from crowd_ik.kernels import ccd

    ti, rig, b = crowd.ti, crowd.rig, crowd.buffers
    below, reach, move, limb = _rig_constants(crowd)
    weighted = lane_weights(crowd, req)
    if weighted is not None:
        _solve_lanes(crowd, req, below, reach, weighted)
        return
    # compile time: the plain sweep stays as it was; 1 axis targets, 2 full rotation targets
    goals = int(not b.orient_zero) | (6 if req.rotations is not None else 0)  # 4: limb_weights
    ccd.ccd_solve(
        *bundles.limited_rig(crowd), below, reach, *bundles.pose(crowd), *bundles.goal(crowd),
        *bundles.rotation_goal(crowd), move,
        crowd.scratch("ccd_rel_t", ti.math.vec3, (crowd.n, rig.n_effectors)),
        crowd.scratch("ccd_aim_t", ti.math.vec3, (crowd.n, rig.n_effectors)),
        crowd.scratch("ccd_eff_pos", ti.math.vec3, (crowd.n, rig.n_effectors)),
        limb, crowd.scratch("ccd_aim_w", ti.f32, (crowd.n, rig.n_effectors)),
        req.max_iterations, req.tolerance, req.rotation_tolerance, goals, *bundles.result(crowd),
    )


def lane_weights(crowd, req) -> tuple | None:
    """The effectors switched on when kernels/ccd_lanes.py reproduces this request (CPU lanes, no rotation targets,
    the same effectors weighted by every character that weights any; a rig with limits or orientation targets also
    needs the limited lanes switched on, settings.limited_lanes),
    else None."""
    if settings.lanes() <= 1 or req.rotations is not None:
        return None
    if not _free(crowd) and settings.limited_lanes() <= 1:
        return None
    return weighted_effectors(crowd.buffers.weights)


def _free(crowd) -> bool:
    """Whether the constraint-free lane kernel takes the request: no limits, no orientation targets."""
    return crowd.rig.constraint_free and crowd.buffers.orient_zero


def _solve_lanes(crowd, req, below, reach, weighted: tuple) -> None:
    from crowd_ik.kernels import ccd_lanes, lane_plan

    ra, rig, b = crowd.rig_arrays, crowd.rig, crowd.buffers
    free = _free(crowd)
    L = settings.lanes() if free else settings.limited_lanes()
    pattern = "".join("1" if w else "0" for w in weighted)  # the pattern's joints and effectors, uploaded once
    active, on = crowd.constants((f"ccd_active_{pattern}", f"ccd_on_{pattern}"),
                                 lambda: (active_joints(crowd, weighted), np.asarray(weighted, np.int32)))
    kernel = ccd_lanes.ccd_solver(L, lane_plan.capacity(rig.n_joints), lane_plan.capacity(rig.n_effectors), not free)
    prepared(kernel)(
        ra["parent"], ra["offset"], ra["kind"], ra["axes"], ra["lo"], ra["hi"], ra["lim_p"], ra["lim_h"], ra["cone"],
        ra["dof_start"], ra["child_start"], ra["child_list"], ra["eff_joint"], ra["eff_axis"], below, reach, active,
        on, *bundles.pose(crowd), *bundles.goal(crowd), int(not b.orient_zero), lane_plan.streams(crowd.n, L),
        req.max_iterations, req.tolerance, req.rotation_tolerance, *bundles.result(crowd),
    )
