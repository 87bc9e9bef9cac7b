"""Scene validation: a raw TOML dict -> a Scene, checking each value and what the values imply together
(extents, the camera, shots the ballistic aim can carry, memory); the first problem is one ValueError
line `FILE: key.sub: problem (got VALUE)`."""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any

from crowd_ik.scene_schema import (
    _SEED_SPEC, ALL_KEYS, BYTES_PER_BULLET, BYTES_PER_CHARACTER, BYTES_PER_PIXEL, MAX_AIM_HEIGHT, MAX_EXTENT, MAX_FRAMES,
    MEMORY_LIMIT, MIN_CAMERA_DISTANCE, MIN_CAMERA_TILT, SECTIONS, Scene, _Bad, _field_specs, _num, _show,
)

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
