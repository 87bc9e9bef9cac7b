"""`crowd-ik mouse` target paths: reading a t,x,y CSV (shipped names resolve from anywhere), resampling
it to frames, and recording a live drag to path_NNN.csv."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np

from crowd_ik.io.csv_table import finite, read_table
from crowd_ik.mouse.session import MAX_FRAMES, SCENES

# ---------------------------------------------------------------------------------------------
# CSV input and recording


def resolve_input(path: str) -> Path:
    """An existing file, or else the shipped file of that name in crowd_ik/scenes (".csv" optional)."""
    p = Path(path).expanduser()
    if p.exists():
        return p
    for name in (p.name, p.name + ".csv"):
        shipped = SCENES / name
        if p.parent.name in ("", ".", "scenes") and shipped.is_file():
            return shipped
    shipped = ", ".join(sorted(f.name for f in SCENES.glob("*.csv")))
    raise FileNotFoundError(f"{path}: no such file (shipped: {shipped})")


def load_path(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a target path: header ``t,x,y`` (seconds, chain units), then one row per sample with t
    increasing. Blank lines and '#' lines are skipped. Returns (t (M,), xy (M, 2)).

    Problems raise ValueError("path:LINE: problem (got value)").
    """
    path = os.fspath(path)
    table = read_table(path, ("t", "x", "y"), "t,x,y", max_rows=MAX_FRAMES)
    rows = []
    for number, fields in table.rows:
        row = [finite(path, number, name, f) for name, f in zip(table.header, fields)]
        if rows and row[0] <= rows[-1][0]:
            raise ValueError(f"{path}:{number}: t: expected times increasing row by row (got {fields[0]} after {rows[-1][0]:g})")
        rows.append(row)
    a = np.array(rows, dtype=np.float64)
    return a[:, 0], a[:, 1:]


def path_frames(t: np.ndarray, xy: np.ndarray, fps: float | None, source: str = "path") -> tuple[np.ndarray, np.ndarray, float]:
    """(times, targets (F, 2), video fps): one frame per row at the rows' mean rate, or resampled
    on t at ``fps`` (linear interpolation; frames at t0 + k/fps up to the last row's time)."""
    if fps is None:
        rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 else 30.0
        if not 0.0 < rate <= 1000.0:
            raise ValueError(f"{source}: rows come at {rate:g} per second; give --fps to resample (got no --fps)")
        return t.copy(), xy.copy(), float(round(rate, 6))
    count = int(math.floor((t[-1] - t[0]) * fps + 1e-9)) + 1
    if count > MAX_FRAMES:
        raise ValueError(f"--fps: {count} frames exceed {MAX_FRAMES} (got {fps:g})")
    times = t[0] + np.arange(count) / fps
    return times, np.stack([np.interp(times, t, xy[:, 0]), np.interp(times, t, xy[:, 1])], axis=1), float(fps)


class Recorder:
    """Target positions over time, saved as path_NNN.csv (the first free name) in ``folder``."""

    def __init__(self, folder: str | os.PathLike = "."):
        self.folder = Path(folder)
        self.rows: list[tuple[float, float, float]] = []
        self.start = time.monotonic()

    def add(self, xy) -> None:
        self.rows.append((time.monotonic() - self.start, float(xy[0]), float(xy[1])))

    def save(self) -> Path:
        from crowd_ik.io.output import write_text

        text = "t,x,y\n" + "".join(f"{t:.4f},{x:.5f},{y:.5f}\n" for t, x, y in self.rows)
        for k in range(1, 100_000):
            name = self.folder / f"path_{k:03d}.csv"
            if name.exists() or name.is_symlink():
                continue
            try:
                return write_text(name, text)
            except FileExistsError:  # appeared since the check: take the next number
                continue
        raise RuntimeError(f"{self.folder}: no free name path_NNN.csv left")
