"""The bench's record and its reading: machine and source metadata, targets met or missed, the
table, the game lines, and the comparison with an earlier --json."""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
from pathlib import Path

import numpy as np

from crowd_ik.bench.options import (
    BASELINE_PROBE,
    CUDA_EXTRA_CHARS,
    FRAME_MS,
    GAME_SCENE,
    SEED,
    SPACING,
    Options,
)
from crowd_ik.solvers.registry import DLS, FABRIK


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
                     limited_lanes=c.get("limited_lanes"), general_lanes=c.get("general_lanes"),
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
               "success = status CONVERGED; reachable = no target beyond its chain's length from the root joint"],
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
        name = "game frame, every character's targets moving (warm FABRIK <= 4 it + 4096 bullets)"
        # issue 13's target is the median frame; the p95 is the stricter frame budget (`fits`)
        median = g["frame_ms"].get("median")
        if median is not None:
            out.append(dict(name=f"{name}, median ms", arch=g["arch"], n=g["n"], goal=f"<= {FRAME_MS:.1f} ms",
                            unit="ms", value=median, met=bool(median <= FRAME_MS)))
        out.append(dict(name=f"{name}, p95 ms", arch=g["arch"], n=g["n"], goal=f"<= {FRAME_MS:.1f} ms", unit="ms",
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
            f"\n  ({g['hits']} hits, {g['bullets_alive']:.0f} bullets alive, "
            f"{100 * g.get('substepped_share', 0):.2f}% of them sub-stepped, up to {g['mean_substeps']:.1f} sub-steps "
            f"a frame on average;\n  joints moved {1e3 * g['limb_step_m']:.1f} mm per frame (median character), "
            f"{1e3 * g['limb_step_max_m']:.0f} mm at most)" + format_runs(g.get("runs")) + format_scene(g.get("scene")))


def format_runs(runs: list[dict] | None) -> str:
    """Each run's frame median / p95 (bench.workloads.best_game_frames), when there was more than one."""
    if not runs or len(runs) < 2:
        return ""
    each = ", ".join(f"{r['frame_ms']['median']:.2f} / {r['frame_ms']['p95']:.2f}" for r in runs)
    return f"\n  {len(runs)} runs, the one with the lowest median kept: frame median / p95 {each} ms"


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
