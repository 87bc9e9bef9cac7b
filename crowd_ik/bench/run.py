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
cache is on, so after the first run this is mostly cache loading). With ``--peers numba`` the numba peers of
each chain16 FABRIK / DLS cell on the CPU are timed in the same child process, one run of each after each of
crowd_ik's timed repeats (crowd_ik/bench/peers.py: Interleaved), so the ratio compares runs made moments apart.
The NumPy baseline gets a time
budget per cell: it starts on min(N, 100) characters and grows the subset while `repeats` runs still
fit in the budget; solves/s is then the subset size over its best time (``numpy_n`` says which).

The game workload (``game_workload``): a crowd of humanoids (10,000 by default) standing in natural
poses, as in the game: their targets are where those poses put the effectors (reachable), the cold
solve goes there from rest, then frames in which the head and hand targets follow a small smooth
offset while the feet stay planted, each solved with FABRIK warm-started
from the previous frame (at most 4 iterations), plus the bullet step of a full 4096-bullet pool
against the crowd's limb capsules; the frame time is compared with one 60 Hz frame. Like a solve cell it
runs ``repeats`` times from the same start, and the run with the lowest median frame is kept (every run's
medians are printed: this 2-core VM has phases about a third slower). Every character's
targets move every frame there: the worst case. The full run also times the game as played
(``game_scene``): the shipped stress_10k scene (10,000 humanoids, 16 shooters) in crowd_ik.game.world.World,
FABRIK capped at 4 iterations, per 60 Hz world step the characters' IK and the bullets' step, after
the first bullets have reached the crowd; there only the threatened characters move.
The full run also renders the three shipped game scenes to H.264 through play's pipeline
(crowd_ik.bench.render; ``--render-frames N`` a scene, 0 skips it): frames per second, warm.

Exit codes (as crowd_ik.commands.cli): 2 for bad options, an existing output without --force, an unreadable
--compare file, and for ``--arch cuda`` on a machine without a CUDA GPU (refused before anything
runs, as bad input for this machine); 1 when a child process fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from crowd_ik.bench.baseline import Baseline, _reference_solver
from crowd_ik.bench.options import (
    GAME_SCENE,
    Options,
    cells_for,
    resolve_arches,
    resolve_options,
)
from crowd_ik.bench.report import (
    _isa,
    build_meta,
    compare_lines,
    evaluate_targets,
    format_game,
    format_table,
    format_targets,
    load_results,
)
from crowd_ik.bench.workloads import (
    compile_time,
    best_game_frames,
    game_scene,
    make_workload,
    time_cell,
)


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

    from crowd_ik.bench import peers as bench_peers

    cells = [tuple(c) for c in spec["cells"]]
    total = len(cells) + (1 if spec["game_chars"] else 0) + (1 if spec.get("render_frames") else 0)
    records, compile_info = [], {}
    with tqdm(total=total, desc=f"bench {arch}", unit="cell", file=sys.stderr, dynamic_ncols=True) as bar:
        for rig_name, solver, n in cells:
            bar.set_postfix_str(f"{rig_name} {solver} N={n}")
            key = f"{rig_name}/{solver}"
            if key not in compile_info:
                small = min(m for r, s, m in cells if (r, s) == (rig_name, solver))
                compile_info[key] = compile_time(make_workload(rig_name, small), solver)
            rec = dict(arch=arch, rig=rig_name, solver=solver, n=n)
            wl = make_workload(rig_name, n)
            peer = None
            if spec.get("peers") and bench_peers.qualifies(arch, rig_name, solver):
                peer = bench_peers.Interleaved(wl, solver, spec["threads"])
            rec.update(time_cell(wl, solver, spec["repeats"], between=peer.run_once if peer else None))
            if peer is not None:
                peer.fill(rec)
            rec["compile_s"] = compile_info[key]["compile_s"]
            records.append(rec)
            bar.update(1)
        game = None
        if spec["game_chars"]:
            bar.set_postfix_str(f"game N={spec['game_chars']}")
            game = dict(arch=arch, **best_game_frames(spec["game_chars"], spec["game_frames"], spec["repeats"]))
            if spec.get("scene_steps"):
                bar.set_postfix_str(f"game scene {GAME_SCENE}")
                game["scene"] = game_scene(spec["scene_steps"])
            bar.update(1)
        render = []
        if spec.get("render_frames"):
            from crowd_ik.bench.render import render_workload

            bar.set_postfix_str(f"render {spec['render_frames']} frames a scene")
            render = [dict(arch=arch, **r) for r in render_workload(spec["render_frames"])]
            bar.update(1)
    from crowd_ik.solvers import settings

    result = dict(arch=arch, requested=spec["arch"], lanes=settings.lanes(), limited_lanes=settings.limited_lanes(),
                  general_lanes=settings.general_lanes(),
                  taichi_threads=int(ti.lang.impl.current_cfg().cpu_max_num_threads),
                  gpu=_gpu_name() if arch == "cuda" else None,
                  peak_rss_bytes=int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024,
                  loadavg_start=load_start, loadavg_end=list(os.getloadavg()),
                  compile=compile_info, records=records, game=game, render=render)
    Path(result_path).write_text(json.dumps(result))
    return 0


def run_child(arch: str, cells: list, opts: Options) -> dict:
    """Run one arch in a child process (`python -m crowd_ik.bench.run --child`) and return its result."""
    with tempfile.TemporaryDirectory(prefix="crowd-ik-bench-") as tmp:
        spec, result = Path(tmp) / "spec.json", Path(tmp) / "result.json"
        spec.write_text(json.dumps(dict(arch=arch, threads=opts.threads, cells=cells, repeats=opts.repeats,
                                        game_chars=opts.game_chars, game_frames=opts.game_frames,
                                        scene_steps=opts.scene_steps, render_frames=opts.render_frames,
                                        peers=bool(opts.peers))))
        proc = subprocess.run([sys.executable, "-m", "crowd_ik.bench.run", "--child", str(spec), str(result)])
        if proc.returncode == 130 or proc.returncode == -2:
            raise KeyboardInterrupt
        if proc.returncode != 0 or not result.is_file():
            raise RuntimeError(f"the {arch} benchmark process failed (exit {proc.returncode}); see its messages above")
        return json.loads(result.read_text())


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
        print("bench numba: timing the peers of the chain16 cells not timed beside them", file=sys.stderr)
        bench_peers.measure(records, make_workload, opts.repeats, opts.threads)
        peer_targets = bench_peers.targets(records, _isa())
    from crowd_ik.bench import render as bench_render

    renders = [r for c in children for r in c.get("render") or []]
    render_targets = [t for c in children for t in bench_render.render_targets(c.get("render") or [], c["arch"])]
    result = dict(meta=build_meta(opts, children, arches, load_before), records=records, game=games, render=renders,
                  targets=evaluate_targets(records, games) + peer_targets + render_targets)
    missing = [s for s in opts.solvers if _reference_solver(s) is None]
    if missing:
        result["meta"]["notes"].append(f"no NumPy twin for {', '.join(missing)}: no baseline or speed-up for it")

    print(format_table(records))
    if opts.peers:
        from crowd_ik.bench import peers as bench_peers
        print(bench_peers.format_table(records))
    for c in children:
        where = f"{c['gpu']}: one character per GPU thread" if c["arch"] == "cuda" and c.get("gpu") else _isa()
        narrow = ""
        if c.get("lanes", 0) > 1 and c.get("limited_lanes"):  # the joint-limited and general DLS kernels' width
            narrow = (f"; {c['limited_lanes']} for the joint-limited FABRIK and CCD, {c.get('general_lanes') or 1} for "
                      "the general DLS")
        print(f"lanes {c['arch']}: {c.get('lanes')} characters per thread ({where}){narrow}")
        for key, info in c["compile"].items():
            print(f"compile {c['arch']} {key}: first call {info['first_call_s']:.2f} s, steady {info['steady_s']:.3f} s "
                  f"on {info['n']} characters -> compile {info['compile_s']:.2f} s")
    for g in games:
        print(format_game(g))
    for c in children:
        for line in bench_render.format_render(c.get("render") or [], c["arch"]):
            print(line)
    text = format_targets(result["targets"])
    if text:
        print(text)
    if old is not None:
        print("\n".join(compare_lines(old, result, args.compare) + bench_render.compare_render(old, result)))
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
