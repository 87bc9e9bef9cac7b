"""Live play's window: the World driven by mouse and keys in Taichi's GUI.

`crowd-ik play SCENE --live` opens a window of the scene's video size (or --size). The player
walks with WASD or the arrow keys (camera-relative) or toward the cursor while the right mouse
button is held; the mouse aims its right arm by IK and a left click fires a bullet at the aim
point (the aim snaps to a standing shooter's chest near the cursor); a shooter the player's bullet
hits is down: it shatters and stops firing. Space pauses; Esc (or closing the window) quits. Time
moves only while the player moves (the scene's time scale: World.step). The HUD shows the time
scale, hits, dodges and shooters down (the World's lines) and the window's frames per second; a
crosshair marks the aim.
The inputs are recorded as crowd_ik.io.inputs describes.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from crowd_ik.io.inputs import PlayerInput
from crowd_ik.session import Session

AIM_FAR = 60.0  # m: a ray that never meets the aim plane aims this far along itself
CHEST_HEIGHT = 1.3  # m (times characters.scale): the plane the mouse aims in
SNAP_FRACTION = 0.035  # a shooter's chest within this fraction of the window height snaps the aim
WALK_DEADZONE = 0.2  # m: walking toward the cursor stops this close to it
WINDOW_TITLE = "crowd-ik play"
WARMUP = 5  # played frames left out of the mean fps (the first ones compile kernels)
LEGEND = "WASD / arrows / right-drag: move   mouse: aim   click: fire   Space: pause   Esc: quit"


def no_display_message(scene_arg) -> str:
    scene = scene_arg if scene_arg else "SCENE"
    return (f"--live needs a display; render headless instead: crowd-ik play {scene} -o OUT.mp4 "
            f"(or --inputs F.csv)")


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


def shooter_chests(world) -> np.ndarray:
    """(S', 3) world positions of the standing shooters' chests (what the mouse snaps to)."""
    if world.n_shooters == 0:
        return np.zeros((0, 3))
    chests = world.shooters.joints[:, world.hbody.chest].astype(np.float64)
    return chests[world.shooters.alive]


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
    start = world.player.position()
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
            camera = world.camera  # the shown frame's camera (it follows the player in camera.mode "follow")
            if not paused:
                if gui.is_pressed(ti.GUI.RMB):
                    move = walk_toward(camera, px, py, world.player.position()[[0, 2]])
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
                      start.tolist(), world.player.position().tolist())


def display_available() -> bool:
    """True when $DISPLAY names an X server that accepts a connection (view.display)."""
    from crowd_ik.view.display import display_available as check

    return check()
