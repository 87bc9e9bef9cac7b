"""The one place that initialises Taichi.

Every entry point calls :func:`init` lazily with its defaults; a user may call it first to pick the
backend, thread count, precision or cache folder. It is idempotent for the same arch, and refuses
to switch arch once Taichi is running (kernels already compiled for one backend cannot move). Before
Taichi starts it lightens Taichi's frontend, which runs at every kernel's first launch in a process even
with the offline cache warm: a short position message per AST node (_short_debug_info) and each function's
source read once (_remembered_sources).
"""

from __future__ import annotations

import os

from crowd_ik.solvers import settings

_STATE: dict = {}

ARCHES = ("auto", "cpu", "cuda")
# Taichi's offline cache is LRU-cleaned at exit once it passes this size (Taichi's default 100 MB): crowd_ik's
# kernels (the lane kernels' variants, the game's, the raster's) take more, so at the default a bench run evicted
# the render kernels and its next render compiled them again (the arena 6.3 instead of 22 frames/s)
CACHE_BYTES = 1 << 30


class BackendUnavailable(RuntimeError, ValueError):
    """The backend asked for cannot start on this machine. A RuntimeError for library callers, and bad input
    (exit code 2) for the command line, which maps ValueError to 2."""


def _short_debug_info() -> None:
    """Make Taichi's frontend record each AST node's position as 'File, line, in function:' and the source line.

    Taichi 1.7.4 builds, for every node of every kernel it turns into IR, a message with the node's lines and a
    caret row under them, each wrapped by textwrap (ASTTransformerContext.get_pos_info). It is kept for error
    messages only, and it is half of the frontend's time: the arena's World build (the kernels' first launches,
    the offline cache warm) 4.2-4.7 s with it, 2.6-3.2 s with this; the first shot of a scene stalls its step
    less. The offline cache's keys do not depend on it (a build with this after one without compiled nothing).
    A compile error still names the file, line and function and shows the line."""
    from taichi.lang.ast import ast_transformer_utils as atu

    def get_pos_info(self, node):
        return (f'File "{self.file}", line {node.lineno + self.lineno_offset}, in {self.func.func.__name__}:\n'
                f"{self.src[node.lineno - 1]}\n")

    context = getattr(atu, "ASTTransformerContext", None)
    if context is not None and hasattr(context, "get_pos_info"):
        context.get_pos_info = get_pos_info


def _remembered_sources() -> None:
    """Have Taichi's frontend read each function's source once per process, not at every call site it inlines.

    Taichi 1.7.4 re-reads a ti.func's source lines (inspect.getsourcelines: the module's lines tokenised up to
    the function's end) each time a kernel inlines a call to it, ~2,000 times for an arena World. The lines of
    a function object do not change while the process runs, so they are kept (a copy handed out each time):
    the arena World's build 2.9-3.1 -> 2.3-2.4 s."""
    import functools

    from taichi.lang import kernel_impl as ki

    read = getattr(ki, "getsourcelines", None)
    if read is None or getattr(read, "_crowd_ik_remembered", False):
        return

    @functools.lru_cache(maxsize=None)
    def remembered(fn):
        lines, start = read(fn)
        return tuple(lines), start

    def getsourcelines(fn):
        try:
            lines, start = remembered(fn)
        except TypeError:  # an unhashable callable: read it as Taichi does
            return read(fn)
        return list(lines), start

    getsourcelines._crowd_ik_remembered = True
    ki.getsourcelines = getsourcelines


def _opt_level() -> int:
    """Taichi's opt_level for the process: CROWD_IK_TAICHI_OPT_LEVEL (0 or 1, to compare), else 1."""
    value = os.environ.get("CROWD_IK_TAICHI_OPT_LEVEL", "1")
    if value not in ("0", "1"):
        raise ValueError(f"CROWD_IK_TAICHI_OPT_LEVEL: expected 0 or 1 (got {value!r})")
    return int(value)


def _cuda_available(ti) -> bool:
    """True when Taichi's CUDA backend can start on this machine (no display probe)."""
    try:
        from taichi._lib import core as _ti_core

        # the driver probe first: without libcuda, Taichi's own check prints a warning to stderr
        return _probe_cuda_device() and bool(_ti_core.with_cuda())
    except Exception:  # noqa: BLE001 - any failure here means no usable CUDA
        return False


def _probe_cuda_device() -> bool:
    import ctypes

    for name in ("libcuda.so.1", "libcuda.so"):
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        if lib.cuInit(0) != 0:
            return False
        count = ctypes.c_int(0)
        return lib.cuDeviceGetCount(ctypes.byref(count)) == 0 and count.value > 0
    return False


def init(arch: str = "auto", threads: int | None = None, fp: int = 32, cache_dir: str | None = None,
         lanes: int | None = None) -> str:
    """Initialise Taichi once and return the resolved arch ("cpu" or "cuda").

    arch: "auto" (CUDA if present, else CPU) | "cpu" | "cuda". "cuda" without a GPU raises
    RuntimeError (never a silent CPU fallback). A second call with the same (or "auto") arch is a
    no-op; another arch raises RuntimeError. threads: CPU worker threads (None = all cores).
    fp: 32 or 64 (default float precision). cache_dir: Taichi's offline kernel cache folder.
    lanes: characters per CPU thread in the lane-packed solvers (1, 2, 4, 8, 16 or 32; None = the
    CROWD_IK_LANES environment variable, else 16 with AVX-512, 8 with AVX2, 1 on CUDA); see
    crowd_ik/solvers/settings.py.
    """
    if arch not in ARCHES:
        raise ValueError(f"arch: expected one of {', '.join(ARCHES)} (got {arch!r})")
    if fp not in (32, 64):
        raise ValueError(f"fp: expected 32 or 64 (got {fp!r})")
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise ValueError(f"threads: expected a positive integer (got {threads!r})")
    if lanes is not None:
        settings.parse_lanes(lanes, "lanes")
    if _STATE:
        resolved = _STATE["arch"]
        if lanes is not None and lanes != _STATE["lanes"]:
            raise RuntimeError(f"crowd_ik is already running with lanes={_STATE['lanes']}; cannot switch to {lanes}")
        if arch not in ("auto", resolved):
            raise RuntimeError(f"crowd_ik is already running on {resolved}; cannot switch to {arch} in this process")
        if fp != _STATE["fp"]:
            raise RuntimeError(f"crowd_ik is already running with fp={_STATE['fp']}; cannot switch to fp={fp}")
        return resolved

    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    import taichi as ti

    if arch == "cuda" and not _cuda_available(ti):
        raise BackendUnavailable("arch: 'cuda' requested but no CUDA GPU is available to Taichi on this machine")
    use_cuda = arch == "cuda" or (arch == "auto" and _cuda_available(ti))
    kwargs = dict(
        arch=ti.cuda if use_cuda else ti.cpu,
        default_fp=ti.f64 if fp == 64 else ti.f32,
        offline_cache=True,
        offline_cache_max_size_of_files=CACHE_BYTES,
        log_level=ti.WARN,
        # Taichi's control-flow-graph passes: most of a big kernel's cold compile, and LLVM does their work after
        # them; off, except for the kernels kernels/compile_settings.py marks (the raster's).
        # CROWD_IK_TAICHI_CFG_OPT=1 turns them on everywhere (to compare)
        cfg_optimization=os.environ.get("CROWD_IK_TAICHI_CFG_OPT", "0") == "1",
        # Taichi's own simplification level, 1; kernels/compile_settings.py compiles the joint-limited FABRIK lanes
        # at 0 (no whole-kernel CSE). CROWD_IK_TAICHI_OPT_LEVEL sets the default (to compare)
        opt_level=_opt_level(),
        # CUDA's fast math swaps sin, cos, sqrt and division for approximations (about 1e-6 off each): forward
        # kinematics then drifted up to 9e-6 m from the twin and a 0.002 rad rotation error read as 0 on an H200.
        # The CPU keeps Taichi's default (its compiled code, and so the golden frames, stay as they are)
        fast_math=not use_cuda,
    )
    if cache_dir is not None:
        kwargs["offline_cache_file_path"] = str(cache_dir)
    if threads is not None:
        kwargs["cpu_max_num_threads"] = threads
    _short_debug_info()
    _remembered_sources()
    # Taichi's banner goes to stdout; machine-readable output is written to files instead.
    ti.init(**kwargs)
    resolved = "cuda" if ti.lang.impl.current_cfg().arch == ti.cuda else "cpu"
    if arch == "cuda" and resolved != "cuda":
        raise RuntimeError("arch 'cuda' requested but Taichi could not start its CUDA backend")
    chosen = settings.choose_lanes(resolved, lanes)
    settings.set_lanes(chosen, resolved)
    _STATE.update(arch=resolved, fp=fp, threads=threads, lanes=chosen, cache_dir=cache_dir)
    return resolved


def settings_for_child() -> dict:
    """init's arguments that give another process the same Taichi runtime as this one (arch, threads,
    precision, lanes, cache folder): io.render_process starts its child with them, so its kernels compute
    what this process's would, bit for bit."""
    ensure_init()
    return {key: _STATE[key] for key in ("arch", "threads", "fp", "cache_dir", "lanes")}


def ensure_init() -> str:
    """Initialise with the defaults unless already initialised; return the arch."""
    return _STATE["arch"] if _STATE else init()


def current() -> dict:
    """The settings Taichi was started with ({} before init)."""
    return dict(_STATE)


def float_dtype():
    """NumPy dtype matching the kernels' float precision."""
    import numpy as np

    return np.float64 if _STATE.get("fp", 32) == 64 else np.float32


__all__ = ["init", "ensure_init", "current", "float_dtype", "ARCHES", "BackendUnavailable"]
