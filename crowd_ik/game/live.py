"""Live play: the World driven by the player's inputs, in Taichi's GUI window or replayed headless.

`crowd-ik play SCENE --live` opens a window of the scene's video size (or --size). The player
walks with WASD or the arrow keys (camera-relative) or toward the cursor while the right mouse
button is held; the mouse aims its right arm by IK and a left click fires a bullet at the aim
point (the aim snaps to a standing shooter's chest near the cursor); a shooter the player's bullet
hits is down: it shatters and stops firing. Space pauses; Esc (or closing the window) quits. Time
moves only while the player moves (the scene's time scale: World.step). The HUD shows the time
scale, hits, dodges and shooters down (the World's lines) and the window's frames per second; a
crosshair marks the aim.

Inputs, one row per simulated video frame (paused frames are neither simulated nor recorded):
    frame,move_x,move_z,aim_x,aim_y,aim_z,fire
frame counts from 0 in order; move_x, move_z in [-1, 1] (world x and z; the player walks at
move * player.speed); aim_* the world point aimed at (metres); fire 0 or 1. A first comment line
`# crowd-ik play inputs: scene=... seed=... fps=... size=WxH solver=...` keeps the session's
settings: a replay (`crowd-ik play SCENE --inputs F.csv -o OUT.mp4`) uses them unless the command
line gives others, so by default it simulates exactly the recorded session, frame for frame.
Values are rounded to 6 decimals before they are applied, live or replayed, so the text holds
exactly what was simulated. Bad rows raise ValueError("F.csv:LINE: problem (got value)").

A row is applied by :class:`Session`: World.set_player_input (the walk steered by
:class:`SteeredWalker`, a bullet on fire) and World.step(); the same code runs live and replayed.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from crowd_ik.game.world import ARM_REACH, Walker, World

HEADER = ("frame", "move_x", "move_z", "aim_x", "aim_y", "aim_z", "fire")
SETTINGS_TAG = "# crowd-ik play inputs:"
SETTING_KEYS = ("scene", "seed", "fps", "size", "solver")
DECIMALS = 6  # inputs are rounded to this many decimals before they are applied
MAX_ROWS = 1_000_000
MAX_AIM = 1e6  # metres: aim points farther out than this are refused
AIM_FAR = 60.0  # m: a ray that never meets the aim plane aims this far along itself
CHEST_HEIGHT = 1.3  # m (times characters.scale): the plane the mouse aims in
SNAP_FRACTION = 0.035  # a shooter's chest within this fraction of the window height snaps the aim
WALK_DEADZONE = 0.2  # m: walking toward the cursor stops this close to it
FACE_MIN = 0.3  # m: an aim point closer than this (horizontally) does not turn the player
WINDOW_TITLE = "crowd-ik play"
WARMUP = 5  # played frames left out of the mean fps (the first ones compile kernels)
LEGEND = "WASD / arrows / right-drag: move   mouse: aim   click: fire   Space: pause   Esc: quit"


def no_display_message(scene_arg) -> str:
    scene = scene_arg if scene_arg else "SCENE"
    return (f"--live needs a display; render headless instead: crowd-ik play {scene} -o OUT.mp4 "
            f"(or --inputs F.csv)")


# ------------------------------------------------------------------------------------------------
# one frame of input


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


# ------------------------------------------------------------------------------------------------
# the steered walk and the world that counts the player's shots


class SteeredWalker(Walker):
    """The player's Walker steered by hand: each update moves the root by velocity * dt (instead of
    along the path) and keeps the procedural stepping, arm swing and pelvis bob of the walk.

    It takes over the state of the walker it replaces (position, heading, planted feet, clock).
    The player faces the aim point when one is set (else the way it walks, else it keeps its
    heading), and IK holds the right hand ARM_REACH from the shoulder on the line to the aim.
    """

    def __init__(self, walker: Walker):  # not super().__init__: that would restart the path walk
        self.__dict__.update(vars(walker))
        self.velocity = np.zeros(2)  # m/s in x, z
        self.aim: np.ndarray | None = None
        self._goal = (float(self.root[0]), float(self.root[2]))
        names = self.body.rig.effector_names
        self._hand_effector = names.index("hand_r") if "hand_r" in names else None

    def steer(self, move, aim=None) -> None:
        """move (x, z), each in [-1, 1] (cut to length 1): velocity = move * speed; aim (3,) or None."""
        m = np.asarray(move, np.float64).reshape(-1)
        if m.shape != (2,) or not np.all(np.isfinite(m)) or np.any(np.abs(m) > 1.0):
            raise ValueError(f"set_player_input: move: expected (x, z) with each in [-1, 1] (got {move!r})")
        n = float(np.hypot(*m))
        self.velocity = (m / n if n > 1.0 else m) * self.speed
        if aim is None:
            self.aim = None
            return
        a = np.asarray(aim, np.float64).reshape(-1)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(np.abs(a) > MAX_AIM):
            raise ValueError(f"set_player_input: aim: expected a finite world point (x, y, z) (got {aim!r})")
        self.aim = a.astype(np.float32)

    def _position(self, t: float) -> tuple[float, float]:
        return self._goal

    def _heading(self, t: float) -> float:
        if self.aim is not None:
            dx, dz = float(self.aim[0] - self.root[0]), float(self.aim[2] - self.root[2])
            if math.hypot(dx, dz) > FACE_MIN * self.body.scale:
                return math.atan2(dx, dz)
        vx, vz = self.velocity
        if math.hypot(vx, vz) > 1e-9:
            return math.atan2(vx, vz)
        return self.yaw

    def update(self, dt: float):
        self._goal = (float(self.root[0] + self.velocity[0] * dt), float(self.root[2] + self.velocity[1] * dt))
        root, yaw, targets, speed = super().update(dt)
        b = self.body
        if self.aim is not None and self._hand_effector is not None and b.humanoid:
            ground = (np.asarray(root) * [1.0, 0.0, 1.0])[None].astype(np.float32)
            shoulder = b.point(b.shoulder_r, ground, np.array([yaw], np.float32))[0]
            shoulder[1] += root[1] - b.rest_root_y
            d = self.aim - shoulder
            n = float(np.linalg.norm(d))
            if n > 1e-6:
                targets[self._hand_effector] = shoulder + d * (ARM_REACH * b.scale / n)
        return root, yaw, targets, speed


class PlayerWorld(World):
    """A World played by hand: counts the player's shots, and its HUD's frame line has no total
    (a live session has no set length)."""

    def __init__(self, scene, autofire: bool = True, hud_timings: bool | None = None):
        super().__init__(scene, autofire=autofire, hud_timings=hud_timings)
        self.player_shots = 0

    def set_player_input(self, move, aim=None, fire: bool = False) -> np.ndarray:
        slots = super().set_player_input(move, aim, fire)
        self.player_shots += len(slots)
        return slots

    def hud_lines(self) -> list[str]:
        lines = super().hud_lines()
        return [f"frame {self.frame}   world {self.world_time:.2f} s   shots {self.player_shots}"
                if line.startswith("frame ") else line for line in lines]

    def player_position(self) -> np.ndarray:
        """(3,) float64 world position of the player's root (on the ground: y = 0)."""
        return np.asarray(self.walker.root, np.float64) * [1.0, 0.0, 1.0]


class Session:
    """A World played by inputs: each :meth:`advance` applies one input and simulates one video
    frame; the canonical inputs applied are kept in `log` (what --record writes)."""

    def __init__(self, world: World):
        if world.frame != 0:
            raise ValueError(f"Session: expected a fresh World at frame 0 (got frame {world.frame})")
        self.world = world
        self.log: list[PlayerInput] = []

    def advance(self, inp: PlayerInput) -> None:
        inp = inp.canonical()
        self.world.set_player_input(inp.move, inp.aim, inp.fire)
        self.world.step()
        self.log.append(inp)

    def frame(self, inp: PlayerInput) -> np.ndarray:
        """Apply `inp`, simulate one video frame and render it: (H, W, 3) uint8 BGR."""
        self.advance(inp)
        return self.world.render()


# ------------------------------------------------------------------------------------------------
# the inputs file


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
    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = fh.read().splitlines()
    settings: dict[str, str] = {}
    settings_line = 0
    header_seen = False
    rows: list[PlayerInput] = []
    for number, raw in enumerate(lines, start=1):
        text = raw.strip()
        if not text:
            continue
        if text.startswith("#"):
            if text.startswith(SETTINGS_TAG) and not header_seen and not settings_line:
                settings = _parse_settings(path, number, text)
                settings_line = number
            continue
        fields = [f.strip() for f in text.split(",")]
        if not header_seen:
            if tuple(fields) != HEADER:
                raise ValueError(f"{path}:{number}: expected the header {','.join(HEADER)} (got {text[:80]!r})")
            header_seen = True
            continue
        if len(fields) != len(HEADER):
            raise ValueError(f"{path}:{number}: expected {len(HEADER)} fields {','.join(HEADER)} "
                             f"(got {len(fields)}: {text[:80]!r})")
        if fields[0] != str(len(rows)):
            raise ValueError(f"{path}:{number}: frame: expected {len(rows)} (rows count frames from 0 in order) "
                             f"(got {fields[0]!r})")
        values = []
        for name, f in zip(HEADER[1:6], fields[1:6]):
            try:
                v = float(f)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise ValueError(f"{path}:{number}: {name}: expected a finite number (got {f!r})")
            if name.startswith("move") and abs(v) > 1.0:
                raise ValueError(f"{path}:{number}: {name}: expected a number in [-1, 1] (got {f})")
            if name.startswith("aim") and abs(v) > MAX_AIM:
                raise ValueError(f"{path}:{number}: {name}: expected metres within +-{MAX_AIM:g} (got {f})")
            values.append(v)
        if fields[6] not in ("0", "1"):
            raise ValueError(f"{path}:{number}: fire: expected 0 or 1 (got {fields[6]!r})")
        rows.append(PlayerInput((values[0], values[1]), tuple(values[2:5]), fields[6] == "1"))
        if len(rows) > MAX_ROWS:
            raise ValueError(f"{path}:{number}: more than {MAX_ROWS} rows (got more)")
    if not header_seen:
        got = "an empty file" if not lines else "only comments"
        raise ValueError(f"{path}:{len(lines) + 1}: expected the header {','.join(HEADER)} (got {got})")
    if not rows:
        raise ValueError(f"{path}:{len(lines) + 1}: expected at least one row after the header (got none)")
    return InputLog(path, tuple(rows), settings, settings_line)


# ------------------------------------------------------------------------------------------------
# mouse and keys -> input


def ground_basis(camera) -> tuple[np.ndarray, np.ndarray]:
    """Unit (x, z) directions of the camera's forward and right on the ground: W walks 'into' the screen."""
    fwd = np.array([camera.forward[0], camera.forward[2]], np.float64)
    if np.linalg.norm(fwd) < 1e-6:  # looking straight down: the screen's up is forward
        fwd = np.array([camera.up[0], camera.up[2]], np.float64)
    fwd /= np.linalg.norm(fwd)
    right = np.array([camera.right[0], camera.right[2]], np.float64)
    right /= max(np.linalg.norm(right), 1e-12)
    return fwd, right


def move_from_keys(camera, forward: bool, back: bool, left: bool, right: bool) -> tuple[float, float]:
    """(x, z) walk direction of held keys, camera-relative, length 0 or 1."""
    fwd, rgt = ground_basis(camera)
    v = fwd * (float(forward) - float(back)) + rgt * (float(right) - float(left))
    n = float(np.linalg.norm(v))
    return (0.0, 0.0) if n < 1e-9 else (float(v[0] / n), float(v[1] / n))


def ray_plane(camera, px: float, py: float, height: float) -> np.ndarray | None:
    """World point where the ray through pixel (px, py) meets the plane y = height, or None."""
    origin, d = camera.ray(px, py)
    if abs(d[1]) < 1e-9:
        return None
    t = (height - origin[1]) / d[1]
    return None if t <= 0.0 else origin + t * d


def aim_point(camera, px: float, py: float, height: float, targets=None) -> np.ndarray:
    """The world point aimed at through pixel (px, py): the chest of a target (K, 3) that is
    drawn within SNAP_FRACTION of the window height of the cursor (the nearest), else the ray's
    point at y = height, else (a ray above the horizon) a point AIM_FAR along the ray."""
    if targets is not None and len(targets):
        pix, depth = camera.project(np.asarray(targets, np.float64))
        dist = np.hypot(pix[:, 0] - px, pix[:, 1] - py)
        dist[~np.isfinite(dist) | (depth <= 0)] = np.inf
        k = int(np.argmin(dist))
        if dist[k] <= SNAP_FRACTION * camera.height:
            return np.asarray(targets[k], np.float64)
    p = ray_plane(camera, px, py, height)
    if p is not None and np.linalg.norm(p - camera.position) <= AIM_FAR * 4:
        return p
    origin, d = camera.ray(px, py)
    return origin + AIM_FAR * d


def walk_toward(camera, px: float, py: float, player_xz) -> tuple[float, float]:
    """(x, z) unit direction from the player to the ground point under the cursor ((0, 0) when close)."""
    p = ray_plane(camera, px, py, 0.0)
    if p is None:
        return 0.0, 0.0
    v = np.array([p[0] - player_xz[0], p[2] - player_xz[1]])
    n = float(np.linalg.norm(v))
    return (0.0, 0.0) if n < WALK_DEADZONE else (float(v[0] / n), float(v[1] / n))


def shooter_chests(world: World) -> np.ndarray:
    """(S', 3) world positions of the standing shooters' chests (what the mouse snaps to)."""
    if world.n_shooters == 0:
        return np.zeros((0, 3))
    chests = world.shooters.joint_positions()[:, world.hbody.chest].astype(np.float64)
    return chests[world.shooter_alive]


# ------------------------------------------------------------------------------------------------
# the window


def draw_overlay(frame: np.ndarray, lines: list[str], cursor=None) -> np.ndarray:
    """Write `lines` bottom-left on a dark band and a crosshair at cursor (px, py), in place."""
    import cv2

    h, w = frame.shape[:2]
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = max(0.33, 0.5 * h / 720.0)
    (_, text_h), base = cv2.getTextSize("Ag", font, scale, 1)
    line_h = text_h + base + 4
    band = line_h * len(lines) + 6
    region = frame[h - band:, :]
    region[:] = (region.astype(np.uint16) * 90 >> 8).astype(np.uint8)
    for i, s in enumerate(lines):
        y = h - band + line_h * (i + 1) - 2
        cv2.putText(frame, s, (6, y), font, scale, (235, 235, 235), 1, cv2.LINE_AA)
    if cursor is not None:
        x, y = int(round(cursor[0])), int(round(cursor[1]))
        r = max(5, h // 60)
        cv2.circle(frame, (x, y), r, (40, 40, 230), 1, cv2.LINE_AA)
        cv2.line(frame, (x - 2 * r, y), (x - r // 2, y), (40, 40, 230), 1, cv2.LINE_AA)
        cv2.line(frame, (x + r // 2, y), (x + 2 * r, y), (40, 40, 230), 1, cv2.LINE_AA)
        cv2.line(frame, (x, y - 2 * r), (x, y - r // 2), (40, 40, 230), 1, cv2.LINE_AA)
        cv2.line(frame, (x, y + r // 2), (x, y + 2 * r), (40, 40, 230), 1, cv2.LINE_AA)
    return frame


def gui_image(frame: np.ndarray) -> np.ndarray:
    """BGR (H, W, 3) uint8, row 0 at the top -> Taichi GUI's float32 RGBA (W, H, 4) indexed [x, y]
    with y up: the layout GUI.set_image keeps as it is (a uint8 RGB image costs it another
    conversion, 6 ms at 1280x720)."""
    import cv2

    rgba = cv2.rotate(cv2.cvtColor(frame, cv2.COLOR_BGRA2RGBA if frame.shape[2] == 4 else cv2.COLOR_BGR2RGBA),
                      cv2.ROTATE_90_CLOCKWISE)
    return np.multiply(rgba, np.float32(1.0 / 255.0), dtype=np.float32)


def _to_px(pos, size) -> tuple[float, float]:
    """Taichi GUI position (x right, y up, 0..1) -> pixel coordinates (x right, y down)."""
    return pos[0] * size[0], size[1] - 1 - pos[1] * size[1]


@dataclass
class LiveResult:
    """What a live session did."""

    frames: int  # simulated video frames (= recorded rows)
    shown: int  # window frames, paused ones included
    wall_s: float
    mean_fps: float  # simulated frames per wall second while not paused, after the first WARMUP
    median_fps: float  # 1 / the median time of those frames (kernels compiled mid-game left out)
    player_start: list
    player_end: list


def play_window(session: Session, size: tuple[int, int], title: str = WINDOW_TITLE) -> LiveResult:
    """The interactive loop (see the module docstring) on session.world; returns when the window
    is closed. The inputs applied are in session.log, also after an exception."""
    import taichi as ti

    world = session.world
    camera = world.camera
    height = CHEST_HEIGHT * world.hbody.scale
    fps = world.scene.video.fps
    gui = ti.GUI(title, res=size)
    gui.fps_limit = max(1, int(math.ceil(fps)))
    start = world.player_position()
    paused = False
    shown, fps_ema, times = 0, None, []
    t0 = t_last = time.perf_counter()
    picture = world.render()
    try:
        while gui.running:
            fire = False
            for e in gui.get_events(ti.GUI.PRESS):
                key = e.key.lower() if isinstance(e.key, str) and len(e.key) == 1 else e.key
                if key in (ti.GUI.ESCAPE, ti.GUI.EXIT):
                    gui.running = False
                elif key == ti.GUI.SPACE:
                    paused = not paused
                elif key == ti.GUI.LMB:
                    fire = True
            if not gui.running:
                break
            px, py = _to_px(gui.get_cursor_pos(), size)
            if not paused:
                if gui.is_pressed(ti.GUI.RMB):
                    move = walk_toward(camera, px, py, world.player_position()[[0, 2]])
                else:
                    move = move_from_keys(camera, gui.is_pressed("w", "W", ti.GUI.UP),
                                          gui.is_pressed("s", "S", ti.GUI.DOWN),
                                          gui.is_pressed("a", "A", ti.GUI.LEFT),
                                          gui.is_pressed("d", "D", ti.GUI.RIGHT))
                aim = aim_point(camera, px, py, height, shooter_chests(world))
                picture = session.frame(PlayerInput(move, tuple(aim), fire))
            now = time.perf_counter()
            dt, t_last = now - t_last, now
            if not paused and len(session.log) > WARMUP:  # the first frames compile kernels
                times.append(dt)
            fps_ema = 1.0 / max(dt, 1e-6) if fps_ema is None else fps_ema + 0.1 * (1.0 / max(dt, 1e-6) - fps_ema)
            state = "PAUSED (Space to go on)" if paused else f"time x{world.time_scale:.2f}"
            overlay = draw_overlay(picture.copy(), [f"fps {fps_ema:.1f}   {state}", LEGEND], cursor=(px, py))
            gui.set_image(gui_image(overlay))
            gui.show()
            shown += 1
    finally:
        gui.close()
    frames = len(session.log)
    mean = len(times) / sum(times) if times else 0.0
    median = 1.0 / float(np.median(times)) if times else 0.0
    return LiveResult(frames, shown, time.perf_counter() - t0, mean, median,
                      start.tolist(), world.player_position().tolist())


def display_available() -> bool:
    """True when $DISPLAY names an X server that accepts a connection."""
    from crowd_ik.mouse.session import display_available as check

    return check()


def run(args) -> int:
    """`crowd-ik play SCENE --live [--record F.csv] [--stats F.json] [--size WxH] ...`."""
    from crowd_ik import runtime
    from crowd_ik.io.output import check_writable, write_json
    from crowd_ik.commands.play import build_scene, summary

    scene = build_scene(args)
    if args.record is not None:
        if Path(args.record).suffix.lower() != ".csv":
            raise ValueError(f"--record: inputs are written as a .csv file (got {args.record!r})")
        check_writable(args.record, args.force)
    if args.stats is not None:
        if Path(args.stats).suffix.lower() != ".json":
            raise ValueError(f"--stats: expected a .json file (got {args.stats!r})")
        check_writable(args.stats, args.force)
    if not display_available():
        raise ValueError(no_display_message(args.scene))
    arch = runtime.init(arch=args.arch, threads=args.threads)
    sys.stdout.flush()
    world = PlayerWorld(scene, hud_timings=args.hud_timings)
    session = Session(world)
    try:
        result = play_window(session, (scene.video.width, scene.video.height))
    finally:  # an interrupted session keeps its inputs too
        if args.record is not None and session.log:
            write_inputs(args.record, session.log, scene_settings(scene), force=args.force)
    print(f"{scene.name} live: {result.frames} frames played ({result.shown} shown) in {result.wall_s:.1f} s, "
          f"{result.mean_fps:.1f} fps while playing (median {result.median_fps:.1f}); hits {world.hits}, "
          f"dodges {world.dodges}, shots {world.player_shots}, shooters down {world.shooters_down}/{world.n_shooters}")
    if args.record is not None:
        print(f"  inputs      {args.record}" if result.frames else "  inputs      none recorded (no frame played)")
    if args.stats is not None:
        info = summary(world, scene, args.record or "(window)", result.wall_s, arch, result.frames)
        info.update(live_fps=result.mean_fps, live_median_fps=result.median_fps, shown=result.shown,
                    player_shots=world.player_shots, player_start=result.player_start, player_end=result.player_end)
        write_json(args.stats, info, force=args.force)
        print(f"  stats       {args.stats}")
    return 0


__all__ = ["PlayerInput", "SteeredWalker", "PlayerWorld", "Session", "InputLog", "load_inputs", "format_inputs",
           "write_inputs", "scene_settings", "move_from_keys", "aim_point", "walk_toward", "ray_plane",
           "play_window", "no_display_message", "run", "HEADER"]
