"""Scene files: TOML -> frozen dataclasses, with validation that names the file, the key and the value.

Every key is optional and the dataclass defaults *are* the arena scene, so `load_scene(None)` works
from any directory without the repo checkout; `scenes/arena.toml` spells the same values out.
Errors are one line, `FILE: key.sub: problem (got VALUE)`, raised as ValueError before anything
is allocated (a scene that would need more than 8 GiB is refused with the estimate in the message).

The schema lives in crowd_ik/scene_schema.py, the checks in crowd_ik/scene_checks.py; this module
loads files and strings, applies overrides and re-exports the schema's names (the public API).
"""

from __future__ import annotations

import difflib
import importlib.resources
import re
import tomllib
from pathlib import Path
from typing import Any

from crowd_ik.scene_checks import (  # noqa: F401  (the scene API: checks a caller may run)
    _Validator, aim_height, crowd_extent, longest_shot, memory_estimate,
)
from crowd_ik.scene_schema import (  # noqa: F401  (the scene API: the schema's dataclasses and bounds)
    ALL_KEYS, BYTES_PER_BULLET, BYTES_PER_CHARACTER, BYTES_PER_PIXEL, Bullets, Camera, Characters, DEFAULT_NAME,
    FLOAT32_MAX, MAX_AIM_HEIGHT, MAX_CHARACTERS, MAX_EXTENT, MAX_FRAMES, MAX_ITERATIONS, MAX_POOL_SIZE,
    MAX_SCALE, MAX_SEED, MAX_SHOOTERS, MAX_SPEED, MAX_WAYPOINTS, MEMORY_LIMIT, MIN_CAMERA_DISTANCE,
    MIN_CAMERA_TILT, MIN_FOV_DEG, Player, SECTIONS, Scene, Shooters, Solver, Time, Video, _SEED_SPEC, _plain,
    _show,
)

# --------------------------------------------------------------------------------------------
# loading


_LINE = re.compile(r"\(at line (\d+), column (\d+)\)")


MAX_SCENE_BYTES = 16 * 2**20  # a scene is a few kilobytes; anything this large is not one
MAX_NESTING = 32  # arrays and tables inside one another; the TOML parser recurses (5,000 overflowed its stack)


def _check_nesting(text: str, source: str) -> None:
    """Refuse arrays and inline tables nested deeper than MAX_NESTING, naming the line (strings and comments
    skipped)."""
    if text.count("[") + text.count("{") <= MAX_NESTING:  # (every scene that is one: no character scan)
        return
    depth, line, quote, i = 0, 1, "", 0
    while i < len(text):
        ch = text[i]
        if ch == "\n":
            line += 1
        elif quote:
            if ch == "\\" and quote == '"':
                i += 1
            elif ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
        elif ch == "#":
            while i + 1 < len(text) and text[i + 1] != "\n":
                i += 1
        elif ch in "[{":
            depth += 1
            if depth > MAX_NESTING:
                raise ValueError(f"{source}: line {line}: invalid TOML: nested deeper than {MAX_NESTING} levels")
        elif ch in "]}":
            depth = max(depth - 1, 0)
        i += 1


def parse_scene(text: str, source: str = "<string>", path: Path | None = None) -> Scene:
    """Parse and validate TOML text; `source` names it in error messages."""
    return _Validator(source).build(parse_toml(text, source), path)


def parse_toml(text: str, source: str) -> dict:
    """TOML text -> dict; nesting deeper than MAX_NESTING and syntax errors raise ValueError naming
    `source` and the line (scene files and jobs files alike)."""
    _check_nesting(text, source)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = _LINE.search(msg)
        where = f"line {m.group(1)}, column {m.group(2)}: " if m else ""
        problem = _LINE.sub("", msg).strip()
        raise ValueError(f"{source}: {where}invalid TOML: {problem}") from None


def read_text_file(path: Path, source: str, what: str, limit: int) -> str:
    """The UTF-8 text of a small input file (a scene, a jobs file): only a regular file of at most
    `limit` bytes is read (a FIFO would block, /dev/zero never ends); problems name `source`."""
    if not path.exists():
        raise FileNotFoundError(f"{source}: no such {what}")
    if path.is_dir():
        raise IsADirectoryError(f"{source}: is a folder, not a {what}")
    if not path.is_file():
        raise ValueError(f"{source}: not a regular file")
    size = path.stat().st_size
    if size > limit:
        raise ValueError(f"{source}: {size:,} bytes; a {what} holds at most {limit:,}")
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{source}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ValueError(f"{source}: cannot be read ({exc.strerror or exc})") from None


def shipped_scenes() -> list[Path]:
    """The scene files that come with crowd_ik, sorted by name: scenes/ beside the package in a
    checkout, else the copy installed as package data (crowd_ik/scenes)."""
    beside = Path(__file__).resolve().parent.parent / "scenes"
    candidates = [beside]
    try:
        packaged = importlib.resources.files("crowd_ik").joinpath("scenes")
        candidates.append(Path(str(packaged)))
    except (ModuleNotFoundError, TypeError):
        pass
    for folder in candidates:
        found = sorted(folder.glob("*.toml")) if folder.is_dir() else []
        if found:
            return found
    return []


def load_scene(path: str | Path | None = None) -> Scene:
    """Load a scene file; None is the built-in arena. A bare name such as "duel" that is not a file
    in the current directory names a shipped scene."""
    if path is None:
        return Scene()
    p = Path(path)
    if not p.exists() and p.suffix == "" and p.parent == Path("."):
        by_name = {s.stem: s for s in shipped_scenes()}
        if p.name in by_name:
            p = by_name[p.name]
    text = read_text_file(p, str(path), "scene file", MAX_SCENE_BYTES)
    return parse_scene(text, source=str(path) if p == Path(path) else str(p), path=p)


# Short override names (the CLI's flags) and the keys they set.
ALIASES = {
    "seed": "seed",
    "frames": "video.frames",
    "seconds": "video.seconds",
    "fps": "video.fps",
    "width": "video.width",
    "height": "video.height",
    "method": "solver.method",
}


def parse_size(text: str, name: str = "--size") -> tuple[int, int]:
    """"1280x720" -> (1280, 720); the range and evenness are checked with the scene."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(text))
    if not m:
        raise ValueError(f"{name}: expected WIDTHxHEIGHT such as 1280x720 (got {text!r})")
    return int(m.group(1)), int(m.group(2))


def scene_with(scene: Scene, **overrides: Any) -> Scene:
    """A copy of `scene` with some keys replaced, validated like a file. Keys are the short names
    in ALIASES, `size` ("WxH" or (w, h)), or dotted keys (`**{"characters.count": 10}`);
    None values are ignored, so CLI arguments can be passed straight through. `seconds` clears
    the scene's `frames`."""
    given = {k: v for k, v in overrides.items() if v is not None}
    if "frames" in given and "seconds" in given:
        raise ValueError("give frames or seconds, not both")
    labels: dict[str, str] = {}
    if "size" in given:
        size = given.pop("size")
        wh = parse_size(size, "size") if isinstance(size, str) else tuple(size)
        if len(wh) != 2:
            raise ValueError(f"size: expected (width, height) (got {size!r})")
        for name, value in zip(("width", "height"), wh):
            if name not in given:
                given[name] = value
                labels[name] = f"size={_show(size)}"
    raw = scene.to_dict()
    overridden: dict[str, str] = {}
    for name, value in given.items():
        key = ALIASES.get(name, name)
        if key not in ALL_KEYS:
            close = difflib.get_close_matches(key, [*ALIASES, *ALL_KEYS], n=1, cutoff=0.6)
            hint = f"; did you mean {close[0]}?" if close else ""
            raise ValueError(f"scene_with: unknown override {name!r}{hint}")
        if key == "seed":
            raw["seed"] = value
        else:
            section, sub = key.split(".")
            raw[section][sub] = _plain(value)
        overridden[key] = labels.get(name, f"{name}={_show(value)}")
    if "video.seconds" in overridden and "video.frames" not in overridden:
        raw["video"].pop("frames", None)
    source = str(scene.path) if scene.path is not None else DEFAULT_NAME
    return _Validator(source, overridden).build(raw, scene.path)


def check_table(table: Any, source: str, prefix: str = "") -> dict:
    """Check a raw table of scene keys on its own (every key known, every value valid) and return it.

    For tables that carry scene keys inside another file, such as a JOBS file's [overrides]: errors read
    like a scene's, `SOURCE: PREFIXsection.key: problem (got VALUE)`. Cross-key rules (a pool at least
    as large as the shooters, ...) need the whole scene: apply_table checks them.
    """
    check = _Validator(source, prefix=prefix)
    if not isinstance(table, dict):
        raise ValueError(f"{source}: {prefix.rstrip('.')}: must be a table of scene keys (got {_show(table)})")
    for name, value in table.items():
        if name == "seed":
            check.value("seed", _SEED_SPEC, value)
        elif name in SECTIONS:
            check.section(name, value)
        else:
            raise check.unknown(name, value, ["seed", *SECTIONS], "")
    return table


def apply_table(scene: Scene, table: dict, source: str) -> Scene:
    """`scene` with the keys of a checked raw table (check_table) replaced, validated like a file.

    A cross-key problem names the scene and where the keys came from, e.g. `duel.toml with override
    bullets.pool_size=1 from jobs.toml: bullets.pool_size: must be at least shooters.count (4), ...`.
    `video.seconds` without `video.frames` clears the scene's frames, as in scene_with.
    """
    raw = scene.to_dict()
    overridden: dict[str, str] = {}
    for name, value in table.items():
        if name == "seed":
            raw["seed"] = value
            overridden["seed"] = f"seed={_show(value)} from {source}"
            continue
        for key, sub in value.items():
            raw[name][key] = _plain(sub)
            overridden[f"{name}.{key}"] = f"{name}.{key}={_show(sub)} from {source}"
    if "video.seconds" in overridden and "video.frames" not in overridden:
        raw["video"].pop("frames", None)
    label = str(scene.path) if scene.path is not None else DEFAULT_NAME
    return _Validator(label, overridden).build(raw, scene.path)
