"""The player's inputs: one row per simulated video frame, as recorded by live play and replayed headless.

    frame,move_x,move_z,aim_x,aim_y,aim_z,fire
frame counts from 0 in order; move_x, move_z in [-1, 1] (world x and z; the player walks at
move * player.speed); aim_* the world point aimed at (metres); fire 0 or 1. A first comment line
`# crowd-ik play inputs: scene=... seed=... fps=... size=WxH solver=...` keeps the session's
settings: a replay (`crowd-ik play SCENE --inputs F.csv -o OUT.mp4`) uses them unless the command
line gives others, so by default it simulates exactly the recorded session, frame for frame.
Values are rounded to 6 decimals before they are applied, live or replayed, so the text holds
exactly what was simulated. Bad rows raise ValueError("F.csv:LINE: problem (got value)").
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from crowd_ik.game.player import MAX_AIM  # the bound the player's steering applies
from crowd_ik.io.csv_table import finite, read_table

HEADER = ("frame", "move_x", "move_z", "aim_x", "aim_y", "aim_z", "fire")
SETTINGS_TAG = "# crowd-ik play inputs:"
SETTING_KEYS = ("scene", "seed", "fps", "size", "solver")
DECIMALS = 6  # inputs are rounded to this many decimals before they are applied
MAX_ROWS = 1_000_000


def _round(v: float) -> float:
    return float(round(float(v), DECIMALS)) + 0.0  # + 0.0 turns -0.0 into 0.0


@dataclass(frozen=True)
class PlayerInput:
    """The player's input for one video frame: move (x, z) in [-1, 1], aim (3,) world point, fire."""

    move: tuple[float, float] = (0.0, 0.0)
    aim: tuple[float, float, float] = (0.0, 1.3, 0.0)
    fire: bool = False

    def canonical(self) -> PlayerInput:
        """Move cut to length <= 1, every value rounded to DECIMALS (what is applied and recorded)."""
        mx, mz = (float(v) for v in self.move)
        ax, ay, az = (float(v) for v in self.aim)
        if not all(math.isfinite(v) for v in (mx, mz, ax, ay, az)):
            raise ValueError(f"player input: expected finite numbers (got move {self.move}, aim {self.aim})")
        n = math.hypot(mx, mz)
        if n > 1.0:
            mx, mz = mx / n, mz / n
        return PlayerInput((_round(mx), _round(mz)), (_round(ax), _round(ay), _round(az)), bool(self.fire))

    def row(self, frame: int) -> str:
        """The CSV row of this input at `frame` (values as Python writes them: they read back exactly)."""
        values = [*self.move, *self.aim]
        return f"{frame}," + ",".join(repr(float(v)) for v in values) + f",{int(bool(self.fire))}"


def scene_settings(scene) -> dict[str, str]:
    """The settings a replay needs to simulate the same session: name, seed, fps, size, solver."""
    v = scene.video
    return {"scene": scene.name, "seed": str(scene.seed), "fps": repr(float(v.fps)),
            "size": f"{v.width}x{v.height}", "solver": scene.solver.method}


def format_inputs(log, settings: dict[str, str] | None = None) -> str:
    """The CSV text of a list of PlayerInput (canonical values), with the settings comment line."""
    lines = []
    if settings:
        lines.append(SETTINGS_TAG + " " + " ".join(f"{k}={settings[k]}" for k in SETTING_KEYS if k in settings))
    lines.append(",".join(HEADER))
    lines += [inp.canonical().row(k) for k, inp in enumerate(log)]
    return "\n".join(lines) + "\n"


def write_inputs(path, log, settings: dict[str, str] | None = None, force: bool = False) -> Path:
    """Write the inputs CSV atomically; never clobbers without force."""
    from crowd_ik.io.output import write_text

    return write_text(path, format_inputs(log, settings), force=force)


@dataclass(frozen=True)
class InputLog:
    """A read inputs file: one PlayerInput per simulated frame, and the recorded settings."""

    path: str
    inputs: tuple[PlayerInput, ...]
    settings: dict[str, str] = field(default_factory=dict)
    settings_line: int = 0  # line of the settings comment (0: none)

    def __len__(self) -> int:
        return len(self.inputs)


def _setting_ok(key: str, value: str) -> bool:
    from crowd_ik.scene import parse_size

    try:
        if key == "seed":
            return int(value) >= 0
        if key == "fps":
            return math.isfinite(float(value)) and float(value) > 0
        if key == "size":
            parse_size(value)
        return True
    except ValueError:
        return False


def _parse_settings(path: str, number: int, text: str) -> dict[str, str]:
    """key=value tokens of the settings comment; other tokens are notes for people."""
    out: dict[str, str] = {}
    for token in text[len(SETTINGS_TAG):].split():
        key, sep, value = token.partition("=")
        if sep and key in SETTING_KEYS:
            if not _setting_ok(key, value):
                raise ValueError(f"{path}:{number}: {key}: not a valid setting (got {value!r})")
            out[key] = value
    return out


def load_inputs(path) -> InputLog:
    """Read an inputs CSV (see the module docstring). Problems raise ValueError("F.csv:LINE: ...")."""
    path = os.fspath(path)
    if not Path(path).is_file():
        if Path(path).is_dir():
            raise ValueError(f"--inputs: {path}: is a folder, an inputs .csv file is expected")
        raise FileNotFoundError(f"--inputs: {path}: no such file")
    found: dict = {}

    def settings_comment(number: int, text: str) -> None:
        if text.startswith(SETTINGS_TAG) and not found:
            found.update(settings=_parse_settings(path, number, text), line=number)

    table = read_table(path, HEADER, ",".join(HEADER), max_rows=MAX_ROWS, on_comment=settings_comment)
    rows: list[PlayerInput] = []
    for number, fields in table.rows:
        if fields[0] != str(len(rows)):
            raise ValueError(f"{path}:{number}: frame: expected {len(rows)} (rows count frames from 0 in order) "
                             f"(got {fields[0]!r})")
        values = []
        for name, f in zip(HEADER[1:6], fields[1:6]):
            v = finite(path, number, name, f)
            if name.startswith("move") and abs(v) > 1.0:
                raise ValueError(f"{path}:{number}: {name}: expected a number in [-1, 1] (got {f})")
            if name.startswith("aim") and abs(v) > MAX_AIM:
                raise ValueError(f"{path}:{number}: {name}: expected metres within +-{MAX_AIM:g} (got {f})")
            values.append(v)
        if fields[6] not in ("0", "1"):
            raise ValueError(f"{path}:{number}: fire: expected 0 or 1 (got {fields[6]!r})")
        rows.append(PlayerInput((values[0], values[1]), tuple(values[2:5]), fields[6] == "1"))
    settings, settings_line = found.get("settings", {}), found.get("line", 0)
    return InputLog(path, tuple(rows), settings, settings_line)
