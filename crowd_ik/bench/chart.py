"""The `crowd-ik bench --plot` chart: solves per second against character count, log-log.

One panel per rig; a solid line per (solver, backend), the NumPy baseline of each solver dashed in
the same colour, and the float64 numba peer (``--peers numba``) dotted. Drawn on a bare matplotlib Figure with the Agg canvas (no pyplot state, no display).
"""

from __future__ import annotations

from pathlib import Path

from crowd_ik.solvers.registry import CCD, DLS, FABRIK

COLOURS = {FABRIK: "#1f77b4", DLS: "#d62728", CCD: "#2ca02c"}
MARKERS = {"cpu": "o", "cuda": "^"}


def _series(records: list[dict], rig: str) -> tuple[dict, dict]:
    """{(solver, arch): [(n, solves/s)]} for Taichi and {solver: [(n, numpy solves/s, on a subset)]} for NumPy."""
    taichi, numpy = {}, {}
    for r in sorted(records, key=lambda r: r["n"]):
        if r["rig"] != rig:
            continue
        taichi.setdefault((r["solver"], r["arch"]), []).append((r["n"], r["solves_per_s"]))
        if r.get("numpy_solves_per_s"):
            points = numpy.setdefault(r["solver"], [])
            if all(n != r["n"] for n, *_ in points):
                points.append((r["n"], r["numpy_solves_per_s"], r["numpy_n"] < r["n"]))
    return taichi, numpy


def _count(x: float) -> str:
    """100 -> '100', 10000 -> '10k', 1000000 -> '1M'."""
    for scale, suffix in ((1e6, "M"), (1e3, "k")):
        if x >= scale:
            return f"{x / scale:g}{suffix}"
    return f"{x:g}"


def draw(result: dict, path: str | Path, dpi: int = 120) -> None:
    """Draw the chart of a bench result (the --json structure) to `path` (format from its suffix)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

    records = result["records"]
    rigs = list(dict.fromkeys(r["rig"] for r in records))
    if not rigs:
        raise ValueError("plot: no benchmark records to draw")
    fig = Figure(figsize=(6.4 * len(rigs), 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(rigs), squeeze=False)[0]
    for ax, rig in zip(axes, rigs):
        taichi, numpy = _series(records, rig)
        for (solver, arch), pts in taichi.items():
            n, y = zip(*pts)
            ax.plot(n, y, color=COLOURS.get(solver, "k"), marker=MARKERS.get(arch, "s"), lw=2,
                    label=f"{solver} (Taichi {arch})")
        peers = {}
        for r in sorted(records, key=lambda r: r["n"]):
            if r["rig"] == rig and r.get("numba_f64_solves_per_s"):
                pts = peers.setdefault(r["solver"], [])
                if all(n != r["n"] for n, _ in pts):
                    pts.append((r["n"], r["numba_f64_solves_per_s"]))
        for solver, pts in peers.items():
            ax.plot(*zip(*pts), color=COLOURS.get(solver, "k"), ls=":", marker="x", lw=1.5,
                    label=f"{solver} (numba f64 peer)")
        for solver, pts in numpy.items():
            n, y, subset = zip(*pts)
            colour = COLOURS.get(solver, "k")
            ax.plot(n, y, color=colour, ls="--", lw=1.5, label=f"{solver} (NumPy)")
            full = [(a, b) for a, b, s in pts if not s]
            part = [(a, b) for a, b, s in pts if s]
            if full:
                ax.plot(*zip(*full), ls="none", marker="s", ms=5, color=colour)
            if part:  # measured on the first numpy_n characters only, within the time budget
                ax.plot(*zip(*part), ls="none", marker="s", ms=6, mfc="white", mec=colour)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ns = sorted({r["n"] for r in records if r["rig"] == rig})
        ax.xaxis.set_major_locator(FixedLocator(ns))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: _count(x)))
        ax.xaxis.set_minor_locator(NullLocator())
        if len(ns) == 1:
            ax.set_xlim(ns[0] / 2, ns[0] * 2)
        ax.set_xlabel("characters N")
        ax.set_ylabel("solves per second")
        ax.set_title(rig)
        ax.grid(True, which="major", alpha=0.4)
        ax.grid(True, which="minor", alpha=0.15)
    meta = result.get("meta", {})
    cores = meta.get("usable_cores") or meta.get("cores")
    fig.suptitle(f"crowd-ik bench: IK solves/s vs characters - {meta.get('cpu_model', '?')}, {cores} cores "
                 f"(best of {meta.get('settings', {}).get('repeats', '?')})", fontsize="medium")
    legend = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    fig.legend(legend.values(), legend.keys(), loc="outside lower center", ncol=min(len(legend), 6), fontsize="small",
               title="solid: Taichi; dashed: vectorised NumPy twins; dotted: numba peers; hollow squares: NumPy timed on a subset of the "
                     "characters (its time budget)", title_fontsize="small", frameon=False)
    fig.savefig(path, dpi=dpi)


__all__ = ["draw"]
