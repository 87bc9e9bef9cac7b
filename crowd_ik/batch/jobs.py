"""JOBS files of `crowd-ik render-many`: TOML -> a list of Jobs, refused like scenes when bad
(one line, `FILE: key: problem (got VALUE)`, a ValueError the command line turns into exit 2).

    scenes = ["duel", "arena", "my/scene.toml"]   # shipped names, or paths relative to this file
    seeds = "0..7"                                # or [0, 3, 9]; inclusive; default: each scene's own
    solvers = ["fabrik", "dls"]                   # optional; every combination is a job
    labels = true                                 # optional: per-frame pose labels beside each video
    timeout_s = 600                               # optional: a job running longer fails (checked per frame)

    [overrides]                                   # scene keys in the scene schema, for every job
    video = { width = 160, height = 96, frames = 12 }

    [[job]]                                       # explicit jobs, alone or beside a sweep
    scene = "duel"
    seed = 3                                      # optional (the scene's seed)
    solver = "dls"                                # optional (the scene's solver)
    labels = false                                # optional (the file's labels)
    timeout_s = 60                                # optional (the file's timeout_s)

Job names, and so output names, are `<scene>_s<seed>` with `_<solver>` added when the sweep names
solvers (or the [[job]] table a solver): `DIR/<name>.mp4`, `DIR/<name>.labels.jsonl`. Two jobs with one
name are refused. Every scene is loaded and checked here, overrides applied, before anything runs.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass
from pathlib import Path

from crowd_ik.scene import (
    MAX_SEED, Scene, apply_table, check_table, load_scene, parse_toml, read_text_file, scene_with, shipped_scenes,
)
from crowd_ik.solvers.registry import METHODS

MAX_JOBS = 100_000
MAX_JOBS_BYTES = 1 * 2**20
TOP_KEYS = ("scenes", "seeds", "solvers", "labels", "timeout_s", "overrides", "job")
JOB_KEYS = ("scene", "seed", "solver", "labels", "timeout_s")
_RANGE = re.compile(r"\s*(\d+)\s*\.\.\s*(\d+)\s*")

__all__ = ["Job", "load_jobs", "parse_jobs", "MAX_JOBS"]


@dataclass(frozen=True)
class Job:
    """One video to render: `scene` is the effective scene (overrides, seed and solver applied)."""

    name: str  # output stem: <scene>_s<seed>[_<solver>]
    scene: Scene
    source: str  # where the JOBS file defines it, e.g. "sweep.toml: job[2]" or "sweep.toml: scenes[0]"
    labels: bool = False
    timeout_s: float | None = None

    @property
    def key(self) -> str:
        """A digest of what the job renders (every scene value, labels); a manifest record of another
        key is of another job."""
        text = self.scene.to_toml() + f"\nlabels = {str(self.labels).lower()}\n"
        return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]

    def outputs(self, folder: Path) -> tuple[Path, Path | None]:
        """(video, labels or None) paths in `folder`."""
        return folder / f"{self.name}.mp4", (folder / f"{self.name}.labels.jsonl") if self.labels else None

    def describe(self) -> dict:
        """The job as the manifest records it."""
        return {"name": self.name, "scene": self.scene.name, "seed": self.scene.seed,
                "solver": self.scene.solver.method, "frames": self.scene.n_frames,
                "size": [self.scene.video.width, self.scene.video.height], "labels": self.labels}


def _show(v) -> str:
    text = f'"{v}"' if isinstance(v, str) else str(v).lower() if isinstance(v, bool) else repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


class _Reader:
    def __init__(self, source: str, folder: Path):
        self.source, self.folder = source, folder

    def bad(self, key: str, problem: str, value=None) -> ValueError:
        got = "" if value is None else f" (got {_show(value)})"
        return ValueError(f"{self.source}: {key}: {problem}{got}")

    def seed(self, key: str, v) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= MAX_SEED:
            raise self.bad(key, f"must be an integer from 0 to {MAX_SEED}", v)
        return v

    def seeds(self, v) -> list[int]:
        if isinstance(v, str):
            m = _RANGE.fullmatch(v)
            if not m:
                raise self.bad("seeds", 'must be a list of integers or a range "A..B" (inclusive)', v)
            a, b = int(m.group(1)), int(m.group(2))
            if b < a:
                raise self.bad("seeds", f"range {a}..{b} is empty (A..B needs A <= B)", v)
            if b > MAX_SEED:
                raise self.bad("seeds", f"must be at most {MAX_SEED}", v)
            if b - a + 1 > MAX_JOBS:
                raise self.bad("seeds", f"gives {b - a + 1} seeds, more than {MAX_JOBS} jobs", v)
            return list(range(a, b + 1))
        if not isinstance(v, list) or not v:
            raise self.bad("seeds", 'must be a non-empty list of integers or a range "A..B"', v)
        out = [self.seed(f"seeds[{i}]", s) for i, s in enumerate(v)]
        for i, s in enumerate(out):
            if s in out[:i]:
                raise self.bad(f"seeds[{i}]", f"repeats seeds[{out.index(s)}]", s)
        return out

    def names(self, key: str, v, what: str) -> list[str]:
        if not isinstance(v, list) or not v or not all(isinstance(x, str) for x in v):
            raise self.bad(key, f"must be a non-empty list of {what}", v)
        return v

    def solver(self, key: str, v) -> str:
        if v not in METHODS:
            listed = ", ".join(f'"{m}"' for m in METHODS)
            raise self.bad(key, f"must be one of {listed}", v)
        return v

    def flag(self, key: str, v) -> bool:
        if not isinstance(v, bool):
            raise self.bad(key, "must be true or false", v)
        return v

    def timeout(self, key: str, v) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise self.bad(key, "must be a positive number of seconds", v)
        return float(v)

    def scene(self, key: str, ref, cache: dict) -> Scene:
        """A shipped name ("duel") or a path relative to the JOBS file, loaded and checked once."""
        if not isinstance(ref, str) or not ref:
            raise self.bad(key, 'must be a scene name such as "duel" or a path to a .toml file', ref)
        if ref in cache:
            return cache[ref]
        path = Path(ref).expanduser()
        if not path.is_absolute():
            path = self.folder / path
        shipped = {p.stem: p for p in shipped_scenes()}
        if not path.exists() and Path(ref).suffix == "" and "/" not in ref and ref in shipped:
            path = shipped[ref]
        if not path.exists():
            names = ", ".join(sorted(shipped)) or "none found"
            raise self.bad(key, f"no such scene file ({path}) and no shipped scene of that name ({names})", ref)
        cache[ref] = load_scene(path)
        return cache[ref]


def _read(path: Path) -> tuple[dict, str]:
    source = str(path)
    return parse_toml(read_text_file(path, source, "jobs file", MAX_JOBS_BYTES), source), source


def load_jobs(path: str | Path) -> list[Job]:
    """Read and check a JOBS file; scene paths in it are relative to its folder."""
    p = Path(path).expanduser()
    raw, source = _read(p)
    return parse_jobs(raw, source, p.parent)


def parse_jobs(raw: dict, source: str = "<jobs>", folder: Path | None = None) -> list[Job]:
    """The Jobs of a parsed JOBS table (see the module docstring)."""
    r = _Reader(source, folder or Path("."))
    for key, value in raw.items():
        if key not in TOP_KEYS:
            import difflib

            close = difflib.get_close_matches(key, TOP_KEYS, n=1, cutoff=0.6)
            hint = f"did you mean {close[0]}?" if close else f"known keys: {', '.join(TOP_KEYS)}"
            raise r.bad(key, f"unknown key; {hint}", value)
    overrides = check_table(raw.get("overrides", {}), source, prefix="overrides.")
    labels = r.flag("labels", raw["labels"]) if "labels" in raw else False
    timeout = r.timeout("timeout_s", raw["timeout_s"]) if "timeout_s" in raw else None
    cache: dict[str, Scene] = {}
    specs = []  # (source key, scene, seed or None, solver or None, named solver, labels, timeout)
    if "scenes" in raw:
        refs = r.names("scenes", raw["scenes"], 'scene names or paths, e.g. ["duel", "arena"]')
        seeds = r.seeds(raw["seeds"]) if "seeds" in raw else [None]
        solvers = [r.solver(f"solvers[{i}]", m) for i, m in
                   enumerate(r.names("solvers", raw["solvers"], "solver names"))] if "solvers" in raw else [None]
        count = len(refs) * len(seeds) * len(solvers)
        if count > MAX_JOBS:
            raise r.bad("scenes", f"scenes x seeds x solvers gives {count} jobs, more than {MAX_JOBS}", len(refs))
        for i, ref in enumerate(refs):
            scene = r.scene(f"scenes[{i}]", ref, cache)
            specs += [(f"scenes[{i}]", scene, s, m, "solvers" in raw, labels, timeout) for s in seeds for m in solvers]
    elif "seeds" in raw or "solvers" in raw:
        raise r.bad("seeds" if "seeds" in raw else "solvers", "a sweep needs scenes = [...] too")
    tables = raw.get("job", [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise r.bad("job", "must be an array of tables, written [[job]]")
    if len(specs) + len(tables) > MAX_JOBS:
        raise r.bad("job", f"{len(specs) + len(tables)} jobs, more than {MAX_JOBS}")
    for i, table in enumerate(tables):
        key = f"job[{i}]"
        for k, v in table.items():
            if k not in JOB_KEYS:
                raise r.bad(f"{key}.{k}", f"unknown key; known keys: {', '.join(JOB_KEYS)}", v)
        if "scene" not in table:
            raise r.bad(f"{key}.scene", 'missing; every [[job]] names its scene, e.g. scene = "duel"')
        scene = r.scene(f"{key}.scene", table["scene"], cache)
        seed = r.seed(f"{key}.seed", table["seed"]) if "seed" in table else None
        solver = r.solver(f"{key}.solver", table["solver"]) if "solver" in table else None
        job_labels = r.flag(f"{key}.labels", table["labels"]) if "labels" in table else labels
        job_timeout = r.timeout(f"{key}.timeout_s", table["timeout_s"]) if "timeout_s" in table else timeout
        specs.append((key, scene, seed, solver, solver is not None, job_labels, job_timeout))
    if not specs:
        raise ValueError(f"{source}: no jobs: give scenes = [...] (and seeds = [...]), or [[job]] tables")
    with_overrides: dict[int, Scene] = {}
    jobs: list[Job] = []
    seen: dict[str, str] = {}
    for key, scene, seed, solver, named, job_labels, job_timeout in specs:
        if id(scene) not in with_overrides:
            with_overrides[id(scene)] = apply_table(scene, overrides, source) if overrides else scene
        effective = scene_with(with_overrides[id(scene)], seed=seed, method=solver)
        name = f"{effective.name}_s{effective.seed}" + (f"_{effective.solver.method}" if named else "")
        if name in seen:
            raise r.bad(key, f"renders {name}.mp4, as {seen[name]} does (same scene name, seed and solver)")
        seen[name] = key
        jobs.append(Job(name, effective, f"{source}: {key}", job_labels, job_timeout))
    return jobs
