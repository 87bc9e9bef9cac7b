"""Scene files: TOML -> frozen dataclasses, with validation that names the file, the key and the value.

Every key is optional and the dataclass defaults *are* the arena scene, so `load_scene(None)` works
from any directory without the repo checkout; `scenes/arena.toml` spells the same values out.
Errors are one line, `FILE: key.sub: problem (got VALUE)`, raised as ValueError before anything
is allocated (a scene that would need more than 8 GiB is refused with the estimate in the message).

`crowd-ik scenes [FILE]` (`run_cli`) lists the shipped scenes, or checks one and prints its
effective values as TOML.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib.resources
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from crowd_ik.solvers.registry import DEFAULT as DEFAULT_METHOD, METHODS

MAX_CHARACTERS = 1_000_000
MAX_POOL_SIZE = 10_000_000
MAX_SHOOTERS = 100_000
MAX_FRAMES = 1_000_000
MAX_ITERATIONS = 10_000
MAX_WAYPOINTS = 100_000
MAX_SEED = 2**31 - 1  # seeds reach kernels as i32 scalars
MIN_SIZE, MAX_SIZE = 16, 7680
MIN_FPS, MAX_FPS = 1.0, 1000.0
MEMORY_LIMIT = 8 * 2**30
MAX_EXTENT = 1e4  # metres: |coordinates| and distances (the library's bound, crowd_ik.rig.MAX_EXTENT)
MIN_CAMERA_DISTANCE = 1e-3  # metres between camera.position and camera.look_at
MIN_CAMERA_TILT = 1e-3  # horizontal part of the unit viewing direction: below it the camera looks straight
#                         down (or up) and "up" in the picture is undefined
FLOAT32_MAX = 3.4028234663852886e38  # every number reaches the kernels as float32
MAX_SPEED = 1e6  # m/s, the player's and the bullets' (a step's travel and its square stay well inside float32)
MAX_SCALE = 1000.0  # characters.scale: a 1.75 km humanoid
MIN_FIRE_RATE, MAX_FIRE_RATE = 1e-6, 1e6  # shots per second (1 / fire_rate is a float32 time)
MIN_FOV_DEG = 0.01  # a narrower view's focal length in pixels overflows float32
MAX_AIM_HEIGHT = 1e18  # metres above its target a shot may aim (the game's ballistic estimate; its float32 square stays finite)

# Rough per-item footprints (host + device) used to refuse absurd scenes before allocating.
# A humanoid (~20 joints, ~37 DOF, 5 effectors): positions, quaternions and angles with their
# previous-step copies, DLS scratch (J^T J), collision capsules at both ends of a step, shards.
BYTES_PER_CHARACTER = {"humanoid": 12 * 1024, "chain": 4 * 1024}
# A bullet: position, velocity, previous position, age, owner, alive flag and an 8-point trail.
BYTES_PER_BULLET = 160
# A pixel: BGR frame (3) + depth (4) + shadow (4) + limb id (4) + the encoder's copy (3).
BYTES_PER_PIXEL = 18

DEFAULT_NAME = "arena"


# --------------------------------------------------------------------------------------------
# value checks: each spec turns a raw TOML value into a typed value or raises _Bad(problem)


class _Bad(Exception):
    """A problem with one value; `suffix` refines the key (e.g. "[2]"), `value` the reported value."""

    _SAME = object()

    def __init__(self, problem: str, suffix: str = "", value: Any = _SAME):
        super().__init__(problem)
        self.problem, self.suffix, self.value = problem, suffix, value


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _num(x: float) -> str:
    """A bound as written in a message: 0 not 0.0, 1000 not 1000.0."""
    return str(int(x)) if float(x).is_integer() else repr(float(x))


class _Int:
    def __init__(self, lo: int, hi: int, even: bool = False, unit: str = ""):
        self.lo, self.hi, self.even, self.unit = lo, hi, even, unit

    def parse(self, v: Any) -> int:
        if isinstance(v, bool):
            raise _Bad("must be an integer, not a boolean")
        if not isinstance(v, int):
            raise _Bad("must be an integer")
        if v < self.lo:
            if self.lo == 1:
                raise _Bad("must be a positive integer")
            if self.lo == 0:
                raise _Bad("must be zero or a positive integer")
            raise _Bad(f"must be from {self.lo} to {self.hi}{self.unit}")
        if v > self.hi:
            raise _Bad(f"must be at most {self.hi}{self.unit}")
        if self.even and v % 2:
            raise _Bad("must be even (H.264 with yuv420p needs even sizes)")
        return v


class _OptionalInt(_Int):
    """An int that may be absent (None); TOML has no null, so None only comes from the default."""

    def parse(self, v: Any) -> int | None:
        return None if v is None else super().parse(v)


class _Float:
    """A finite number in float32 (|x| <= 3.4e38, what the kernels receive) within [lo, hi] (open or closed
    ends; None = unbounded), `unit` for the message."""

    def __init__(self, lo: float | None = None, hi: float | None = None, lo_open: bool = True, hi_open: bool = False,
                 unit: str = ""):
        self.lo, self.hi, self.lo_open, self.hi_open, self.unit = lo, hi, lo_open, hi_open, unit

    def _range(self) -> str:
        if self.hi is None:
            if self.lo == 0:
                return "must be a positive number" if self.lo_open else "must be zero or positive"
            return f"must be {'>' if self.lo_open else '>='} {_num(self.lo)}"
        if self.lo is None:
            return f"must be {'<' if self.hi_open else '<='} {_num(self.hi)}{self.unit}"
        return (f"must be in {'(' if self.lo_open else '['}{_num(self.lo)}, {_num(self.hi)}{')' if self.hi_open else ']'}"
                f"{self.unit}")

    def parse(self, v: Any) -> float:
        if isinstance(v, bool):
            raise _Bad("must be a number, not a boolean")
        if not _is_number(v):
            raise _Bad("must be a number")
        try:
            x = float(v)
        except OverflowError:
            raise _Bad("must be a finite number") from None
        if not math.isfinite(x):
            raise _Bad("must be a finite number")
        if self.lo is not None and (x <= self.lo if self.lo_open else x < self.lo):
            raise _Bad(self._range())
        if self.hi is not None and (x >= self.hi if self.hi_open else x > self.hi):
            raise _Bad(self._range())
        if abs(x) > FLOAT32_MAX:
            raise _Bad("must be finite in float32 (|x| <= 3.4e38)")
        return x


class _Choice:
    def __init__(self, *options: str):
        self.options = options

    def parse(self, v: Any) -> str:
        listed = ", ".join(f'"{o}"' for o in self.options)
        if not isinstance(v, str):
            raise _Bad(f"must be a string, one of {listed}")
        if v not in self.options:
            close = difflib.get_close_matches(v.lower(), self.options, n=1, cutoff=0.5)
            hint = f'; did you mean "{close[0]}"?' if close else ""
            raise _Bad(f"must be one of {listed}{hint}")
        return v


def _finite_numbers(v: Any, n: int, limit: float = MAX_EXTENT) -> tuple[float, ...] | None:
    """`v` as a tuple of n floats within +-limit, or None when it is not a list of n such numbers."""
    if not isinstance(v, (list, tuple)) or len(v) != n or not all(_is_number(c) for c in v):
        return None
    try:
        out = tuple(float(c) for c in v)
    except OverflowError:
        return None
    return out if all(math.isfinite(c) and abs(c) <= limit for c in out) else None


class _Vec3:
    """A world point [x, y, z], each within +-MAX_EXTENT metres."""

    def parse(self, v: Any) -> tuple[float, float, float]:
        out = _finite_numbers(v, 3)
        if out is None:
            if isinstance(v, (list, tuple)) and len(v) == 3 and all(_is_number(c) for c in v):
                raise _Bad(f"must be 3 finite numbers [x, y, z] within +-{_num(MAX_EXTENT)} m")
            raise _Bad("must be a list of 3 numbers [x, y, z]")
        return out  # type: ignore[return-value]


class _Path:
    def parse(self, v: Any) -> tuple[tuple[float, float], ...]:
        if not isinstance(v, (list, tuple)) or not v:
            raise _Bad("must be a list of one or more [x, z] pairs")
        if len(v) > MAX_WAYPOINTS:
            raise _Bad(f"must have at most {MAX_WAYPOINTS} waypoints", value=f"{len(v)} waypoints")
        out = []
        for i, p in enumerate(v):
            pair = _finite_numbers(p, 2)
            if pair is None:
                raise _Bad(f"must be an [x, z] pair of finite numbers within +-{_num(MAX_EXTENT)} m",
                           suffix=f"[{i}]", value=p)
            out.append(pair)
        return tuple(out)


def _key(default: Any, spec: Any, doc: str) -> Any:
    return field(default=default, metadata={"spec": spec, "doc": doc})


# --------------------------------------------------------------------------------------------
# the schema: the defaults are the arena scene


@dataclass(frozen=True)
class Characters:
    """The crowd: how many characters, how they stand, which rig and how big."""

    count: int = _key(40, _Int(1, MAX_CHARACTERS), "number of characters")
    layout: str = _key("grid", _Choice("grid", "ring", "random"), "how the roots are placed")
    spacing: float = _key(1.5, _Float(0, MAX_EXTENT, unit=" m"), "distance between neighbouring roots, metres")
    rig: str = _key("humanoid", _Choice("humanoid", "chain"), "the skeleton every character uses")
    scale: float = _key(1.0, _Float(0, MAX_SCALE), "size factor on the rig (1 = a 1.75 m humanoid)")
    walk_speed: float = _key(1.0, _Float(0, 10.0, lo_open=False, unit=" m/s"),
                             "bystanders' mean wandering speed, metres per second (0: they stand)")


@dataclass(frozen=True)
class Player:
    """The player walks the waypoints at constant speed; time moves when it moves."""

    path: tuple[tuple[float, float], ...] = _key(
        ((0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0), (0.0, 0.0)), _Path(), "(x, z) waypoints, metres"
    )
    speed: float = _key(1.5, _Float(0, MAX_SPEED, unit=" m/s"), "walking speed, metres per second")


@dataclass(frozen=True)
class Shooters:
    """The shooters that aim with IK and fire at the crowd."""

    count: int = _key(4, _Int(1, MAX_SHOOTERS), "number of shooters")
    placement: str = _key("ring", _Choice("ring", "line"), "ring around the crowd, or a line in front of it")
    radius: float = _key(12.0, _Float(0, MAX_EXTENT, unit=" m"), "ring radius or distance of the line from the centre, metres")
    fire_rate: float = _key(1.0, _Float(MIN_FIRE_RATE, MAX_FIRE_RATE, lo_open=False), "shots per second per shooter, world time")
    spread_deg: float = _key(2.0, _Float(0, 90, lo_open=False, hi_open=True), "aim spread half-angle, degrees")


@dataclass(frozen=True)
class Bullets:
    """Bullet physics and the fixed-size pool they live in."""

    speed: float = _key(25.0, _Float(0, MAX_SPEED, unit=" m/s"), "muzzle speed, metres per second")
    radius: float = _key(0.03, _Float(0, MAX_EXTENT, unit=" m"), "collision radius, metres")
    gravity: float = _key(9.81, _Float(0, lo_open=False), "downward acceleration, metres per second squared")
    drag: float = _key(0.0, _Float(0, lo_open=False), "quadratic drag coefficient: dv/dt = -drag |v| v, 1 per metre")
    pool_size: int = _key(4096, _Int(1, MAX_POOL_SIZE), "bullet slots allocated once")
    lifetime: float = _key(3.0, _Float(0), "seconds of world time before a bullet is retired")


@dataclass(frozen=True)
class Time:
    """SUPERHOT time: the scale rises with the player's speed and falls toward `floor` at rest."""

    floor: float = _key(0.05, _Float(0, 1, lo_open=True, hi_open=False), "time scale while the player stands still")
    response: float = _key(4.0, _Float(0), "how fast the time scale follows the player, 1 per second")


@dataclass(frozen=True)
class Solver:
    """The IK method and its per-frame budget."""

    method: str = _key(DEFAULT_METHOD, _Choice(*METHODS), "IK method")
    iterations: int = _key(8, _Int(1, MAX_ITERATIONS), "iterations per frame")
    tolerance: float = _key(0.005, _Float(0), "converged when every effector is this close, metres")


@dataclass(frozen=True)
class Camera:
    """A perspective camera looking at a point, y up; "follow" keeps position - look_at as an offset from
    the player's pelvis (low-passed), "fixed" stays where it is."""

    mode: str = _key("follow", _Choice("follow", "fixed"), "follow the player, or stay fixed")
    position: tuple[float, float, float] = _key((0.0, 4.5, 8.5), _Vec3(), "eye position, metres")
    look_at: tuple[float, float, float] = _key((0.0, 1.0, 0.0), _Vec3(), "point at the centre of the frame, metres")
    fov_deg: float = _key(50.0, _Float(MIN_FOV_DEG, 180, lo_open=False, hi_open=True), "vertical field of view, degrees")


@dataclass(frozen=True)
class Video:
    """Frame size, rate and length; `frames` wins over `seconds` when given."""

    width: int = _key(1280, _Int(MIN_SIZE, MAX_SIZE, even=True, unit=" pixels"), "frame width, pixels")
    height: int = _key(720, _Int(MIN_SIZE, MAX_SIZE, even=True, unit=" pixels"), "frame height, pixels")
    fps: float = _key(30.0, _Float(MIN_FPS, MAX_FPS, lo_open=False), "frames per second")
    seconds: float = _key(10.0, _Float(0, MAX_FRAMES / MIN_FPS, unit=" s"), "video length, seconds")
    frames: int | None = _key(None, _OptionalInt(1, MAX_FRAMES), "video length in frames (overrides seconds)")


SECTIONS: dict[str, type] = {
    "characters": Characters,
    "player": Player,
    "shooters": Shooters,
    "bullets": Bullets,
    "time": Time,
    "solver": Solver,
    "camera": Camera,
    "video": Video,
}
_SEED_SPEC = _Int(0, MAX_SEED)


@dataclass(frozen=True)
class Scene:
    """A whole scene. `path` is the source file (None for the built-in arena) and is not compared."""

    seed: int = 0
    characters: Characters = field(default_factory=Characters)
    player: Player = field(default_factory=Player)
    shooters: Shooters = field(default_factory=Shooters)
    bullets: Bullets = field(default_factory=Bullets)
    time: Time = field(default_factory=Time)
    solver: Solver = field(default_factory=Solver)
    camera: Camera = field(default_factory=Camera)
    video: Video = field(default_factory=Video)
    path: Path | None = field(default=None, compare=False)

    @property
    def name(self) -> str:
        """The file stem, or "arena" for the built-in default."""
        return self.path.stem if self.path is not None else DEFAULT_NAME

    @property
    def n_frames(self) -> int:
        """Frames to render: `video.frames` if given, else round(seconds * fps)."""
        v = self.video
        return v.frames if v.frames is not None else int(round(v.seconds * v.fps))

    def to_dict(self) -> dict:
        """Plain nested dict of every key (lists, not tuples; no `frames` when it is unset)."""
        out: dict[str, Any] = {"seed": self.seed}
        for section in SECTIONS:
            values = dataclasses.asdict(getattr(self, section))
            out[section] = {k: _plain(v) for k, v in values.items() if v is not None}
        return out

    def to_toml(self) -> str:
        """Every effective value as TOML that loads back to an equal scene."""
        lines = [f"seed = {self.seed}"]
        for section, values in self.to_dict().items():
            if section == "seed":
                continue
            lines += ["", f"[{section}]"]
            lines += [f"{k} = {_toml_value(v)}" for k, v in values.items()]
            if section == "video" and self.video.frames is None:
                lines.append(f"# frames not set: seconds * fps = {self.n_frames}")
        return "\n".join(lines) + "\n"


def _plain(v: Any) -> Any:
    return [_plain(x) for x in v] if isinstance(v, (list, tuple)) else v


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {v!r}")


def _show(v: Any, limit: int = 60) -> str:
    """A value as it would be written in TOML, shortened for a one-line message."""
    if isinstance(v, float) and not math.isfinite(v):
        text = "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    elif isinstance(v, dict):
        text = "{" + ", ".join(f"{k} = {_show(x)}" for k, x in v.items()) + "}"
    elif isinstance(v, (list, tuple)):
        text = "[" + ", ".join(_show(x) for x in v) + "]"
    elif isinstance(v, (bool, int, float, str)):
        text = _toml_value(v)
    else:
        text = str(v)
    return text if len(text) <= limit else text[: limit - 3] + "..."


# --------------------------------------------------------------------------------------------
# validation of a raw TOML dict


def _field_specs(cls: type) -> dict[str, Any]:
    return {f.name: f.metadata["spec"] for f in dataclasses.fields(cls)}


ALL_KEYS: tuple[str, ...] = ("seed",) + tuple(f"{s}.{k}" for s, cls in SECTIONS.items() for k in _field_specs(cls))


class _Validator:
    """Builds a Scene from a raw dict; the first problem becomes one ValueError line."""

    def __init__(self, source: str, overridden: dict[str, str] | None = None, prefix: str = ""):
        self.source = source
        self.overridden = overridden or {}
        self.prefix = prefix  # written before every key in messages ("overrides." for a JOBS file's table)

    def error(self, key: str, problem: str, value: Any = _Bad._SAME, involved: tuple[str, ...] = ()) -> ValueError:
        keys = involved or (key.split("[")[0],)
        names = list(dict.fromkeys(self.overridden[k] for k in keys if k in self.overridden))
        label = self.source if not names else f"{self.source} with override {', '.join(names)}"
        got = "" if value is _Bad._SAME else f" (got {_show(value)})"
        return ValueError(f"{label}: {self.prefix}{key}: {problem}{got}")

    def unknown(self, key: str, value: Any, known: list[str], prefix: str) -> ValueError:
        close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
        if close:
            hint = f"did you mean {prefix}{close[0]}?"
        elif not prefix:
            # a sub-key written at the top level, e.g. `count = 40` outside [characters]
            homes = [k for k in ALL_KEYS if k.split(".")[-1] == key and "." in k]
            hint = f"did you mean {' or '.join(homes)}?" if homes else f"known: {', '.join(known)}"
        else:
            hint = f"known keys: {', '.join(known)}"
        what = "unknown section or key" if not prefix else "unknown key"
        return self.error(prefix + key, f"{what}; {hint}", value)

    def build(self, raw: dict, path: Path | None) -> Scene:
        kwargs: dict[str, Any] = {"path": path}
        top = ["seed", *SECTIONS]
        for name, value in raw.items():
            if name == "seed":
                kwargs["seed"] = self.value("seed", _SEED_SPEC, value)
            elif name in SECTIONS:
                kwargs[name] = self.section(name, value)
            else:
                raise self.unknown(name, value, top, "")
        scene = Scene(**kwargs)
        self.cross_check(scene)
        return scene

    def value(self, key: str, spec: Any, value: Any) -> Any:
        try:
            return spec.parse(value)
        except _Bad as bad:
            shown = value if bad.value is _Bad._SAME else bad.value
            raise self.error(key + bad.suffix, bad.problem, shown) from None

    def section(self, name: str, table: Any) -> Any:
        cls = SECTIONS[name]
        if not isinstance(table, dict):
            raise self.error(name, f"must be a table, e.g. [{name}] or {name} = {{ ... }}", table)
        specs = _field_specs(cls)
        values = {}
        for key, value in table.items():
            if key not in specs:
                raise self.unknown(key, value, list(specs), f"{name}.")
            values[key] = self.value(f"{name}.{key}", specs[key], value)
        return cls(**values)

    def cross_check(self, scene: Scene) -> None:
        cam = scene.camera
        view = [a - b for a, b in zip(cam.look_at, cam.position)]
        distance = math.sqrt(sum(c * c for c in view))
        camera_keys = ("camera.look_at", "camera.position")
        if distance < MIN_CAMERA_DISTANCE:
            raise self.error("camera.look_at", f"must be at least {_num(MIN_CAMERA_DISTANCE * 1000)} mm from camera.position "
                             f"{_show(list(cam.position))}", list(cam.look_at), involved=camera_keys)
        if math.hypot(view[0], view[2]) < MIN_CAMERA_TILT * distance:
            raise self.error("camera.look_at", f"is straight {'below' if view[1] < 0 else 'above'} camera.position "
                             f"{_show(list(cam.position))}, so the picture has no up direction; move one of them "
                             f"sideways (by at least {_num(MIN_CAMERA_TILT)} of their distance)", list(cam.look_at),
                             involved=camera_keys)
        if scene.bullets.pool_size < scene.shooters.count:
            raise self.error("bullets.pool_size", f"must be at least shooters.count ({scene.shooters.count}), one slot per shooter",
                             scene.bullets.pool_size, involved=("bullets.pool_size", "shooters.count"))
        v = scene.video
        if v.frames is None:
            n = scene.n_frames
            involved = ("video.seconds", "video.fps")
            if n < 1:
                raise self.error("video.seconds", f"gives no frames at {_num(v.fps)} fps (seconds * fps < 0.5)", v.seconds, involved=involved)
            if n > MAX_FRAMES:
                raise self.error("video.seconds", f"gives {n} frames at {_num(v.fps)} fps, more than {MAX_FRAMES}", v.seconds, involved=involved)
        need = memory_estimate(scene)
        if need["total"] > MEMORY_LIMIT:
            parts = {k: b for k, b in need.items() if k != "total"}
            biggest = max(parts, key=parts.get)
            key = {"characters": "characters.count", "bullets": "bullets.pool_size", "frame": "video.width"}[biggest]
            shown = {"characters.count": scene.characters.count, "bullets.pool_size": scene.bullets.pool_size,
                     "video.width": f"{v.width}x{v.height}"}[key]
            detail = " + ".join(f"{k} {_gib(b)}" for k, b in parts.items())
            raise self.error(key, f"scene needs about {_gib(need['total'])} ({detail}), more than the {_gib(MEMORY_LIMIT)} limit",
                             shown, involved=("characters.count", "bullets.pool_size", "video.width", "video.height", "characters.rig"))
        c = scene.characters
        reach = crowd_extent(scene) + 2.0 * c.spacing
        if reach > MAX_EXTENT:
            raise self.error("characters.spacing", f"puts {c.count} characters ({c.layout}) up to {reach:.4g} m from the "
                             f"centre, beyond {_num(MAX_EXTENT)} m", c.spacing,
                             involved=("characters.spacing", "characters.count", "characters.layout"))
        sh = scene.shooters
        if sh.placement == "line" and sh.count - 1 > MAX_EXTENT:
            raise self.error("shooters.count", f"puts a line of shooters 2 m apart up to {sh.count - 1} m from the centre, "
                             f"beyond {_num(MAX_EXTENT)} m", sh.count, involved=("shooters.count", "shooters.placement"))
        b = scene.bullets
        shot = longest_shot(scene)
        height = aim_height(shot, b.speed, b.gravity, b.drag)
        if not height <= MAX_AIM_HEIGHT:
            raise self.error("bullets.speed", f"cannot carry a shot {shot:.4g} m far under gravity {_num(b.gravity)} and drag "
                             f"{_num(b.drag)}: it would aim {height:.3g} m above its target (at most {MAX_AIM_HEIGHT:g}); "
                             f"raise bullets.speed or lower bullets.gravity, bullets.drag or shooters.radius", b.speed,
                             involved=("bullets.speed", "bullets.gravity", "bullets.drag", "shooters.radius", "shooters.count",
                                       "characters.count", "characters.spacing", "characters.scale", "player.path"))


def crowd_extent(scene: Scene) -> float:
    """Metres from the centre to the farthest character root along x or z (crowd_ik.game.layout's layouts:
    a centred square grid, jittered by up to a quarter spacing for "random", or a ring)."""
    c = scene.characters
    n, sp = c.count, c.spacing
    if c.layout == "ring":
        return max(sp * n / (2.0 * math.pi), sp)
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    half = 0.5 * (max(cols, rows) - 1) * sp
    return half + (0.25 * sp if c.layout == "random" else 0.0)


def longest_shot(scene: Scene) -> float:
    """An upper bound on the horizontal distance of any shot, metres: a shooter at the far side of the
    crowd, or the player anywhere on its path, to a shooter (plus a character's height)."""
    sh = scene.shooters
    farthest_shooter = sh.radius + (sh.count - 1 if sh.placement == "line" else 0.0)
    farthest_target = max(crowd_extent(scene) * math.sqrt(2.0), max(math.hypot(x, z) for x, z in scene.player.path))
    return farthest_shooter + farthest_target + 2.0 * scene.characters.scale


def aim_height(distance: float, speed: float, gravity: float, drag: float) -> float:
    """Metres above a target `distance` away that a shot aims, by the game's ballistic estimate
    (crowd_ik.game.aim.ballistic_direction: four fixed-point steps on the flight time); large or inf when
    the target is far beyond the bullets' range."""
    t = distance / speed
    height = 0.0
    for _ in range(4):
        t_eff = t * (1.0 + 0.5 * drag * speed * t)
        height = 0.5 * gravity * t_eff * t_eff
        t = math.hypot(distance, height) / speed
    return height


def _gib(n: int) -> str:
    """Bytes as GiB, or MiB below 1 GiB."""
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.1f} MiB"


def memory_estimate(scene: Scene) -> dict[str, int]:
    """Approximate bytes the scene will allocate: characters, bullets, frame buffers, and total."""
    c, b, v = scene.characters, scene.bullets, scene.video
    parts = {
        "characters": c.count * BYTES_PER_CHARACTER[c.rig],
        "bullets": b.pool_size * BYTES_PER_BULLET,
        "frame": v.width * v.height * BYTES_PER_PIXEL,
    }
    parts["total"] = sum(parts.values())
    return parts


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
    _check_nesting(text, source)
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = _LINE.search(msg)
        where = f"line {m.group(1)}, column {m.group(2)}: " if m else ""
        problem = _LINE.sub("", msg).strip()
        raise ValueError(f"{source}: {where}invalid TOML: {problem}") from None
    return _Validator(source).build(raw, path)


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
    if not p.exists():
        raise FileNotFoundError(f"{path}: no such scene file")
    if p.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, not a scene file")
    if not p.is_file():  # a FIFO would block, /dev/zero never ends
        raise ValueError(f"{path}: not a regular file")
    size = p.stat().st_size
    if size > MAX_SCENE_BYTES:
        raise ValueError(f"{path}: {size:,} bytes; a scene file holds at most {MAX_SCENE_BYTES:,}")
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or exc})") from None
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


# --------------------------------------------------------------------------------------------
# `crowd-ik scenes [FILE]`


def describe(path: Path) -> str:
    """The first comment line of a scene file, without the '#'."""
    for line in path.read_text(encoding="utf-8").splitlines():
        s = line.strip()
        if s.startswith("#"):
            return s.lstrip("#").strip()
        if s:
            break
    return ""


def scene_table(paths: list[Path]) -> str:
    """A text table of scenes: name, characters, shooters, frames, size, description."""
    scenes = [(load_scene(p), describe(p)) for p in paths]
    scenes.sort(key=lambda s: (s[0].characters.count, s[0].name))
    header = ("name", "characters", "shooters", "frames", "size", "description")
    rows = [header] + [
        (s.name, str(s.characters.count), str(s.shooters.count), str(s.n_frames),
         f"{s.video.width}x{s.video.height}", d)
        for s, d in scenes
    ]
    widths = [max(len(r[i]) for r in rows) for i in range(len(header) - 1)]
    right = {1, 2, 3}
    lines = []
    for r in rows:
        cells = [c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths))]
        lines.append("  ".join(cells) + "  " + r[-1])
    return "\n".join(lines)


def run_cli(args) -> int:
    """`crowd-ik scenes`: table of the shipped scenes; `crowd-ik scenes FILE`: check one."""
    if args.file is None:
        paths = shipped_scenes()
        if not paths:
            raise RuntimeError("no shipped scenes found (looked beside the package and in crowd_ik/scenes)")
        print(scene_table(paths))
        print(f"\n{len(paths)} scenes in {paths[0].parent}; check one with: crowd-ik scenes FILE")
        return 0
    scene = load_scene(args.file)
    need = memory_estimate(scene)
    print(f"{args.file}: ok")
    print(f"# {scene.name}: {scene.n_frames} frames, estimated memory {_gib(need['total'])}")
    print(scene.to_toml(), end="")
    return 0
