"""The bench's settings: rigs, solvers, character counts, the --quick and full defaults, and how flags resolve into them."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

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
            scene_steps=120, render_frames=90)
QUICK = dict(chars=(100, 1000), solvers=(FABRIK, DLS), rigs=("chain16",), repeats=1, budget=1.0, game_chars=256,
             game_frames=5, scene_steps=0, render_frames=0)
MAX_RENDER_FRAMES = 100_000


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
    render_frames: int = 0  # frames per scene of the render workload (crowd_ik.bench.render); 0 skips it


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


def rig(name: str):
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
    render_frames = base["render_frames"] if getattr(args, "render_frames", None) is None else args.render_frames
    if isinstance(render_frames, bool) or not isinstance(render_frames, int) or not 0 <= render_frames <= MAX_RENDER_FRAMES:
        raise ValueError(f"--render-frames: expected an integer in [0, {MAX_RENDER_FRAMES}] (got {render_frames!r})")
    return Options(chars, args.chars is not None, solvers, rigs, arches, threads, repeats, float(budget),
                   int(game_chars), base["game_frames"], bool(args.quick), base["scene_steps"] if game_chars else 0,
                   peers, int(render_frames))


def _bytes_estimate(rig_name: str) -> int:
    from crowd_ik.crowd import Crowd

    return Crowd.bytes_per_character(rig(rig_name))


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
