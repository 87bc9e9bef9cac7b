"""Constraint-free FABRIK for a Crowd without orientation targets: the lane kernels' launch (kernels/fabrik_lanes.py,
characters as SIMD lanes, then the rotations recovered in a second pass)."""

from __future__ import annotations

from crowd_ik.kernels.serial_loops import CHAIN_JOINT, serial_for
from crowd_ik.prepared import prepared
from crowd_ik.solvers import bundles, settings


def solve_free(crowd, max_iterations: int, tolerance: float) -> None:
    """FABRIK on a constraint-free rig: characters as SIMD lanes (kernels/fabrik_lanes.py), then the rotations
    (CPU lanes only: solvers/fabrik.solve sends one lane, CUDA, to the general kernel)."""
    from crowd_ik.kernels import fabrik_lanes, lane_plan

    ra, ti, L = crowd.rig_arrays, crowd.ti, settings.lanes()
    J, E = crowd.rig.n_joints, crowd.rig.n_effectors
    LP = lane_plan.pass_lanes(L)
    P = lane_plan.packets(crowd.n, L)
    V = ti.types.vector(L, ti.f32)
    proposals = [crowd.scratch(f"fabrik_lanes_{k}", V, (P, J)) for k in ("gx", "gy", "gz")]
    b = crowd.buffers
    serial = serial_for(crowd.n * J, CHAIN_JOINT)  # a small crowd on the launching thread
    prepared(fabrik_lanes.free_solver(LP, L, lane_plan.capacity(J), lane_plan.capacity(E)))(
        ra["parent"], ra["bone"], ra["eff_joint"], crowd.world_pos, crowd.root_pos,
        *bundles.goal(crowd, orientations=False),
        lane_plan.streams(crowd.n, LP), *proposals, max_iterations, tolerance, *bundles.result(crowd), serial,
    )
    prepared(fabrik_lanes.free_recover(L, lane_plan.capacity(J)))(
        ra["parent"], ra["offset"], ra["bone"], ra["kind"], ra["child_start"], ra["child_list"], ra["eff_joint"],
        *bundles.pose(crowd), *bundles.goal(crowd, orientations=False), *proposals,
        min(P, lane_plan.MAX_STREAMS), b.error, b.iterations, serial,
    )
