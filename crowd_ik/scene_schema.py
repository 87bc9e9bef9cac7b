"""The scene schema: every key of a scene file as a frozen dataclass field with its default, bounds and
help, and the value specs that check them (crowd_ik/scene.py loads files with it).

Every key is optional and the dataclass defaults *are* the arena scene, so `load_scene(None)` works
from any directory without the repo checkout; `scenes/arena.toml` spells the same values out.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
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
