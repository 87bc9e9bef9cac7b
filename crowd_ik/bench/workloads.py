"""The bench's workloads and how a cell is timed: chain16 and humanoid solves, the game workload (every
character moving, plus the bullet step) and the game as played (a shipped scene in the World)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from crowd_ik.bench.options import (
    FRAME_MS,
    GAME_POOL,
    GAME_SCENE,
    GAME_SCENE_WARMUP,
    GAME_WARMUP_FRAMES,
    MAX_ITERATIONS,
    RIGS,
    SEED,
    SPACING,
)
from crowd_ik.bench.options import rig as _rig
from crowd_ik.solvers.registry import FABRIK


@dataclass(frozen=True)
class Workload:
    """The first m characters of the N-character workload of one rig (float32, world metres)."""

    name: str
    rig: object
    roots: np.ndarray    # (m, 3) root positions on the N-character grid
    angles: np.ndarray   # (m, DOF) start pose, radians
    targets: np.ndarray  # (m, E, 3) world targets
    tolerance: float
    max_iterations: int = MAX_ITERATIONS

    @property
    def n(self) -> int:
        return int(self.roots.shape[0])

    def rotations(self) -> np.ndarray:
        """(m, J, 4) local rotations of the start pose (the NumPy twins' input)."""
        from crowd_ik.geometry.fk import angles_to_rotations

        return angles_to_rotations(self.rig, self.angles.astype(np.float64))


def _unit_ball(rng_dir, rng_rad, shape: tuple, radius: float) -> np.ndarray:
    """Points uniform in a ball of `radius`: shape + (3,). Each stream is consumed in order, so prefixes agree."""
    d = rng_dir.standard_normal(shape + (3,))
    d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    r = radius * np.cbrt(rng_rad.random(shape))
    return d * r[..., None]


def make_workload(name: str, n: int, m: int | None = None) -> Workload:
    """The seeded workload `name` of n characters, or its first m characters (identical to theirs)."""
    from crowd_ik.crowd import grid_positions
    from crowd_ik.geometry.fk import angles_to_rotations, forward_kinematics

    if name not in RIGS:
        raise ValueError(f"rig: expected one of {', '.join(RIGS)} (got {name!r})")
    m = n if m is None else min(int(m), n)
    rig = _rig(name)
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence([SEED, RIGS.index(name)]).spawn(3)]
    rng_dir, rng_rad, rng_pose = streams
    roots = grid_positions(n, SPACING, 3)[:m]
    E = rig.n_effectors
    if name == "chain16":
        reach = float(rig.reach[0])
        angles = np.zeros((m, rig.n_dof), np.float32)
        targets = roots[:, None, :] + _unit_ball(rng_dir, rng_rad, (m, E), 0.9 * reach)
        tolerance = 1e-3 * reach
    else:
        lo, hi = rig.angle_limits()
        lo, hi = np.clip(lo, -np.pi, np.pi), np.clip(hi, -np.pi, np.pi)
        angles = (lo + (hi - lo) * rng_pose.random((m, rig.n_dof))).astype(np.float32)
        pos, _ = forward_kinematics(rig, roots.astype(np.float64), np.zeros(m),
                                    angles_to_rotations(rig, angles.astype(np.float64)))
        targets = pos[:, rig.arrays["eff_joint"]] + _unit_ball(rng_dir, rng_rad, (m, E), 0.3)
        tolerance = 5e-3
    return Workload(name, rig, roots.astype(np.float32), angles, np.ascontiguousarray(targets, np.float32),
                    float(tolerance))


# ------------------------------------------------------------------------------------------------ statistics

def _outcome(error: np.ndarray, iterations: np.ndarray, converged: np.ndarray, reachable: np.ndarray) -> dict:
    n_reach = int(np.count_nonzero(reachable))
    return dict(
        success_rate=float(np.mean(converged)),
        reachable_rate=float(np.mean(reachable)),
        success_rate_reachable=float(np.count_nonzero(converged & reachable) / n_reach) if n_reach else 0.0,
        mean_error=float(np.mean(error)),
        median_error=float(np.median(error)),
        max_error=float(np.max(error)),
        mean_iterations=float(np.mean(iterations)),
    )


def _reachable(wl: Workload) -> np.ndarray:
    """(m,) bool: every target within its chain's length of the root joint (Crowd's UNREACHABLE test, negated;
    the workloads' characters stand unturned, and the humanoid's root joint, its pelvis, is ~1 m above its root)."""
    return ~np.any(wl.rig.beyond_reach(wl.targets, wl.rig.root_joints(wl.roots.astype(np.float64), np.zeros(wl.n))),
                   axis=1)


def _ms_stats(values_ms) -> dict:
    v = np.asarray(values_ms, np.float64)
    return dict(mean=float(v.mean()), median=float(np.median(v)), p95=float(np.percentile(v, 95)), max=float(v.max()))


# ------------------------------------------------------------------------------------------------ Taichi side (child)

def _ndarray_bytes(obj, seen: set) -> int:
    """Bytes held by the ti.ndarrays and NumPy arrays in `obj` (an array, or a dict / list of them) that are not in
    `seen` (ids of the arrays counted so far, a NumPy view by its base's: a solver's kept plan holds the scratch
    arrays the crowd holds)."""
    from taichi.lang._ndarray import Ndarray
    from taichi.lang.util import to_numpy_type

    if isinstance(obj, (np.ndarray, Ndarray)):
        owner = obj
        while isinstance(owner, np.ndarray) and isinstance(owner.base, np.ndarray):
            owner = owner.base
        if id(owner) in seen:
            return 0
        seen.add(id(owner))
        if isinstance(owner, np.ndarray):
            return int(owner.nbytes)
        elem = int(np.prod(getattr(owner, "element_shape", ()) or (1,)))
        return int(np.prod(owner.shape)) * elem * np.dtype(to_numpy_type(owner.dtype)).itemsize
    if isinstance(obj, dict):
        return sum(_ndarray_bytes(v, seen) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(_ndarray_bytes(v, seen) for v in obj)
    return 0


def crowd_bytes(crowd) -> int:
    """Bytes of per-character state a Crowd holds now, Taichi and host arrays (solver scratch included, the shared
    rig not), each array once."""
    seen: set = set()
    return sum(_ndarray_bytes(v, seen) for k, v in vars(crowd).items() if k != "rig_arrays")


def _solve_timed(crowd, wl: Workload, solver: str, max_iterations: int | None = None):
    crowd.set_angles(wl.angles)
    t0 = time.perf_counter()
    report = crowd.solve(wl.targets, method=solver, max_iterations=max_iterations or wl.max_iterations,
                         tolerance=wl.tolerance)
    return time.perf_counter() - t0, report


def compile_time(wl: Workload, solver: str) -> dict:
    """First call (compile or offline-cache load + solve) and a steady call on the same small crowd."""
    from crowd_ik.crowd import Crowd

    crowd = Crowd(wl.rig, wl.n, spacing=SPACING)
    first, _ = _solve_timed(crowd, wl, solver)
    steady, _ = _solve_timed(crowd, wl, solver)
    return dict(n=wl.n, first_call_s=first, steady_s=steady, compile_s=max(first - steady, 0.0))


def time_cell(wl: Workload, solver: str, repeats: int, between=None) -> dict:
    """Best of `repeats` timed solves of the whole workload on a fresh Crowd, with its outcome and memory;
    between() (if given) runs after each timed solve, untimed (the numba peers interleaved: peers.Interleaved)."""
    from crowd_ik.crowd import Crowd, Status

    crowd = Crowd(wl.rig, wl.n, spacing=SPACING)
    _solve_timed(crowd, wl, solver, max_iterations=1)  # allocates the solver's scratch
    times, best = [], None
    for _ in range(repeats):
        dt, report = _solve_timed(crowd, wl, solver)
        if best is None or dt < min(times):
            best = report
        times.append(dt)
        if between is not None:
            between()
    t = min(times)
    converged = best.status == Status.CONVERGED
    reachable = best.status != Status.UNREACHABLE
    memory = crowd_bytes(crowd)
    rec = dict(time_s=t, times_s=times, repeats=repeats, solves_per_s=wl.n / t,
               chain_iterations_per_s=float(np.sum(best.iterations, dtype=np.int64)) / t,
               **_outcome(best.error, best.iterations, converged, reachable),
               status_counts={s.name.lower(): int(np.count_nonzero(best.status == s)) for s in Status},
               bytes_per_character=int(Crowd.bytes_per_character(wl.rig)),
               measured_bytes_per_character=memory / wl.n, memory_bytes=memory)
    del crowd
    return rec


def _smooth_offsets(n: int, E: int, seed: int):
    """A function t -> (n, E, 3) metres: per axis a sine of 1..5 cm amplitude at 0.5..2 Hz (mm..cm per frame)."""
    rng = np.random.default_rng(seed)
    amp = rng.uniform(0.01, 0.05, (n, E, 3)).astype(np.float32)
    freq = rng.uniform(0.5, 2.0, (n, E, 3)).astype(np.float32)
    phase = rng.uniform(0.0, 2 * np.pi, (n, E, 3)).astype(np.float32)

    def at(t: float) -> np.ndarray:
        return amp * (np.sin(2 * np.pi * freq * t + phase) - np.sin(phase))

    return at


def game_workload(n: int) -> Workload:
    """As in the game: humanoids standing in natural poses (a quarter of their joint ranges around rest), their
    effectors' targets where the pose puts them (reachable); the cold solve starts from rest."""
    from crowd_ik.crowd import grid_positions
    from crowd_ik.geometry.fk import angles_to_rotations, forward_kinematics

    rig = _rig("humanoid")
    rng = np.random.default_rng(np.random.SeedSequence([SEED, 99]))
    lo, hi = rig.angle_limits()
    pose = (0.25 * (lo + (hi - lo) * rng.random((n, rig.n_dof)))).astype(np.float64)
    roots = grid_positions(n, SPACING, 3)
    pos, _ = forward_kinematics(rig, roots.astype(np.float64), np.zeros(n), angles_to_rotations(rig, pose))
    targets = np.ascontiguousarray(pos[:, rig.arrays["eff_joint"]], np.float32)
    return Workload("humanoid", rig, roots.astype(np.float32), np.zeros((n, rig.n_dof), np.float32), targets, 5e-3)


def game_frames(n: int, frames: int, pool_size: int = GAME_POOL) -> dict:
    """The game workload: a cold solve, then warm-started 4-iteration FABRIK frames plus the bullet step."""
    from crowd_ik.crowd import Crowd, Status
    from crowd_ik.game.bullets import LIMB_CELL
    from crowd_ik.game.pool import BulletPool

    wl = game_workload(n)
    rig = wl.rig
    J, E = rig.n_joints, rig.n_effectors
    crowd = Crowd(rig, n, spacing=SPACING)
    # compile (or load) both paths before anything is timed: the warm frames' plain solve and the cold solve's
    # windows, on the full crowd (the windows' row kernels take a serial or a parallel variant by size);
    # _solve_timed starts the timed solve from the workload's pose again
    for iterations in (2, wl.max_iterations):
        _solve_timed(crowd, wl, FABRIK, max_iterations=iterations)
    cold_s, cold = _solve_timed(crowd, wl, FABRIK)
    cold_out = _outcome(cold.error, cold.iterations, cold.status == Status.CONVERGED, cold.status != Status.UNREACHABLE)

    from crowd_ik.game.body import Body
    from crowd_ik.game.limbs import Limbs
    from crowd_ik.game.solving import StepSolve

    B = J - 1  # bones: bone k joins joint parent[k + 1] to joint k + 1
    # the World's limbs: capsules, host joints and per-character boxes in one launch, the capsules left in
    # ndarrays for the pool, which skips characters no bullet can reach; both sets hold the cold pose
    limbs = Limbs(Body(rig), n, crowd)
    alive = np.ones(n, np.int32)
    lo, hi = wl.roots.min(0) - 3.0, wl.roots.max(0) + 3.0
    pool = BulletPool(pool_size, radius=0.03, bounds=(lo[0], lo[2], hi[0], hi[2]), cell_size=1.0,
                      capsule_capacity=n * B, limb_cell_size=LIMB_CELL)  # the game's limb grid
    rng = np.random.default_rng(SEED + 1)
    origins = np.stack([rng.uniform(lo[0], hi[0], pool_size), rng.uniform(0.3, 1.8, pool_size),
                        rng.uniform(lo[2], hi[2], pool_size)], axis=1).astype(np.float32)
    heading = rng.uniform(0, 2 * np.pi, pool_size)
    velocities = (25.0 * np.stack([np.cos(heading), np.zeros(pool_size), np.sin(heading)], axis=1)).astype(np.float32)

    # the bullets' state exported to host arrays each step, whose free slots the next spawn takes (as
    # game.bullets.Bullets does: the pool need not read its flags back)
    exported = (np.zeros((pool_size, 3), np.float32), np.zeros((pool_size, 3), np.float32),
                np.zeros(pool_size, np.int32))
    offsets = _smooth_offsets(n, E, SEED + 2)
    # the game's solve (game/solving.py): the request checked once, then refilled in place each frame
    step_solve = StepSolve(crowd, SimpleNamespace(method=FABRIK, iterations=4, tolerance=wl.tolerance), None)
    weights = np.ones((n, E), np.float32)
    feet = np.array([name.startswith("foot") for name in rig.effector_names])
    solve_ms, caps_ms, bullet_ms, iters, conv, err, live, subs, shares, motion, hits = [], [], [], [], [], [], [], [], [], [], 0
    for f in range(GAME_WARMUP_FRAMES + frames):
        targets = wl.targets + np.where(feet[None, :, None], 0.0, offsets((f + 1) / 60.0))  # feet planted
        t0 = time.perf_counter()
        rep = step_solve(targets, weights)
        t1 = time.perf_counter()
        limbs.begin_step()
        limbs.update()
        t2 = time.perf_counter()
        pool.spawn(origins, velocities, free=np.flatnonzero(exported[2] == 0))
        step_hits = pool.advance(1 / 60.0, 9.81, 0.0, 3.0, *limbs.current, limbs.radius, limbs.owner, alive, n,
                                 prev_a=limbs.previous[0], prev_b=limbs.previous[1], owner_boxes=limbs.owner_box,
                                 owner_stride=B, export_to=exported)
        t3 = time.perf_counter()
        # how far the limbs moved this frame: per character its largest joint step, metres
        step = np.linalg.norm(limbs.joints - limbs.joints_prev, axis=2).max(axis=1)
        if f < GAME_WARMUP_FRAMES:
            continue
        motion.append((float(np.median(step)), float(step.max())))
        solve_ms.append(1e3 * (t1 - t0))
        caps_ms.append(1e3 * (t2 - t1))
        bullet_ms.append(1e3 * (t3 - t2))
        iters.append(float(rep.iterations.mean()))
        conv.append(float(np.mean(rep.status == Status.CONVERGED)))
        err.append(float(rep.error.mean()))
        live.append(int(np.count_nonzero(exported[2])))
        hits += len(step_hits.chars)
        subs.append(pool.last_substeps)
        shares.append(pool.last_substepped / max(1, np.count_nonzero(pool.bullet_substeps)))  # of the bullets flown
    frame_ms = np.asarray(solve_ms) + np.asarray(caps_ms) + np.asarray(bullet_ms)
    frame = _ms_stats(frame_ms)
    return dict(
        n=n, frames=frames, warmup_frames=GAME_WARMUP_FRAMES, pool_size=pool_size, capsules=n * B,
        cold=dict(ms=1e3 * cold_s, max_iterations=MAX_ITERATIONS, **cold_out),
        warm=dict(max_iterations=4, solve_ms=_ms_stats(solve_ms), mean_iterations=float(np.mean(iters)),
                  success_rate=float(np.mean(conv)), mean_error=float(np.mean(err))),
        capsules_ms=_ms_stats(caps_ms), bullets_ms=_ms_stats(bullet_ms), frame_ms=frame,
        bullets_alive=float(np.mean(live)), hits=int(hits), mean_substeps=float(np.mean(subs)),
        max_substeps=int(max(subs)), substepped_share=float(np.mean(shares)),
        limb_step_m=float(np.median([m[0] for m in motion])), limb_step_max_m=float(max(m[1] for m in motion)),
        budget_ms=FRAME_MS, fits=bool(frame["p95"] <= FRAME_MS),
    )


def best_game_frames(n: int, frames: int, repeats: int, pool_size: int = GAME_POOL) -> dict:
    """game_frames run `repeats` times from the same start (the same seeds: the same work and results each time),
    the run with the lowest median frame kept, as every solve cell keeps its best repeat; `runs` lists each run's
    frame, solve, capsule and bullet medians and p95s in order, so a slower phase of the machine stays visible."""
    runs = [game_frames(n, frames, pool_size) for _ in range(max(1, int(repeats)))]
    best = min(runs, key=lambda g: g["frame_ms"]["median"])
    keys = ("frame_ms", "capsules_ms", "bullets_ms")
    return dict(best, runs=[dict({k: {q: g[k][q] for q in ("median", "p95")} for k in keys},
                                 solve_ms={q: g["warm"]["solve_ms"][q] for q in ("median", "p95")}) for g in runs])


def game_scene(steps: int, name: str = GAME_SCENE, warmup: int = GAME_SCENE_WARMUP) -> dict:
    """The shipped `name` scene (stress_10k: 10,000 humanoids) as the game plays it, FABRIK capped at 4 iterations:
    after `warmup` world steps, per 60 Hz world step (World.last_step_ms) the characters' IK (dodge targets,
    solve, limb capsules) and the bullets' step with its hits; only threatened characters move."""
    from crowd_ik.game.world import World
    from crowd_ik.scene import load_scene, scene_with

    scene = scene_with(load_scene(name), **{"solver.method": FABRIK, "solver.iterations": 4})
    world = World(scene, hud_timings=False)
    for _ in range(warmup):
        world.step_world()
    hits0 = world.hits
    ik, bullets, total, solving, iters, alive = [], [], [], [], [], []
    for _ in range(steps):
        world.step_world()
        ms = world.last_step_ms
        ik.append(ms["ik"])
        bullets.append(ms["bullets"])
        total.append(ms["total"])
        its = world.characters.last_iterations
        solving.append(float(np.mean(its > 0)))
        iters.append(float(its.mean()))
        alive.append(world.stats["bullets"])
    frame = _ms_stats(np.asarray(ik) + np.asarray(bullets))
    return dict(scene=name, n=int(scene.characters.count), steps=steps, warmup_steps=warmup,
                max_iterations=4, ik_ms=_ms_stats(ik), bullets_ms=_ms_stats(bullets), frame_ms=frame,
                step_ms=_ms_stats(total), solving=float(np.mean(solving)), mean_iterations=float(np.mean(iters)),
                bullets_alive=float(np.mean(alive)), hits=int(world.hits - hits0), budget_ms=FRAME_MS,
                fits=bool(frame["p95"] <= FRAME_MS))
