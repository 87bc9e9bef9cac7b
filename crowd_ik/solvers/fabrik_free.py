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


def _plan(crowd) -> tuple:
    """(serial, the solve's streams, proposals, solve kernel, recover kernel, the recovery's streams) of this crowd
    at the current lane width, made once per width (a solve of 100 chains is ~130 us: the plan's ~10 us counted)."""
    from crowd_ik.kernels import fabrik_lanes, lane_plan

    L = settings.lanes()
    key = (L, settings.on_gpu())
    plans = crowd.__dict__.setdefault("_fabrik_free_plans", {})
    plan = plans.get(key)
    if plan is None:
        J, E = crowd.rig.n_joints, crowd.rig.n_effectors
        P = lane_plan.packets(crowd.n, L)
        serial = serial_for(crowd.n * J, CHAIN_JOINT)  # a small crowd on the launching thread
        LP, n_streams, cap, joint_major = lane_layout(crowd.n, serial)
        V = crowd.ti.types.vector(L, crowd.ti.f32)
        proposals = tuple(crowd.scratch(f"fabrik_lanes_{k}", V, (P, J)) for k in ("gx", "gy", "gz"))
        solver = prepared(fabrik_lanes.free_solver(LP, L, lane_plan.capacity(J), lane_plan.capacity(E), cap,
                                                   joint_major))
        recover = prepared(fabrik_lanes.free_recover(L, lane_plan.capacity(J), cap, joint_major))
        plan = plans[key] = (serial, n_streams, proposals, solver, recover, min(P, cap))
    return plan


def solve_free(crowd, max_iterations: int, tolerance: float) -> None:
    """FABRIK on a constraint-free rig: characters as SIMD lanes (kernels/fabrik_lanes.py), then the rotations."""
    serial, n_streams, proposals, solver, recover, recover_streams = _plan(crowd)
    ra, b = crowd.rig_arrays, crowd.buffers
    solver(ra["parent"], ra["bone"], ra["eff_joint"], crowd.world_pos, crowd.root_pos,
           *bundles.goal(crowd, orientations=False), n_streams, *proposals, max_iterations, tolerance,
           *bundles.result(crowd), serial)
    recover(ra["parent"], ra["offset"], ra["bone"], ra["kind"], ra["child_start"], ra["child_list"], ra["eff_joint"],
            *bundles.pose(crowd), *bundles.goal(crowd, orientations=False), *proposals, recover_streams, b.error,
            b.iterations, serial)
