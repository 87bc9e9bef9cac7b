"""`crowd-ik mouse`: one character posed with the mouse, live in a window or replayed to video.

The seeds' interactive demo (homework ik_demo, lab 2, coursework): a planar chain of unit bones
whose tip follows a target. The methods are the planar NumPy ones of :mod:`crowd_ik.planar`
(newton, dls, follow = the lab's residual stepping) and the Taichi solvers of :class:`Crowd`
with N = 1 (fabrik, ccd). The joint angles (homework convention) are the one shared state, so
switching method mid-drag carries the pose over. A target the chain does not reach is "lost"
(drawn white, as in the lab) and the chain stretches toward it.

- live chain: Taichi's GUI window; drag the target; keys 1-5 method, L limits, R reset, C record
  the target path to path_NNN.csv (never overwriting), Esc quit.
- live humanoid (--rig humanoid): drag a hand, foot or head in the camera's view plane; FABRIK,
  DLS or CCD on the whole body, the other effectors held.
- replay: --path PATH.csv (t,x,y per row) or --keyframes FILE.csv (eased key poses) to a video.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import os
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crowd_ik import planar
from crowd_ik.mouse.view import ChainPicture, View, draw_background, draw_chain_frame, reachable_mask, tips
from crowd_ik.solvers.registry import (
    CCD, DLS, FABRIK, FOLLOW, METHODS as CROWD_METHODS, NEWTON, PLANAR_DEFAULT, PLANAR_METHODS,
)

METHODS = PLANAR_METHODS
TAICHI_METHODS = (FABRIK, CCD)  # the chain's methods solved by a Crowd of one
HUMANOID_METHODS = CROWD_METHODS
KEYS = {str(k + 1): m for k, m in enumerate(METHODS)}
DEFAULT_BONES, MAX_BONES = 4, 100
LOST_TOL = 0.02  # chain units: a tip farther than this from its target has lost it
# follow's accepted sub-steps each miss by up to its 0.05 threshold, so its tip drifts; more than
# this and the next frame's correction is no longer small: lost as well
FOLLOW_DRIFT = 0.1
TRAIL_LENGTH = 40
MAX_FRAMES = 1_000_000
SCENES = Path(__file__).resolve().parents[1] / "scenes"
NO_DISPLAY = "mouse: no display; replay headless instead: crowd-ik mouse --path scenes/circle.csv -o circle.mp4"
LEGEND = ["1 newton  2 dls  3 fabrik  4 ccd  5 follow   drag: move the target",
          "L limits  R reset  C record path  Esc quit"]


def chain_limits(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) radians of the --limits chain: the coursework's ranges spread over n joints.

    The first joint +-45 deg, the last +-170 deg, the ones between +-90 deg (for 3 bones exactly
    the coursework's [-45, 45], [-90, 90], [-170, 170]).
    """
    deg = np.full(n, 90.0)
    if n > 1:
        deg[-1] = 170.0
    deg[0] = 45.0
    return -np.radians(deg), np.radians(deg)


def rest_pose(n: int) -> np.ndarray:
    """A gentle arc (90 deg of bend in all), so the Jacobian has full rank from the start."""
    return np.full(n, 0.5 * np.pi / n)


def _wrap(t: np.ndarray) -> np.ndarray:
    return (t + np.pi) % (2 * np.pi) - np.pi


def _limited_chain_rig(n: int, limits: bool):
    """Rig.chain(n, dim=2) with the per-joint limits of chain_limits when ``limits``."""
    from dataclasses import replace

    from crowd_ik.rig import Rig

    rig = Rig.chain(n, 1.0, dim=2)
    if not limits:
        return rig
    lo, hi = chain_limits(n)
    joints = tuple(replace(j, lo=(float(lo[i]),), hi=(float(hi[i]),)) if i < n else j for i, j in enumerate(rig.joints))
    return Rig(joints, rig.effectors, dim=2, name=rig.name)


class ChainSession:
    """The planar demo's state: angles, method, limits, target; :meth:`step` solves one frame."""

    def __init__(self, n_bones: int = DEFAULT_BONES, method: str = PLANAR_DEFAULT, limits: bool = False):
        if method not in METHODS:
            raise ValueError(f"--method: expected one of {', '.join(METHODS)} (got {method!r})")
        self.n, self.method, self.limits = n_bones, method, bool(limits)
        self._crowds: dict[bool, object] = {}
        self._backgrounds: dict[tuple, np.ndarray] = {}
        self.reset()

    def reset(self) -> None:
        """Back to the rest pose, the target on the tip."""
        self.thetas = rest_pose(self.n)
        self.target = planar.chain(self.thetas)
        self.error, self.lost = 0.0, False

    @property
    def reach(self) -> float:
        return float(self.n)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return chain_limits(self.n) if self.limits else (np.full(self.n, -np.inf), np.full(self.n, np.inf))

    def toggle_limits(self) -> None:
        self.limits = not self.limits
        self.thetas = np.clip(self.thetas, *self.bounds)

    def set_method(self, method: str) -> None:
        if method not in METHODS:
            raise ValueError(f"method: expected one of {', '.join(METHODS)} (got {method!r})")
        self.method = method

    def background(self, view: View) -> np.ndarray:
        """The static layer (grid, reachable area, reach circle) for this view and limits setting;
        the area is sampled once per setting, then cached."""
        key = (view, self.limits)
        if key not in self._backgrounds:
            self._backgrounds[key] = draw_background(view, reachable_mask(view, *self.bounds))
        return self._backgrounds[key]

    def _aim(self) -> np.ndarray:
        """The target, or for one beyond the reach its projection just inside the reach circle."""
        dist = float(np.linalg.norm(self.target))
        edge = self.reach * (1.0 - 1e-3)
        return self.target * (edge / dist) if dist > edge else self.target.copy()

    def _crowd(self):
        if self.limits not in self._crowds:
            from crowd_ik.crowd import Crowd

            self._crowds[self.limits] = Crowd(_limited_chain_rig(self.n, self.limits), n=1)
        return self._crowds[self.limits]

    def step(self) -> None:
        """Solve one frame toward ``self.target``; update ``error`` and ``lost``."""
        lo, hi = self.bounds
        reached = True
        if self.method == NEWTON:
            # the homework's 8 pseudoinverse steps; with limits, clamped after each (coursework 4.3)
            aim = self._aim()
            t = self.thetas
            for _ in range(8 if self.limits else 1):
                t = np.clip(planar.newton(t, aim, iterations=1 if self.limits else 8), lo, hi)
            self.thetas = t
        elif self.method == DLS:
            self.thetas = planar.dls(self.thetas, self.target, damping=0.1, iterations=100, tolerance=1e-4,
                                     limits=(lo, hi) if self.limits else None)
        elif self.method == FOLLOW:
            aim = self._aim()
            t, reached = planar.follow(self.thetas, aim - planar.chain(self.thetas), threshold=0.05, max_depth=10)
            self.thetas = np.clip(t, lo, hi)
        else:
            crowd = self._crowd()
            crowd.set_angles(self.thetas.astype(np.float32))
            crowd.solve(self.target.reshape(1, 1, 2).astype(np.float32), method=self.method,
                        max_iterations=100, tolerance=1e-3)
            self.thetas = crowd.angles()[0].astype(np.float64)
        if not self.limits:
            self.thetas = _wrap(self.thetas)
        self.error = float(np.linalg.norm(planar.chain(self.thetas) - self.target))
        if self.method == FOLLOW:  # the lab's rule: lost when move() gives up
            beyond = np.linalg.norm(self.target) > self.reach
            self.lost = bool(not reached or beyond or self.error > FOLLOW_DRIFT)
        else:
            self.lost = self.error > LOST_TOL

    def settle(self, target) -> None:
        """Start on ``target``: pose the chain from rest by DLS run to convergence (replays begin so)."""
        self.target = np.asarray(target, dtype=np.float64).copy()
        self.thetas = planar.dls(rest_pose(self.n), self.target, damping=0.1, iterations=1000, tolerance=1e-6,
                                 limits=self.bounds if self.limits else None)

    def joints(self) -> np.ndarray:
        return planar.chain_all(self.thetas)

    def hud(self) -> list[str]:
        engine = "Taichi, N=1" if self.method in TAICHI_METHODS else "NumPy"
        x, y = self.target
        return [f"{self.method} ({engine})   {self.n} bones   limits {'on' if self.limits else 'off'}",
                f"target ({x:+.2f}, {y:+.2f})   error {self.error:.3f}",
                "target LOST" if self.lost else "target reached"]


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


def _number(path, number: int, name: str, field: str) -> float:
    try:
        v = float(field)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise ValueError(f"{path}:{number}: {name}: expected a finite number (got {field!r})")
    return v


def load_path(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a target path: header ``t,x,y`` (seconds, chain units), then one row per sample with t
    increasing. Blank lines and '#' lines are skipped. Returns (t (M,), xy (M, 2)).

    Problems raise ValueError("path:LINE: problem (got value)").
    """
    path = os.fspath(path)
    with open(path, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    header, rows = None, []
    for number, raw in enumerate(lines, start=1):
        text = raw.strip()
        if not text or text.startswith("#"):
            continue
        fields = [f.strip() for f in text.split(",")]
        if header is None:
            if fields != ["t", "x", "y"]:
                raise ValueError(f"{path}:{number}: expected header t,x,y (got {text!r})")
            header = fields
            continue
        if len(fields) != 3:
            raise ValueError(f"{path}:{number}: expected 3 fields t,x,y (got {len(fields)}: {text!r})")
        row = [_number(path, number, name, f) for name, f in zip(header, fields)]
        if rows and row[0] <= rows[-1][0]:
            raise ValueError(f"{path}:{number}: t: expected times increasing row by row (got {fields[0]} after {rows[-1][0]:g})")
        rows.append(row)
        if len(rows) > MAX_FRAMES:
            raise ValueError(f"{path}:{number}: more than {MAX_FRAMES} rows (got more)")
    if header is None:
        raise ValueError(f"{path}:1: expected header t,x,y (got an empty file)")
    if not rows:
        raise ValueError(f"{path}:{len(lines) + 1}: expected at least one row t,x,y after the header (got none)")
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


# ---------------------------------------------------------------------------------------------
# replay to video


@dataclass(frozen=True)
class Replay:
    """What a replay wrote, frame by frame."""

    output: Path
    fps: float
    size: tuple[int, int]
    angles: np.ndarray  # (F, n) radians
    lost: np.ndarray  # (F,) bool
    error: np.ndarray  # (F,) chain units (0 for keyframes)

    @property
    def frames(self) -> int:
        return len(self.angles)


def replay_path(csv, output, *, n_bones=DEFAULT_BONES, method=PLANAR_DEFAULT, limits=False, size=(720, 720), fps=None,
                force=False) -> Replay:
    """Solve the chain toward each target of a path CSV and write one frame per target."""
    from crowd_ik.io.video import open_sink

    src = resolve_input(csv)
    t, xy = load_path(src)
    times, targets, rate = path_frames(t, xy, fps, str(src))
    session = ChainSession(n_bones, method, limits)
    view = View(n_bones, *size)
    angles, lost, error = [], [], []
    trail: deque = deque(maxlen=TRAIL_LENGTH)
    with open_sink(output, rate, size, force) as sink:
        background = session.background(view)
        session.settle(targets[0])
        for k, (now, target) in enumerate(zip(times, targets)):
            session.target = target
            session.step()
            joints = session.joints()
            trail.append(joints[-1])
            hud = session.hud() + [f"t {now:.2f} s   frame {k + 1}/{len(times)}"]
            pic = ChainPicture(joints, target, session.lost, background, hud, [f"replay {src.name}"], np.array(trail))
            sink.write(draw_chain_frame(view, pic))
            angles.append(session.thetas.copy())
            lost.append(session.lost)
            error.append(session.error)
    return Replay(Path(sink.path), rate, tuple(size), np.array(angles), np.array(lost), np.array(error))


def replay_keyframes(csv, output, *, n_bones=None, limits=False, size=(720, 720), fps=None, k1=0.2, k2=0.75,
                     force=False) -> Replay:
    """Ease between the key poses of a keyframe CSV (crowd_ik.ease) and write every frame."""
    from crowd_ik.ease import interpolate_keyframes, load_keyframes
    from crowd_ik.io.video import open_sink

    src = resolve_input(csv)
    durations, poses = load_keyframes(src)
    n = poses.shape[1]
    if n_bones is not None and n_bones != n:
        raise ValueError(f"{src}: has {n} angles per key pose but --bones is {n_bones}")
    if n > MAX_BONES:
        raise ValueError(f"{src}: {n} angles per key pose; at most {MAX_BONES} bones")
    session = ChainSession(n, PLANAR_DEFAULT, limits)
    if limits:
        lo, hi = session.bounds
        bad = np.argwhere((poses < lo - 1e-9) | (poses > hi + 1e-9))
        if bad.size:
            k, j = bad[0]
            raise ValueError(f"{src}: key pose {k + 1}: theta{j + 1} = {math.degrees(poses[k, j]):g} deg is outside "
                             f"the --limits range +-{math.degrees(hi[j]):g} deg")
    rate = 30.0 if fps is None else float(fps)
    angles = interpolate_keyframes(durations, poses, rate, k1, k2)
    total = float(durations.sum())
    view = View(n, *size)
    marks = tips(poses)
    trail: deque = deque(maxlen=TRAIL_LENGTH)
    with open_sink(output, rate, size, force) as sink:
        background = session.background(view)
        for k, theta in enumerate(angles):
            joints = planar.chain_all(theta)
            trail.append(joints[-1])
            hud = [f"keyframes ({len(poses)} poses)   sine ease k1 {k1:g}  k2 {k2:g}",
                   f"t {min(k / rate, total):.2f} s of {total:.2f} s   frame {k + 1}/{len(angles)}"]
            pic = ChainPicture(joints, None, False, background, hud, [f"replay {src.name}"], np.array(trail), marks)
            sink.write(draw_chain_frame(view, pic))
    return Replay(Path(sink.path), rate, tuple(size), angles, np.zeros(len(angles), bool), np.zeros(len(angles)))


# ---------------------------------------------------------------------------------------------
# live windows


def display_available() -> bool:
    """True when $DISPLAY names an X server that accepts a connection."""
    name = os.environ.get("DISPLAY", "")
    if not name:
        return False
    lib = ctypes.util.find_library("X11")
    if lib is None:
        return True  # cannot check; let the window try
    x11 = ctypes.CDLL(lib)
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = x11.XOpenDisplay(name.encode())
    if not handle:
        return False
    x11.XCloseDisplay(handle)
    return True


def _to_px(pos, size) -> tuple[float, float]:
    """Taichi GUI position (x right, y up, 0..1) -> pixel coordinates (x right, y down)."""
    x, y = pos
    w, h = size
    return x * w, h - 1 - y * h


def live_chain(n_bones: int, method: str, limits: bool, size: tuple[int, int], record_dir=".") -> int:
    """The interactive window for the planar chain; returns 0 when closed (Esc or the window's X)."""
    import taichi as ti

    from crowd_ik.mouse.view import to_gui_image

    session = ChainSession(n_bones, method, limits)
    view = View(n_bones, *size)
    gui = ti.GUI("crowd-ik mouse", res=size)
    gui.fps_limit = 60
    recorder, dragging = None, False
    trail: deque = deque(maxlen=TRAIL_LENGTH)
    try:
        while gui.running:
            for e in gui.get_events(ti.GUI.PRESS, ti.GUI.RELEASE):
                key = e.key.lower() if isinstance(e.key, str) and len(e.key) == 1 else e.key
                if e.type == ti.GUI.RELEASE:
                    dragging = dragging and key != ti.GUI.LMB
                elif key == ti.GUI.ESCAPE:
                    gui.running = False
                elif key == ti.GUI.LMB:
                    dragging = True
                    session.target = view.to_world(*_to_px(e.pos, size))
                elif key in KEYS:
                    session.set_method(KEYS[key])
                elif key == "l":
                    session.toggle_limits()
                elif key == "r":
                    session.reset()
                    trail.clear()
                elif key == "c":
                    if recorder is None:
                        recorder = Recorder(record_dir)
                    else:
                        _save(recorder)
                        recorder = None
            if dragging:
                session.target = view.to_world(*_to_px(gui.get_cursor_pos(), size))
            session.step()
            if recorder is not None:
                recorder.add(session.target)
            joints = session.joints()
            trail.append(joints[-1])
            pic = ChainPicture(joints, session.target, session.lost, session.background(view), session.hud(), LEGEND,
                               np.array(trail), recording=recorder is not None)
            gui.set_image(to_gui_image(draw_chain_frame(view, pic)))
            gui.show()
    finally:
        if recorder is not None:
            _save(recorder)
        gui.close()
    return 0


def _save(recorder: Recorder) -> None:
    if recorder.rows:
        out = recorder.save()
        print(f"crowd-ik mouse: recorded {len(recorder.rows)} targets to {out}", flush=True)


def live_humanoid(method: str, size: tuple[int, int]) -> int:
    """The interactive window for the humanoid; returns 0 when closed."""
    import taichi as ti

    from crowd_ik.mouse.view import to_gui_image
    from crowd_ik.mouse.view import HumanoidSession

    session = HumanoidSession(size, method)
    gui = ti.GUI("crowd-ik mouse (humanoid)", res=size)
    gui.fps_limit = 60
    keys = {k: m for k, m in KEYS.items() if m in HUMANOID_METHODS}
    try:
        while gui.running:
            for e in gui.get_events(ti.GUI.PRESS, ti.GUI.RELEASE):
                key = e.key.lower() if isinstance(e.key, str) and len(e.key) == 1 else e.key
                if e.type == ti.GUI.RELEASE:
                    if key == ti.GUI.LMB:
                        session.release()
                elif key == ti.GUI.ESCAPE:
                    gui.running = False
                elif key == ti.GUI.LMB:
                    session.press(*_to_px(e.pos, size))
                elif key in keys:
                    session.method = keys[key]
                elif key == "r":
                    session.reset()
            if session.active is not None:
                session.drag_to(*_to_px(gui.get_cursor_pos(), size))
            session.step()
            gui.set_image(to_gui_image(session.render()))
            gui.show()
    finally:
        gui.close()
    return 0


# ---------------------------------------------------------------------------------------------
# command line


def _parse_size(text: str) -> tuple[int, int]:
    from crowd_ik.io.video import check_size

    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise ValueError(f"--size: expected WxH, e.g. 720x720 (got {text!r})") from None
    return check_size((w, h), "--size")


def run(args) -> int:
    """Handler of `crowd-ik mouse` (see cli.py for the arguments)."""
    from crowd_ik import runtime

    size = _parse_size(args.size)
    if args.fps is not None and not (math.isfinite(args.fps) and 0 < args.fps <= 1000):
        raise ValueError(f"--fps: expected a number in (0, 1000] (got {args.fps:g})")
    if args.bones is not None and not 1 <= args.bones <= MAX_BONES:
        raise ValueError(f"--bones: expected an integer in [1, {MAX_BONES}] (got {args.bones})")
    if args.path and args.keyframes:
        raise ValueError("--path and --keyframes: give one of them (got both)")
    replay = args.path or args.keyframes
    if args.rig == "humanoid":
        if replay or args.output:
            raise ValueError("--rig humanoid: the humanoid is live only; --path, --keyframes and -o replay the chain")
        if args.method not in HUMANOID_METHODS:
            raise ValueError(f"--method: the humanoid is solved with {', '.join(HUMANOID_METHODS)} (got {args.method})")
    elif replay:
        output = args.output or f"{Path(replay).stem}.mp4"
        runtime.init(args.arch, args.threads)
        if args.path:
            result = replay_path(args.path, output, n_bones=args.bones or DEFAULT_BONES, method=args.method,
                                 limits=args.limits, size=size, fps=args.fps, force=args.force)
            extra = f"; target lost on {int(result.lost.sum())} of them"
        else:
            result = replay_keyframes(args.keyframes, output, n_bones=args.bones, limits=args.limits, size=size,
                                      fps=args.fps, k1=args.k1, k2=args.k2, force=args.force)
            extra = ""
        print(f"crowd-ik mouse: wrote {result.output} ({result.frames} frames, {size[0]}x{size[1]}, "
              f"{result.fps:g} fps{extra})")
        return 0
    elif args.output:
        raise ValueError(f"-o {args.output}: needs --path PATH.csv or --keyframes FILE.csv to replay (the window writes no video)")
    if not display_available():
        raise ValueError(NO_DISPLAY)
    runtime.init(args.arch, args.threads)
    sys.stdout.flush()
    if args.rig == "humanoid":
        return live_humanoid(args.method, size)
    return live_chain(args.bones or DEFAULT_BONES, args.method, args.limits, size)


__all__ = ["ChainSession", "Recorder", "Replay", "METHODS", "LOST_TOL", "chain_limits", "load_path",
           "path_frames", "replay_path", "replay_keyframes", "display_available", "live_chain",
           "live_humanoid", "run"]
