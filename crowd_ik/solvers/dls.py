"""Damped least squares for a Crowd: which kernel solves a request, its per-solve settings, and its launch.

One position effector on a constraint-free rig with no secondary terms has a closed-form 3 x 3
system: characters as SIMD lanes (kernels/dls_lanes.py; on CUDA one per thread, kernels/dls_free.py).
Everything else runs the general solve (LM damping, joint-limit active set, orientation rows, rest / velocity /
balance terms): on the CPU as SIMD lanes (kernels/dls_general_lanes.py, settings.general_lanes' width; full rotation
targets, a free root and the secondary terms in kernels of their own), on CUDA one character per thread
(kernels/dls.py).
"""

from __future__ import annotations

import numpy as np

from crowd_ik.kernels.serial_loops import CHAIN_JOINT, serial_for
from crowd_ik.prepared import prepared
from crowd_ik.solvers import bundles, settings
from crowd_ik.solvers.dls_setup import dls_settings
from crowd_ik.solvers.limits import limit_half_turns, limit_pseudo_angles


def solve(crowd, req) -> None:
    if crowd.rig.constraint_free and crowd.rig.n_effectors == 1 and req.plain and req.root_weight is None:
        _free(crowd, req)
    else:
        _general(crowd, req)


def _general(crowd, req) -> None:
    """kernels/dls.py, one launch. A free root (req.root_weight) adds 3 columns after the DOFs' D + 1; the
    kernel moves crowd.root_pos in place (the Crowd then refreshes what it derives from the roots)."""
    from crowd_ik.kernels import dls

    ra, ti, rig, N = crowd.rig_arrays, crowd.ti, crowd.rig, crowd.n
    # rows: 3 per effector, 2 more for each effector with an axis (orientation target), 2 for balance
    D, J = max(rig.n_dof, 1), rig.n_joints
    R = 3 * rig.n_effectors + 2 * int(rig.arrays["eff_has_axis"].sum()) + 2 * int(req.balance_weight > 0)
    # compile-time feature bits of kernels/dls.py: 1 full rotation targets, 2 secondary terms in the null space,
    # 4 a free root
    extra = 0
    if req.rotations is not None:
        extra |= 1
        R += 3 * rig.n_effectors
    if req.rest_weight > 0 or req.velocity_weight > 0 or req.balance_weight > 0:
        extra |= 2
    C = D + 1  # columns: the DOFs, one padding, and the root's translation when it is free
    if req.root_weight is not None:
        extra |= 4
        C += 3
    cfg, small = _general_settings(crowd, req, C)
    if settings.general_lanes() > 1:
        _general_lanes(crowd, req, cfg, small, sec=bool(extra & 2))
        return
    prepared(dls.dls_solve)(
        ra["parent"], ra["offset"], ra["kind"], small["jmode"], ra["axes"], small["lo"], small["hi"],
        small["lim_p"], ra["cone"], ra["dof_start"], ra["child_start"], ra["child_list"], ra["eff_joint"],
        ra["eff_axis"], ra["eff_has_axis"],
        small["eff_lim"], small["joint_w"], small["com_w"], small["support_w"], *bundles.pose(crowd),
        *bundles.goal(crowd), *bundles.rotation_goal(crowd),
        crowd.scratch("dls_rel_pos", ti.math.vec3, (N, J)),
        crowd.scratch("dls_qwork", ti.math.vec4, (N, dls.N_Q_SLOTS, J)),
        crowd.scratch("dls_work", ti.f32, (N, dls.N_DOF_SLOTS, C)),
        crowd.scratch("dls_jac", ti.f32, (N, R, C)), crowd.scratch("dls_rows", ti.f32, (N, 3, R)),
        crowd.scratch("dls_sys", ti.f32, (N, R, R)),
        req.max_iterations, req.tolerance, cfg["damping"], cfg["length"],
        req.rest_weight, req.velocity_weight, req.balance_weight, extra, *bundles.result(crowd),
    )


def _general_settings(crowd, req, C: int) -> tuple:
    """(cfg, the uploaded per-solve settings) of the general solve, computed and uploaded when they change (a game's
    solves reuse them)."""
    ti, rig = crowd.ti, crowd.rig
    jw = None if req.joint_weights is None else req.joint_weights
    key = ("general", req.damping, None if jw is None else jw.tobytes(), req.root_weight)
    cfg, small = _loaded(crowd, key)
    if small is None:
        cfg = dls_settings(rig, req.damping, jw)
        joint_w = np.zeros(C, np.float32)
        joint_w[: rig.n_dof] = 1.0 if jw is None else jw
        if req.root_weight is not None:
            D1 = max(rig.n_dof, 1) + 1
            joint_w[D1 : D1 + rig.dim] = req.root_weight  # a planar rig's root stays in its plane
        small = {}  # per-solve settings: a few dozen numbers
        for name, value in (("eff_lim", cfg["eff_lim"]), ("joint_w", joint_w), ("jmode", cfg["jmode"]),
                            ("lo", cfg["lo32"]), ("hi", cfg["hi32"]),
                            ("lim_p", limit_pseudo_angles(cfg["lo32"], cfg["hi32"])),
                            ("lim_h", limit_half_turns(cfg["lo32"], cfg["hi32"])),
                            ("com_w", cfg["com_w"].astype(np.float32)),
                            ("support_w", cfg["support_w"].astype(np.float32))):
            small[name] = crowd.scratch(f"dls_{name}", ti.i32 if value.dtype == np.int32 else ti.f32, value.shape)
            small[name].from_numpy(value)
        _store(crowd, key, cfg, small)
    return cfg, small


def row_layout(rig, weights: np.ndarray, orient: np.ndarray | None, rot_w: np.ndarray | None = None) -> np.ndarray:
    """(E,) int32, the general lanes' rows per effector, bits: 1 its 3 position rows (some character weights it, or
    gives it a rotation target), 2 its 2 axis rows and a zero row (some character that weights it gives it an
    orientation target, and the rig has its axis), 4 its 3 rotation rows (some character's rot_w > 0); 0 no rows."""
    on = weights > 0.0
    rows = on.any(axis=0).astype(np.int32)
    if orient is not None:
        ori = on & (np.einsum("nec,nec->ne", orient, orient) > 0.0) & (rig.arrays["eff_has_axis"] != 0)
        rows[ori.any(axis=0)] |= 2
    if rot_w is not None:
        rot = (rot_w > 0.0).any(axis=0)
        rows[rot] |= 5
    return rows


def shared_runs(rig, free_root: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(count (E, E) int32, runs (E, E, K, 2) int32): per pair of effectors the runs [start, end) of consecutive DOF
    columns on both of their paths to the root, ascending (the only columns where both effectors' Jacobian rows can
    be nonzero; a pair's own runs are the columns the effector moves). A free root adds its three columns, the last
    (D + 1 .. D + 3), to every pair: every effector's position rows move with it."""
    E, kind, start = rig.n_effectors, rig.arrays["kind"], rig.arrays["dof_start"]
    on = np.zeros((E, max(rig.n_dof, 1) + 1 + 3 * free_root), bool)
    for e, eff in enumerate(rig.effectors):
        for j in rig.path_to_root(eff.joint):
            on[e, start[j] : start[j] + kind[j]] = True
    if free_root:
        on[:, -3:] = True
    found = {}
    for a in range(E):
        for b in range(E):
            both = np.concatenate([[False], on[a] & on[b], [False]]).astype(np.int8)
            edges = np.flatnonzero(np.diff(both))  # starts and ends alternate
            found[a, b] = edges.reshape(-1, 2)
    count = np.zeros((E, E), np.int32)
    runs = np.zeros((E, E, max(1, max(len(r) for r in found.values())), 2), np.int32)
    for (a, b), r in found.items():
        count[a, b] = len(r)
        runs[a, b, : len(r)] = r
    return count, runs


def row_groups(layout: np.ndarray) -> np.ndarray:
    """(G,) int32: the effector of each block of three rows of the general lanes' system, in row order (per effector
    its position rows, its axis rows and a zero row, its rotation rows, as its layout bits say)."""
    counts = (layout & 1 > 0).astype(int) + (layout & 2 > 0) + (layout & 4 > 0)
    return np.repeat(np.arange(len(layout), dtype=np.int32), counts)


def _general_lanes(crowd, req, cfg: dict, small: dict, sec: bool) -> None:
    """kernels/dls_general_lanes.py: the general solve (with or without full rotation targets, a free root and the
    secondary terms), characters as SIMD lanes."""
    from crowd_ik.kernels import dls_general_lanes, lane_plan

    ra, rig, b = crowd.rig_arrays, crowd.rig, crowd.buffers
    rot = req.rotations is not None
    layout = row_layout(rig, b.weights, None if b.orient_zero else b.orient, b.rot_w if rot else None)
    groups = row_groups(layout)
    free_root = req.root_weight is not None
    runs = crowd.constants((f"dls_run_count_{free_root:d}", f"dls_runs_{free_root:d}"),
                           lambda: shared_runs(rig, free_root))
    spelled = "_".join(str(x) for x in layout)  # uploaded once per layout, with each block's effector
    rows = crowd.constants((f"dls_rows_{spelled}", f"dls_groups_{spelled}"),
                           lambda: (layout, np.resize(groups, max(len(groups), 1))))
    L = settings.general_lanes()
    C = small["joint_w"].shape[0]
    cap = lane_plan.capacity
    most = (9 if rot else 6) * rig.n_effectors  # at most 3 blocks of three rows per effector with rotation targets
    sizes = (cap(rig.n_joints + 1), cap(C), cap(max(most, 1)), cap(rig.n_effectors))
    kernel = dls_general_lanes.general_solver(L, *sizes, rot, free_root, sec)
    streams = min(lane_plan.streams(crowd.n, L), dls_general_lanes.max_streams(L, *sizes, sec))
    prepared(kernel)(
        ra["parent"], ra["offset"], ra["kind"], small["jmode"], ra["axes"], small["lo"], small["hi"], small["lim_p"],
        small["lim_h"], ra["cone"], ra["dof_start"], ra["child_start"], ra["child_list"], ra["eff_joint"],
        ra["eff_axis"], ra["eff_has_axis"], small["eff_lim"], *rows, *runs, small["joint_w"], small["com_w"],
        small["support_w"], *bundles.pose(crowd), *bundles.goal(crowd), *bundles.rotation_goal(crowd), len(groups),
        streams, req.max_iterations, req.tolerance, cfg["damping"], cfg["length"], req.rest_weight,
        req.velocity_weight, req.balance_weight, *bundles.result(crowd),
    )


def _free(crowd, req) -> None:
    """DLS of one effector on a constraint-free rig: a closed-form 3 x 3 system, characters as SIMD lanes."""
    from crowd_ik.kernels import dls_lanes, lane_plan

    ra, ti, rig = crowd.rig_arrays, crowd.ti, crowd.rig
    key = ("free", req.damping)
    cfg, small = _loaded(crowd, key)
    if small is None:
        cfg = dls_settings(rig, req.damping)
        on_path_np = np.zeros(rig.n_joints, np.int32)
        path = rig.path_to_root(rig.effectors[0].joint)
        on_path_np[path] = rig.arrays["kind"][path] > 0
        small = dict(on_path=crowd.scratch("dls_on_path", ti.i32, (rig.n_joints,)),
                     eff_lim=crowd.scratch("dls_eff_lim", ti.f32, cfg["eff_lim"].shape))
        small["on_path"].from_numpy(on_path_np)
        small["eff_lim"].from_numpy(cfg["eff_lim"])
        _store(crowd, key, cfg, small)
    head = (ra["parent"], ra["offset"], ra["kind"], small["on_path"], ra["eff_joint"], small["eff_lim"],
            *bundles.pose(crowd), *bundles.goal(crowd, orientations=False))
    L = settings.lanes()
    if L == 1:  # CUDA: one character per GPU thread, each pose in local arrays
        from crowd_ik.kernels import dls_free

        prepared(dls_free.dls_solve_free)(*head, req.max_iterations, req.tolerance, cfg["damping"],
                                          cfg["length"], *bundles.result(crowd), rig.n_joints)
        return
    # one vector per value (L lanes): 2L ran 12 % faster but took 31 s instead of ~10 s to compile
    serial = serial_for(crowd.n * rig.n_joints, CHAIN_JOINT)  # a small crowd on one thread
    prepared(dls_lanes.free_solver(L, lane_plan.capacity(rig.n_joints)))(
        *head, lane_plan.streams(crowd.n, L, serial), req.max_iterations, req.tolerance, cfg["damping"],
        cfg["length"], *bundles.result(crowd), serial,
    )


def _loaded(crowd, key) -> tuple:
    """(cfg's damping and length, uploaded arrays) when the crowd's DLS scratch holds the settings of `key`, else
    (None, None)."""
    held = crowd.__dict__.get("_dls_loaded")
    return held[1:] if held is not None and held[0] == key else (None, None)


def _store(crowd, key, cfg: dict, small: dict) -> None:
    """Record what the DLS scratch now holds (one set at a time: each solver variant uploads its own) and the two
    settings the launch takes besides (the rest of cfg is not kept)."""
    crowd.__dict__["_dls_loaded"] = (key, dict(damping=cfg["damping"], length=cfg["length"]), small)
