"""`crowd-ik bench`: IK throughput against character count, solver and backend, beside a NumPy baseline.

The parent process (:func:`run`) checks the options and every output path first, then runs one child
process per arch (``python -m crowd_ik.bench.run --child SPEC.json RESULT.json``: Taichi is initialised
once per process, so a CPU and a CUDA run cannot share one), times the vectorised NumPy twins of
``crowd_ik/reference/`` on the same workloads, prints a table, and writes ``--json`` / ``--plot``.

Workloads (fixed seeds; the first m characters of a workload of N are the workload of m, so a
NumPy run on a subset sees exactly the same problems as the first m Taichi characters):
- ``chain16``: ``Rig.chain(16, 0.1, dim=3)``, targets uniform in the ball of 0.9 x reach around the
  root, tolerance 1e-3 x reach, at most 100 iterations, every repeat starting straight;
- ``humanoid``: ``Rig.humanoid()`` from a random pose inside its box limits, its 5 effectors moved by
  random offsets of up to 0.3 m, tolerance 5 mm, at most 100 iterations, every repeat from that pose.

Timing: each cell is a fresh Crowd; one solve with max_iterations=1 first (allocates and touches the
solver's scratch), then the best of ``repeats`` solves, each timed from the call to the return of
``Crowd.solve`` (upload of the targets and download of the report included). Compile time is taken
apart, per (rig, solver), as the first call minus a steady call on a small crowd (the offline kernel
cache is on, so after the first run this is mostly cache loading). The NumPy baseline gets a time
budget per cell: it starts on min(N, 100) characters and grows the subset while `repeats` runs still
fit in the budget; solves/s is then the subset size over its best time (``numpy_n`` says which).

The game workload (``game_workload``): a crowd of humanoids (10,000 by default) standing in natural
poses, as in the game: their targets are where those poses put the effectors (reachable), the cold
solve goes there from rest, then frames in which the head and hand targets follow a small smooth
offset while the feet stay planted, each solved with FABRIK warm-started
from the previous frame (at most 4 iterations), plus the bullet step of a full 4096-bullet pool
against the crowd's limb capsules; the frame time is compared with one 60 Hz frame. Every character's
targets move every frame there: the worst case. The full run also times the game as played
(``game_scene``): the shipped stress_10k scene (10,000 humanoids, 16 shooters) in crowd_ik.game.world.World,
FABRIK capped at 4 iterations, per 60 Hz world step the characters' IK and the bullets' step, after
the first bullets have reached the crowd; there only the threatened characters move.

Exit codes (as crowd_ik.commands.cli): 2 for bad options, an existing output without --force, an unreadable
--compare file, and for ``--arch cuda`` on a machine without a CUDA GPU (refused before anything
runs, as bad input for this machine); 1 when a child process fails.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crowd_ik.solvers.registry import DLS, FABRIK, METHODS

RIGS = ("chain16", "humanoid")
SOLVERS = METHODS
ARCHES = ("cpu", "cuda")
PEERS = ("numba",)  # compiled peers the bench can time beside crowd_ik (crowd_ik/bench/peers.py)
DEFAULT_CHARS = (100, 1000, 10000, 100000)
CUDA_EXTRA_CHARS = 1_000_000  # added to chain16 on a CUDA arch when --chars is not given
SEED = 20240601
SPACING = 1.0  # metres between roots on the crowd's grid
MAX_ITERATIONS = 100
BASELINE_PROBE = 100  # first NumPy subset size (characters)
FRAME_MS = 1000.0 / 60.0
GAME_POOL = 4096
GAME_WARMUP_FRAMES = 3
MEMORY_LIMIT = 16 * 2**30  # the Crowd's own refusal limit, checked here before any child starts

GAME_SCENE = "stress_10k"  # the shipped scene timed as the game plays it
GAME_SCENE_WARMUP = 180  # world steps before timing it: the shooters' first bullets reach the crowd after ~2.5 s

FULL = dict(chars=DEFAULT_CHARS, solvers=SOLVERS, rigs=RIGS, repeats=3, budget=10.0, game_chars=10000, game_frames=60,
            scene_steps=120)
QUICK = dict(chars=(100, 1000), solvers=(FABRIK, DLS), rigs=("chain16",), repeats=1, budget=1.0, game_chars=256,
             game_frames=5, scene_steps=0)


# ------------------------------------------------------------------------------------------------ options

@dataclass(frozen=True)
class Options:
    """Resolved benchmark settings (explicit flags over the --quick or full defaults)."""

    chars: tuple[int, ...]
    chars_given: bool
    solvers: tuple[str, ...]
    rigs: tuple[str, ...]
    arches: tuple[str, ...]
    threads: int | None
    repeats: int
    budget: float
    game_chars: int
    game_frames: int
    quick: bool
    scene_steps: int = 0
    peers: tuple[str, ...] = ()


def _split(value: str, flag: str) -> list[str]:
    items = [v.strip() for v in str(value).split(",")]
    if not value or not all(items):
        raise ValueError(f"{flag}: expected a comma-separated list (got {value!r})")
    return items


def _choices(value: str | None, flag: str, allowed: tuple[str, ...], default: tuple[str, ...]) -> tuple[str, ...]:
    if value is None:
        return default
    items = [v.lower() for v in _split(value, flag)]
    for v in items:
        if v not in allowed:
            raise ValueError(f"{flag}: expected some of {','.join(allowed)} (got {v!r})")
    return tuple(dict.fromkeys(items))


def parse_chars(value: str) -> tuple[int, ...]:
    """'100,1000' -> (100, 1000): distinct positive integers, ascending."""
    out = []
    for item in _split(value, "--chars"):
        try:
            n = int(item)
        except ValueError:
            raise ValueError(f"--chars: expected comma-separated positive integers (got {item!r})") from None
        if n < 1:
            raise ValueError(f"--chars: expected positive integers (got {n})")
        out.append(n)
    return tuple(sorted(set(out)))


def _rig(name: str):
    from crowd_ik.rig import Rig

    return Rig.chain(16, 0.1, dim=3) if name == "chain16" else Rig.humanoid()


def resolve_options(args) -> Options:
    """Options from the argparse namespace; ValueError (exit 2) naming the flag and the value."""
    base = QUICK if args.quick else FULL
    chars = parse_chars(args.chars) if args.chars is not None else base["chars"]
    solvers = _choices(args.solver, "--solver", SOLVERS, base["solvers"])
    rigs = _choices(args.rig, "--rig", RIGS, base["rigs"])
    arches = _choices(args.arch, "--arch", ARCHES, ()) if args.arch is not None else ()
    threads = args.threads
    if threads is not None and threads < 1:
        raise ValueError(f"--threads: expected a positive integer (got {threads})")
    repeats = base["repeats"] if getattr(args, "repeats", None) is None else args.repeats
    if repeats < 1:
        raise ValueError(f"--repeats: expected a positive integer (got {repeats})")
    budget = base["budget"] if getattr(args, "baseline_budget", None) is None else args.baseline_budget
    if not (math.isfinite(budget) and budget >= 0):
        raise ValueError(f"--baseline-budget: expected seconds >= 0 (got {budget})")
    game_chars = base["game_chars"] if getattr(args, "game_chars", None) is None else args.game_chars
    if game_chars < 0:
        raise ValueError(f"--game-chars: expected an integer >= 0 (got {game_chars})")
    for rig_name in rigs:
        per = _bytes_estimate(rig_name)
        worst = max(chars) * per
        if worst > MEMORY_LIMIT:
            raise ValueError(f"--chars: {max(chars)} characters of {rig_name} need about {worst / 2**30:.1f} GiB "
                             f"(limit {MEMORY_LIMIT / 2**30:.0f} GiB)")
    peers = _choices(args.peers, "--peers", PEERS, ()) if getattr(args, "peers", None) is not None else ()
    if peers:
        from crowd_ik.bench import peers as bench_peers
        if not bench_peers.available():
            raise ValueError("--peers: numba is not installed (pip install -e '.[peers]')")
    return Options(chars, args.chars is not None, solvers, rigs, arches, threads, repeats, float(budget),
                   int(game_chars), base["game_frames"], bool(args.quick), base["scene_steps"] if game_chars else 0,
                   peers)


def _bytes_estimate(rig_name: str) -> int:
    from crowd_ik.crowd import Crowd

    return Crowd.bytes_per_character(_rig(rig_name))


def cuda_available() -> bool:
    """Whether Taichi's CUDA backend can start here (the same probe as crowd_ik.runtime).

    The driver is asked first, through ctypes: without a GPU, Taichi is not even imported, so neither
    its banner nor its "libcuda.so lib not found" warning gets in the way of the one-line refusal.
    """
    from crowd_ik.runtime import _cuda_available, _probe_cuda_device

    if not _probe_cuda_device():
        return False
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    import taichi as ti

    return _cuda_available(ti)


def resolve_arches(requested: tuple[str, ...]) -> tuple[str, ...]:
    """The arches to run: the requested ones (cuda refused without a GPU), else cpu plus cuda when present."""
    has_cuda = cuda_available()
    if not requested:
        return ("cpu", "cuda") if has_cuda else ("cpu",)
    if "cuda" in requested and not has_cuda:
        raise ValueError("--arch cuda: no CUDA GPU is available to Taichi on this machine")
    return requested


def cells_for(opts: Options, arch: str) -> list[tuple[str, str, int]]:
    """(rig, solver, N) cells of one arch, in run order; a CUDA default sweep adds 1,000,000 chain16 characters."""
    out = []
    for rig_name in opts.rigs:
        chars = list(opts.chars)
        if arch == "cuda" and not opts.chars_given and rig_name == "chain16":
            chars.append(CUDA_EXTRA_CHARS)
        for solver in opts.solvers:
            out += [(rig_name, solver, n) for n in chars]
    return out


# ------------------------------------------------------------------------------------------------ workloads

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
    """(m,) bool: every target within its chain's length of the root (Crowd's UNREACHABLE test, negated)."""
    far = np.linalg.norm(wl.targets - wl.roots[:, None, :], axis=-1) > wl.rig.reach[None, :] * (1 + 1e-6) + 1e-7
    return ~np.any(far, axis=1)


def _ms_stats(values_ms) -> dict:
    v = np.asarray(values_ms, np.float64)
    return dict(mean=float(v.mean()), median=float(np.median(v)), p95=float(np.percentile(v, 95)), max=float(v.max()))


# ------------------------------------------------------------------------------------------------ Taichi side (child)

def _ndarray_bytes(obj) -> int:
    """Bytes held by the ti.ndarrays and NumPy arrays in `obj` (an array, or a dict / list of them)."""
    from taichi.lang._ndarray import Ndarray
    from taichi.lang.util import to_numpy_type

    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if isinstance(obj, Ndarray):
        elem = int(np.prod(getattr(obj, "element_shape", ()) or (1,)))
        return int(np.prod(obj.shape)) * elem * np.dtype(to_numpy_type(obj.dtype)).itemsize
    if isinstance(obj, dict):
        return sum(_ndarray_bytes(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(_ndarray_bytes(v) for v in obj)
    return 0


def crowd_bytes(crowd) -> int:
    """Bytes of per-character state a Crowd holds now, Taichi and host arrays (solver scratch included, the shared
    rig not)."""
    return sum(_ndarray_bytes(v) for k, v in vars(crowd).items() if k != "rig_arrays")


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


def time_cell(wl: Workload, solver: str, repeats: int) -> dict:
    """Best of `repeats` timed solves of the whole workload on a fresh Crowd, with its outcome and memory."""
    from crowd_ik.crowd import Crowd, Status

    crowd = Crowd(wl.rig, wl.n, spacing=SPACING)
    _solve_timed(crowd, wl, solver, max_iterations=1)  # allocates the solver's scratch
    times, best = [], None
    for _ in range(repeats):
        dt, report = _solve_timed(crowd, wl, solver)
        if best is None or dt < min(times):
            best = report
        times.append(dt)
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
    from crowd_ik.game.pool import BulletPool
    from crowd_ik.crowd import Crowd, Status

    wl = game_workload(n)
    rig = wl.rig
    J, E = rig.n_joints, rig.n_effectors
    Crowd(rig, min(n, 16), spacing=SPACING).solve(wl.targets[: min(n, 16)], FABRIK, 2, wl.tolerance)  # compile
    crowd = Crowd(rig, n, spacing=SPACING)
    cold_s, cold = _solve_timed(crowd, wl, FABRIK)
    cold_out = _outcome(cold.error, cold.iterations, cold.status == Status.CONVERGED, cold.status != Status.UNREACHABLE)

    from crowd_ik.game.body import Body
    from crowd_ik.game.limbs import Limbs

    B = J - 1  # bones: bone k joins joint parent[k + 1] to joint k + 1
    # the World's limbs: capsules, host joints and per-character boxes in one launch, the capsules left in
    # ndarrays for the pool, which skips characters no bullet can reach; both sets hold the cold pose
    limbs = Limbs(Body(rig), n, crowd)
    alive = np.ones(n, np.int32)
    lo, hi = wl.roots.min(0) - 3.0, wl.roots.max(0) + 3.0
    pool = BulletPool(pool_size, radius=0.03, bounds=(lo[0], lo[2], hi[0], hi[2]), cell_size=1.0,
                      capsule_capacity=n * B)
    rng = np.random.default_rng(SEED + 1)
    origins = np.stack([rng.uniform(lo[0], hi[0], pool_size), rng.uniform(0.3, 1.8, pool_size),
                        rng.uniform(lo[2], hi[2], pool_size)], axis=1).astype(np.float32)
    heading = rng.uniform(0, 2 * np.pi, pool_size)
    velocities = (25.0 * np.stack([np.cos(heading), np.zeros(pool_size), np.sin(heading)], axis=1)).astype(np.float32)

    offsets = _smooth_offsets(n, E, SEED + 2)
    feet = np.array([name.startswith("foot") for name in rig.effector_names])
    solve_ms, caps_ms, bullet_ms, iters, conv, err, live, subs, motion, hits = [], [], [], [], [], [], [], [], [], 0
    for f in range(GAME_WARMUP_FRAMES + frames):
        targets = wl.targets + np.where(feet[None, :, None], 0.0, offsets((f + 1) / 60.0))  # feet planted
        t0 = time.perf_counter()
        rep = crowd.solve(targets, method=FABRIK, max_iterations=4, tolerance=wl.tolerance)
        t1 = time.perf_counter()
        limbs.begin_step()
        limbs.update()
        t2 = time.perf_counter()
        pool.spawn(origins, velocities)
        step_hits = pool.advance(1 / 60.0, 9.81, 0.0, 3.0, *limbs.current, limbs.radius, limbs.owner, alive, n,
                                 prev_a=limbs.previous[0], prev_b=limbs.previous[1], owner_boxes=limbs.owner_box,
                                 owner_stride=B)
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
        live.append(pool.count_alive())
        hits += len(step_hits.chars)
        subs.append(pool.last_substeps)
    frame_ms = np.asarray(solve_ms) + np.asarray(caps_ms) + np.asarray(bullet_ms)
    frame = _ms_stats(frame_ms)
    return dict(
        n=n, frames=frames, warmup_frames=GAME_WARMUP_FRAMES, pool_size=pool_size, capsules=n * B,
        cold=dict(ms=1e3 * cold_s, max_iterations=MAX_ITERATIONS, **cold_out),
        warm=dict(max_iterations=4, solve_ms=_ms_stats(solve_ms), mean_iterations=float(np.mean(iters)),
                  success_rate=float(np.mean(conv)), mean_error=float(np.mean(err))),
        capsules_ms=_ms_stats(caps_ms), bullets_ms=_ms_stats(bullet_ms), frame_ms=frame,
        bullets_alive=float(np.mean(live)), hits=int(hits), mean_substeps=float(np.mean(subs)),
        max_substeps=int(max(subs)),
        limb_step_m=float(np.median([m[0] for m in motion])), limb_step_max_m=float(max(m[1] for m in motion)),
        budget_ms=FRAME_MS, fits=bool(frame["p95"] <= FRAME_MS),
    )


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
        rep = world.characters.last_report
        solving.append(float(np.mean(rep.iterations > 0)))
        iters.append(float(rep.iterations.mean()))
        alive.append(world.stats["bullets"])
    frame = _ms_stats(np.asarray(ik) + np.asarray(bullets))
    return dict(scene=name, n=int(scene.characters.count), steps=steps, warmup_steps=warmup,
                max_iterations=4, ik_ms=_ms_stats(ik), bullets_ms=_ms_stats(bullets), frame_ms=frame,
                step_ms=_ms_stats(total), solving=float(np.mean(solving)), mean_iterations=float(np.mean(iters)),
                bullets_alive=float(np.mean(alive)), hits=int(world.hits - hits0), budget_ms=FRAME_MS,
                fits=bool(frame["p95"] <= FRAME_MS))


def _gpu_name() -> str | None:
    """The first CUDA device's name, through the driver API (None when it cannot be read)."""
    import ctypes

    try:
        lib = ctypes.CDLL("libcuda.so.1")
        buf = ctypes.create_string_buffer(256)
        dev = ctypes.c_int(0)
        if lib.cuInit(0) or lib.cuDeviceGet(ctypes.byref(dev), 0) or lib.cuDeviceGetName(buf, 256, dev):
            return None
        return buf.value.decode(errors="replace")
    except OSError:
        return None


def child_main(spec_path: str, result_path: str) -> int:
    """Run one arch's cells (and the game) in this process; write the result JSON to result_path."""
    import resource

    from tqdm import tqdm

    from crowd_ik import runtime

    spec = json.loads(Path(spec_path).read_text())
    load_start = list(os.getloadavg())
    arch = runtime.init(spec["arch"], spec["threads"])
    import taichi as ti

    cells = [tuple(c) for c in spec["cells"]]
    total = len(cells) + (1 if spec["game_chars"] else 0)
    records, compile_info = [], {}
    with tqdm(total=total, desc=f"bench {arch}", unit="cell", file=sys.stderr, dynamic_ncols=True) as bar:
        for rig_name, solver, n in cells:
            bar.set_postfix_str(f"{rig_name} {solver} N={n}")
            key = f"{rig_name}/{solver}"
            if key not in compile_info:
                small = min(m for r, s, m in cells if (r, s) == (rig_name, solver))
                compile_info[key] = compile_time(make_workload(rig_name, small), solver)
            rec = dict(arch=arch, rig=rig_name, solver=solver, n=n)
            rec.update(time_cell(make_workload(rig_name, n), solver, spec["repeats"]))
            rec["compile_s"] = compile_info[key]["compile_s"]
            records.append(rec)
            bar.update(1)
        game = None
        if spec["game_chars"]:
            bar.set_postfix_str(f"game N={spec['game_chars']}")
            game = dict(arch=arch, **game_frames(spec["game_chars"], spec["game_frames"]))
            if spec.get("scene_steps"):
                bar.set_postfix_str(f"game scene {GAME_SCENE}")
                game["scene"] = game_scene(spec["scene_steps"])
            bar.update(1)
    from crowd_ik.solvers import settings

    result = dict(arch=arch, requested=spec["arch"], lanes=settings.lanes(),
                  taichi_threads=int(ti.lang.impl.current_cfg().cpu_max_num_threads),
                  gpu=_gpu_name() if arch == "cuda" else None,
                  peak_rss_bytes=int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024,
                  loadavg_start=load_start, loadavg_end=list(os.getloadavg()),
                  compile=compile_info, records=records, game=game)
    Path(result_path).write_text(json.dumps(result))
    return 0


def run_child(arch: str, cells: list, opts: Options) -> dict:
    """Run one arch in a child process (`python -m crowd_ik.bench.run --child`) and return its result."""
    with tempfile.TemporaryDirectory(prefix="crowd-ik-bench-") as tmp:
        spec, result = Path(tmp) / "spec.json", Path(tmp) / "result.json"
        spec.write_text(json.dumps(dict(arch=arch, threads=opts.threads, cells=cells, repeats=opts.repeats,
                                        game_chars=opts.game_chars, game_frames=opts.game_frames,
                                        scene_steps=opts.scene_steps)))
        proc = subprocess.run([sys.executable, "-m", "crowd_ik.bench.run", "--child", str(spec), str(result)])
        if proc.returncode == 130 or proc.returncode == -2:
            raise KeyboardInterrupt
        if proc.returncode != 0 or not result.is_file():
            raise RuntimeError(f"the {arch} benchmark process failed (exit {proc.returncode}); see its messages above")
        return json.loads(result.read_text())


# ------------------------------------------------------------------------------------------------ NumPy baseline

def _reference_solver(solver: str):
    """The NumPy twin of `solver` as f(rig, root_pos, root_yaw, rot, targets, weights, orient, max_iterations,
    tolerance) -> (error, iterations); None when crowd_ik/reference has no twin for it."""
    import importlib

    try:
        module = importlib.import_module(f"crowd_ik.reference.{solver}")
    except ImportError:
        return None
    fn = getattr(module, f"{solver}_solve", None)
    if fn is None:
        return None

    def solve(rig, root_pos, root_yaw, rot, targets, weights, max_iterations, tolerance):
        out = fn(rig, root_pos, root_yaw, rot, targets, weights, None, max_iterations=max_iterations,
                 tolerance=tolerance)
        if isinstance(out, dict):
            return np.asarray(out["error"]), np.asarray(out["iterations"])
        return np.asarray(out[2]), np.asarray(out[3])

    return solve


class Baseline:
    """Times the NumPy twins under a per-cell budget; runs on the same subset are shared between cells.

    :meth:`measure` spends a cell's budget and returns the subset size it settled on; :meth:`summary`
    reports that subset from every run made on it (by this cell or an earlier one), so cells that share
    a subset report the same numbers.
    """

    def __init__(self, repeats: int, budget: float):
        self.repeats, self.budget = repeats, budget
        self._runs: dict[tuple, list] = {}  # (rig, solver, m) -> [(seconds, outcome dict), ...]
        self._inputs: dict[tuple, tuple] = {}

    def _inputs_for(self, rig_name: str, n: int, m: int) -> tuple:
        key = (rig_name, n, m)
        if key not in self._inputs:
            self._inputs.clear()  # one subset at a time: the rotations of 100,000 characters are not small
            wl = make_workload(rig_name, n, m)
            self._inputs[key] = (wl, wl.roots.astype(np.float64), np.zeros(m), wl.rotations(),
                                 wl.targets.astype(np.float64), np.ones((m, wl.rig.n_effectors)), _reachable(wl))
        return self._inputs[key]

    def _run(self, rig_name: str, solver: str, n: int, m: int, k: int) -> float:
        """Seconds of the k-th timed run of the NumPy twin on the first m characters (cached)."""
        runs = self._runs.setdefault((rig_name, solver, m), [])
        while len(runs) <= k:
            wl, roots, yaw, rot, targets, weights, reachable = self._inputs_for(rig_name, n, m)
            fn = _reference_solver(solver)
            t0 = time.perf_counter()
            err, iters = fn(wl.rig, roots, yaw, rot, targets, weights, wl.max_iterations, wl.tolerance)
            runs.append((time.perf_counter() - t0, _outcome(err, iters, err <= wl.tolerance, reachable)))
        return runs[k][0]

    def measure(self, rig_name: str, solver: str, n: int) -> int | None:
        """Spend the budget of cell (rig, solver, n); return the subset size measured (None: no twin, or budget 0)."""
        if _reference_solver(solver) is None or self.budget <= 0:
            return None
        start = time.perf_counter()
        m = min(n, BASELINE_PROBE)
        t = self._run(rig_name, solver, n, m, 0)
        while m < n:  # grow the subset while `repeats` runs of the next size fit in what is left
            left = self.budget - (time.perf_counter() - start)
            grow = min(n, 10 * m, int(left / (self.repeats * t / m)))
            if grow < 1.25 * m:
                break
            m = grow
            t = self._run(rig_name, solver, n, m, 0)
        for k in range(1, self.repeats):
            done = self._runs[(rig_name, solver, m)]
            if len(done) <= k and (time.perf_counter() - start) + min(r[0] for r in done) > self.budget:
                break
            self._run(rig_name, solver, n, m, k)
        return m

    def summary(self, rig_name: str, solver: str, m: int) -> dict:
        """NumPy solves/s on the first m characters (best of every run on them) and that run's outcome."""
        runs = self._runs[(rig_name, solver, m)]
        seconds, out = min(runs, key=lambda r: r[0])
        return dict(numpy_solves_per_s=m / seconds, numpy_n=m, numpy_repeats=len(runs), numpy_time_s=seconds,
                    numpy_success_rate=out["success_rate"], numpy_mean_error=out["mean_error"],
                    numpy_mean_iterations=out["mean_iterations"])


# ------------------------------------------------------------------------------------------------ report

def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _isa() -> str:
    """The widest SIMD instruction set of this CPU, as the lane width is chosen from it."""
    from crowd_ik.solvers.settings import cpu_vector_lanes

    return {16: "avx512", 8: "avx2"}.get(cpu_vector_lanes(), "sse")


def _version(dist: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def command_line(opts: Options, arches: tuple[str, ...]) -> str:
    """The explicit `crowd-ik bench` command that repeats this run's settings (outputs left out)."""
    parts = ["crowd-ik bench", f"--chars {','.join(map(str, opts.chars))}", f"--solver {','.join(opts.solvers)}",
             f"--rig {','.join(opts.rigs)}", f"--arch {','.join(arches)}"]
    if opts.threads is not None:
        parts.append(f"--threads {opts.threads}")
    parts += [f"--repeats {opts.repeats}", f"--baseline-budget {opts.budget:g}", f"--game-chars {opts.game_chars}"]
    if opts.peers:
        parts.append(f"--peers {','.join(opts.peers)}")
    return " ".join(parts)


def _source_state() -> dict | None:
    """The git commit of the code measured, and the files of the package that differ from it (None outside git)."""
    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--", "kernels", "crowd_ik"],
                               capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if head.returncode != 0:
        return None
    changed = [line[3:] for line in dirty.stdout.splitlines() if line.strip()]
    return dict(commit=head.stdout.strip(), uncommitted=changed)


def build_meta(opts: Options, children: list[dict], arches: tuple[str, ...], load_before: list[float]) -> dict:
    from crowd_ik import __version__

    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return dict(
        tool="crowd-ik bench", version=__version__,
        date=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        command=command_line(opts, arches),
        cpu_model=_cpu_model(), cores=os.cpu_count(), usable_cores=usable, threads=opts.threads,
        platform=platform.platform(), python=platform.python_version(), numpy=np.__version__,
        taichi=_version("taichi"), matplotlib=_version("matplotlib"), source=_source_state(),
        loadavg_before=load_before,
        isa=_isa(), peers=list(opts.peers),
        arches=[dict(requested=c["requested"], resolved=c["arch"], lanes=c.get("lanes"),
                     taichi_threads=c["taichi_threads"], gpu=c["gpu"],
                     peak_rss_bytes=c["peak_rss_bytes"], loadavg_start=c["loadavg_start"],
                     loadavg_end=c["loadavg_end"], compile=c["compile"]) for c in children],
        settings=dict(chars=list(opts.chars), solvers=list(opts.solvers), rigs=list(opts.rigs), repeats=opts.repeats,
                      baseline_budget_s=opts.budget, baseline_probe=BASELINE_PROBE, game_chars=opts.game_chars,
                      game_frames=opts.game_frames, game_scene=GAME_SCENE if opts.scene_steps else None,
                      game_scene_steps=opts.scene_steps, quick=opts.quick, seed=SEED, spacing_m=SPACING),
        workloads=dict(
            chain16="Rig.chain(16, 0.1, dim=3); targets uniform in the ball of 0.9 x reach (1.44 m) around the root; "
                    "tolerance 1e-3 x reach (1.6 mm); max_iterations 100; every repeat starts straight",
            humanoid="Rig.humanoid(); random pose uniform in the box limits; 5 effectors moved by offsets uniform in a "
                     "0.3 m ball; tolerance 5 mm; max_iterations 100; every repeat starts from that pose",
        ),
        notes=["time = best repeat, from the call to the return of Crowd.solve (uploads and report included)",
               "compile_s = first call - steady call on a small crowd; the offline kernel cache is on",
               "NumPy baseline: float64 twins in crowd_ik/reference/, one process, timed on numpy_n characters "
               "(the first numpy_n of the same workload) within the per-cell budget",
               "success = status CONVERGED; reachable = no target beyond its chain's length from the root"],
    )


def evaluate_targets(records: list[dict], games: list[dict]) -> list[dict]:
    """The issue's targets, each with its measured value and whether it is met."""
    out = []
    for arch in dict.fromkeys(r["arch"] for r in records):
        rows = [r for r in records if r["arch"] == arch and r["rig"] == "chain16"]
        for solver, goal in ((FABRIK, 20.0), (DLS, 50.0)):
            mine = [r for r in rows if r["solver"] == solver]
            if not mine:
                continue
            top = max(mine, key=lambda r: r["n"])
            sp = top.get("speedup")
            out.append(dict(name=f"chain16 {solver} speed-up vs NumPy", arch=arch, n=top["n"], goal=f">= {goal:g}x",
                            unit="x", value=sp, met=bool(sp is not None and sp >= goal)))
            out.append(dict(name=f"chain16 {solver} success rate", arch=arch, n=top["n"], goal=">= 0.99",
                            unit="fraction", value=top["success_rate"], met=bool(top["success_rate"] >= 0.99)))
        big = [r for r in rows if r["n"] >= 100_000]
        if big:
            worst = max(r["measured_bytes_per_character"] for r in big)
            total = worst * 100_000
            out.append(dict(name="chain16 memory of 100,000 characters (worst solver)", arch=arch, n=100_000,
                            goal="<= 24 GiB", unit="bytes", value=total, met=bool(total <= 24 * 2**30)))
        if arch == "cuda":
            for r in rows:
                if r["n"] >= CUDA_EXTRA_CHARS:
                    full = 1.0 / r["time_s"]
                    out.append(dict(name=f"chain16 {r['solver']} full solves/s of {r['n']:,} characters", arch=arch,
                                    n=r["n"], goal=">= 30", unit="per_s", value=full, met=bool(full >= 30)))
    for g in games:
        name = "game frame, every character's targets moving (warm FABRIK <= 4 it + 4096 bullets), p95 ms"
        out.append(dict(name=name, arch=g["arch"], n=g["n"], goal=f"<= {FRAME_MS:.1f} ms", unit="ms",
                        value=g["frame_ms"]["p95"], met=g["fits"]))
        sc = g.get("scene")
        if sc:
            out.append(dict(name=f"game step as played, {sc['scene']} scene (IK <= 4 it + bullets), p95 ms",
                            arch=g["arch"], n=sc["n"], goal=f"<= {FRAME_MS:.1f} ms", unit="ms",
                            value=sc["frame_ms"]["p95"], met=sc["fits"]))
    return out


def _rate(x: float | None) -> str:
    if x is None:
        return "-"
    for scale, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(x) >= scale:
            return f"{x / scale:.3g}{suffix}"
    return f"{x:.3g}"


def format_table(records: list[dict]) -> str:
    """The results as a fixed-width text table (errors in millimetres)."""
    head = ("arch", "rig", "solver", "N", "solves/s", "iter/s", "success", "err mm mean/med", "iters", "best s",
            "NumPy/s (n)", "speed-up", "B/char")
    rows = []
    for r in records:
        np_rate = "-" if r.get("numpy_solves_per_s") is None else \
            f"{_rate(r['numpy_solves_per_s'])} ({r['numpy_n']})"
        rows.append((r["arch"], r["rig"], r["solver"], f"{r['n']:,}", _rate(r["solves_per_s"]),
                     _rate(r["chain_iterations_per_s"]), f"{100 * r['success_rate']:.1f}%",
                     f"{1e3 * r['mean_error']:.2f}/{1e3 * r['median_error']:.2f}", f"{r['mean_iterations']:.1f}",
                     f"{r['time_s']:.3g}", np_rate, "-" if r.get("speedup") is None else f"{r['speedup']:.1f}x",
                     f"{r['measured_bytes_per_character']:.0f}"))
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
    left = {0, 1, 2}
    fmt = lambda row: "  ".join(str(c).ljust(w) if i in left else str(c).rjust(w)  # noqa: E731
                                for i, (c, w) in enumerate(zip(row, widths)))
    return "\n".join([fmt(head), fmt(["-" * w for w in widths]), *map(fmt, rows)])


def format_game(g: dict) -> str:
    c, w = g["cold"], g["warm"]
    return (f"game {g['arch']}: {g['n']:,} humanoids, {g['frames']} frames, {g['pool_size']} bullets vs "
            f"{g['capsules']:,} limb capsules\n"
            f"  cold solve (FABRIK <= {c['max_iterations']} it): {c['ms']:.1f} ms, success {100 * c['success_rate']:.1f}% "
            f"({100 * c['success_rate_reachable']:.1f}% of reachable), mean {c['mean_iterations']:.1f} it\n"
            f"  warm frame median / p95: solve {w['solve_ms']['median']:.2f} / {w['solve_ms']['p95']:.2f} ms "
            f"(mean {w['mean_iterations']:.2f} it, {100 * w['success_rate']:.1f}% within tolerance) + capsules "
            f"{g['capsules_ms']['median']:.2f} / {g['capsules_ms']['p95']:.2f} ms + bullets "
            f"{g['bullets_ms']['median']:.2f} / {g['bullets_ms']['p95']:.2f} ms = "
            f"{g['frame_ms']['median']:.2f} / {g['frame_ms']['p95']:.2f} ms "
            f"vs {g['budget_ms']:.1f} ms: {'fits' if g['fits'] else 'does NOT fit'} "
            f"\n  ({g['hits']} hits, {g['bullets_alive']:.0f} bullets alive, {g['mean_substeps']:.1f} bullet sub-steps per "
            f"frame on average;\n  joints moved {1e3 * g['limb_step_m']:.1f} mm per frame (median character), "
            f"{1e3 * g['limb_step_max_m']:.0f} mm at most)" + format_scene(g.get("scene")))


def format_scene(sc: dict | None) -> str:
    if not sc:
        return ""
    return (f"\n  as played, {sc['scene']} scene ({sc['n']:,} humanoids, FABRIK <= {sc['max_iterations']} it, "
            f"{sc['steps']} world steps after {sc['warmup_steps']}): median / p95 IK {sc['ik_ms']['median']:.2f} / "
            f"{sc['ik_ms']['p95']:.2f} ms + bullets {sc['bullets_ms']['median']:.2f} / "
            f"{sc['bullets_ms']['p95']:.2f} ms = {sc['frame_ms']['median']:.2f} / {sc['frame_ms']['p95']:.2f} ms "
            f"vs {sc['budget_ms']:.1f} ms: "
            f"{'fits' if sc['fits'] else 'does NOT fit'}\n  ({100 * sc['solving']:.1f}% of characters solving, "
            f"{sc['bullets_alive']:.0f} bullets alive, {sc['hits']} hits; whole world step median "
            f"{sc['step_ms']['median']:.2f} ms)")


def format_targets(targets: list[dict]) -> str:
    lines = []
    for t in targets:
        v = t["value"]
        shown = {
            None: lambda: "n/a (no NumPy baseline)",
            "bytes": lambda: f"{v / 2**30:.3f} GiB",
            "x": lambda: f"{v:.1f}x",
            "fraction": lambda: f"{100 * v:.1f}%",
            "ms": lambda: f"{v:.1f} ms",
            "per_s": lambda: f"{v:.3g}/s",
        }[None if v is None else t["unit"]]()
        lines.append(f"  [{'met' if t['met'] else 'MISSED'}] {t['arch']} {t['name']} (N={t['n']:,}): {shown}, goal {t['goal']}")
    return "targets:\n" + "\n".join(lines) if lines else ""


def load_results(path: str) -> dict:
    """An earlier --json file, checked enough to compare against; ValueError / FileNotFoundError otherwise."""
    p = Path(path).expanduser()
    if not p.is_file():
        raise FileNotFoundError(f"--compare: {path}: no such file")
    try:
        data = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"--compare: {path}: not JSON ({exc})") from None
    need = ("arch", "rig", "solver", "n", "solves_per_s")
    if not (isinstance(data, dict) and isinstance(data.get("records"), list)
            and all(isinstance(r, dict) and all(k in r for k in need) for r in data["records"])):
        raise ValueError(f"--compare: {path}: not a crowd-ik bench JSON (needs records with {', '.join(need)})")
    return data


def compare_lines(old: dict, new: dict, label: str = "OLD") -> list[str]:
    """The change of solves/s (and speed-up, game frame time) from `old` to `new`, one line per row."""
    key = lambda r: (r["arch"], r["rig"], r["solver"], int(r["n"]))  # noqa: E731
    before = {key(r): r for r in old["records"]}
    after = {key(r): r for r in new["records"]}
    meta = old.get("meta", {})
    lines = [f"change against {label} ({meta.get('date', '?')}, {meta.get('cpu_model', '?')}):",
             f"  {'arch':<5} {'rig':<9} {'solver':<7} {'N':>9}  {'old solves/s':>12}  {'new solves/s':>12}  "
             f"{'change':>8}  {'speed-up old -> new':>20}"]
    for k in after:
        if k not in before:
            continue
        o, n = before[k], after[k]
        change = 100.0 * (n["solves_per_s"] / o["solves_per_s"] - 1.0) if o["solves_per_s"] > 0 else float("nan")
        sp = f"{o['speedup']:.1f}x -> {n['speedup']:.1f}x" if o.get("speedup") and n.get("speedup") else "-"
        lines.append(f"  {k[0]:<5} {k[1]:<9} {k[2]:<7} {k[3]:>9,}  {_rate(o['solves_per_s']):>12}  "
                     f"{_rate(n['solves_per_s']):>12}  {change:>+7.1f}%  {sp:>20}")
    only_new = [k for k in after if k not in before]
    only_old = [k for k in before if k not in after]
    if only_new:
        lines.append(f"  only in this run: {', '.join(f'{a} {r} {s} N={n:,}' for a, r, s, n in only_new)}")
    if only_old:
        lines.append(f"  only in {label}: {', '.join(f'{a} {r} {s} N={n:,}' for a, r, s, n in only_old)}")
    old_games = {(g["arch"], g["n"]): g for g in old.get("game") or [] if isinstance(g, dict)}
    for g in new.get("game") or []:
        o = old_games.get((g["arch"], g["n"]))
        if o and "frame_ms" in o:
            a, b = o["frame_ms"]["median"], g["frame_ms"]["median"]
            lines.append(f"  game {g['arch']} N={g['n']:,}: frame median {a:.2f} ms -> {b:.2f} ms "
                         f"({100 * (b / a - 1):+.1f}%)")
        so, sn = (o or {}).get("scene"), g.get("scene")
        if so and sn and so.get("scene") == sn.get("scene"):
            a, b = so["frame_ms"]["p95"], sn["frame_ms"]["p95"]
            lines.append(f"  game {g['arch']} {sn['scene']} as played: IK + bullets p95 {a:.2f} ms -> {b:.2f} ms "
                         f"({100 * (b / a - 1):+.1f}%)")
    return lines


# ------------------------------------------------------------------------------------------------ entry point

def run(args) -> int:
    """`crowd-ik bench`: see the module docstring."""
    from tqdm import tqdm

    from crowd_ik.io.output import atomic_path, check_writable, write_json

    opts = resolve_options(args)
    json_path = check_writable(args.json, args.force) if args.json else None
    plot_path = None
    if args.plot:
        if Path(args.plot).suffix.lower() != ".png":
            raise ValueError(f"--plot: expected a .png file name (got {args.plot!r})")
        plot_path = check_writable(args.plot, args.force)
        if json_path is not None and plot_path.resolve() == json_path.resolve():
            raise ValueError(f"--plot: the same file as --json ({args.plot})")
    old = load_results(args.compare) if args.compare else None
    arches = resolve_arches(opts.arches)
    load_before = list(os.getloadavg())
    if load_before[0] > 0.5:
        print(f"crowd-ik bench: note: load average {load_before[0]:.2f} before the run; other processes share the CPU, "
              "so the timings will be pessimistic and noisy", file=sys.stderr)

    children = [run_child(arch, cells_for(opts, arch), opts) for arch in arches]
    records = [r for c in children for r in c["records"]]
    games = [c["game"] for c in children if c["game"]]

    baseline = Baseline(opts.repeats, opts.budget)
    cells = list(dict.fromkeys((r["rig"], r["solver"], r["n"]) for r in records))
    chosen = {}
    if opts.budget > 0:
        for cell in tqdm(cells, desc="bench numpy", unit="cell", file=sys.stderr, dynamic_ncols=True):
            chosen[cell] = baseline.measure(*cell)
    found = {cell: baseline.summary(cell[0], cell[1], m) for cell, m in chosen.items() if m is not None}
    for r in records:
        base = found.get((r["rig"], r["solver"], r["n"]))
        r.update(base or dict(numpy_solves_per_s=None, numpy_n=0, numpy_repeats=0))
        r["speedup"] = r["solves_per_s"] / base["numpy_solves_per_s"] if base else None

    peer_targets = []
    if opts.peers:
        from crowd_ik.bench import peers as bench_peers
        print("bench numba: timing the peers on the chain16 workloads", file=sys.stderr)
        bench_peers.measure(records, make_workload, opts.repeats, opts.threads)
        peer_targets = bench_peers.targets(records, _isa())
    result = dict(meta=build_meta(opts, children, arches, load_before), records=records, game=games,
                  targets=evaluate_targets(records, games) + peer_targets)
    missing = [s for s in opts.solvers if _reference_solver(s) is None]
    if missing:
        result["meta"]["notes"].append(f"no NumPy twin for {', '.join(missing)}: no baseline or speed-up for it")

    print(format_table(records))
    if opts.peers:
        from crowd_ik.bench import peers as bench_peers
        print(bench_peers.format_table(records))
    for c in children:
        print(f"lanes {c['arch']}: {c.get('lanes')} characters per thread ({_isa()})")
        for key, info in c["compile"].items():
            print(f"compile {c['arch']} {key}: first call {info['first_call_s']:.2f} s, steady {info['steady_s']:.3f} s "
                  f"on {info['n']} characters -> compile {info['compile_s']:.2f} s")
    for g in games:
        print(format_game(g))
    text = format_targets(result["targets"])
    if text:
        print(text)
    if old is not None:
        print("\n".join(compare_lines(old, result, args.compare)))
    if json_path is not None:
        write_json(json_path, result, force=args.force)
    if plot_path is not None:
        from crowd_ik.bench.chart import draw

        with atomic_path(plot_path, force=args.force) as tmp:
            draw(result, tmp)
    return 0


def _main(argv: list[str]) -> int:
    if len(argv) == 3 and argv[0] == "--child":
        try:
            return child_main(argv[1], argv[2])
        except KeyboardInterrupt:
            return 130
    print("usage: python -m crowd_ik.bench.run --child SPEC.json RESULT.json (use `crowd-ik bench`)", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(_main(sys.argv[1:]))
