"""Constraint-free FABRIK for a Crowd without orientation targets: the lane kernels' launch (kernels/fabrik_lanes.py,
characters as SIMD lanes, then the rotations recovered in a second pass; on CUDA one lane per GPU thread)."""

from __future__ import annotations

from crowd_ik.kernels.serial_loops import CHAIN_JOINT, serial_for
from crowd_ik.prepared import prepared
from crowd_ik.solvers import bundles, settings


def lane_layout(n: int, serial: bool = False) -> tuple[int, int, int, bool]:
    """(lanes per stream of the solve kernel, streams, scratch rows' streams, joint-major) for n characters, solved
    on the launching thread if serial (kernels/serial_loops.py; one stream, lane_plan.streams). At one lane (CUDA) a
    stream is one GPU thread working through its characters one at a time, lane_plan.GPU_STREAMS of them with their
    scratch joint-major (lane_plan.stream_rows: a warp's threads read a joint's row together)."""
    from crowd_ik.kernels import lane_plan

    L = settings.lanes()
    if L > 1:
        LP = lane_plan.pass_lanes(L)
        return LP, lane_plan.streams(n, LP, serial), lane_plan.MAX_STREAMS, False
    cap = lane_plan.GPU_STREAMS if settings.on_gpu() else lane_plan.MAX_STREAMS
    return 1, min(n, cap), cap, True


def solve_free(crowd, max_iterations: int, tolerance: float) -> None:
    """FABRIK on a constraint-free rig: characters as SIMD lanes (kernels/fabrik_lanes.py), then the rotations."""
    from crowd_ik.kernels import fabrik_lanes, lane_plan

    ra, ti, L = crowd.rig_arrays, crowd.ti, settings.lanes()
    J, E = crowd.rig.n_joints, crowd.rig.n_effectors
    P = lane_plan.packets(crowd.n, L)
    serial = serial_for(crowd.n * J, CHAIN_JOINT)  # a small crowd on the launching thread
    LP, n_streams, cap, joint_major = lane_layout(crowd.n, serial)
    V = ti.types.vector(L, ti.f32)
    proposals = [crowd.scratch(f"fabrik_lanes_{k}", V, (P, J)) for k in ("gx", "gy", "gz")]
    b = crowd.buffers
    prepared(fabrik_lanes.free_solver(LP, L, lane_plan.capacity(J), lane_plan.capacity(E), cap, joint_major))(
        ra["parent"], ra["bone"], ra["eff_joint"], crowd.world_pos, crowd.root_pos,
        *bundles.goal(crowd, orientations=False), n_streams, *proposals, max_iterations, tolerance,
        *bundles.result(crowd), serial,
    )
    prepared(fabrik_lanes.free_recover(L, lane_plan.capacity(J), cap, joint_major))(
        ra["parent"], ra["offset"], ra["bone"], ra["kind"], ra["child_start"], ra["child_list"], ra["eff_joint"],
        *bundles.pose(crowd), *bundles.goal(crowd, orientations=False), *proposals, min(P, cap), b.error,
        b.iterations, serial,
    )
