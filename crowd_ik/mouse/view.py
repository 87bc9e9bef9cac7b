"""Drawing for `crowd-ik mouse`: the planar chain view and the humanoid's overlays, as frames.

A frame is an (H, W, 3) uint8 BGR array, row 0 at the top (DESIGN.md, "Rendering"); the live
window and the headless replay draw the same frames. The planar view maps the square
[-(n+1), n+1]^2 of chain units (bone length 1, y up) onto the frame's largest centred square.

The reachable area is sampled: random joint angles within the limits (plus near-straight poses,
which uniform angles almost never give, so the outer rim fills in) go through a vectorised
forward kinematics, their tips are splatted into a mask and the gaps closed morphologically.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from crowd_ik.solvers.registry import DEFAULT as DEFAULT_METHOD
from crowd_ik.view.overlay import draw_hud

# BGR colours
BACKGROUND = (34, 28, 26)
GRID = (52, 46, 43)
AREA = (105, 100, 96)
AREA_ALPHA = 0.45
REACH = (90, 200, 90)  # the coursework's green circle
BONE = (235, 185, 95)
JOINT = (70, 215, 250)
ROOT = (170, 170, 170)
TARGET = (60, 60, 235)  # the lab's red destination
LOST = (255, 255, 255)  # ... drawn white when the engine has lost track
TRAIL = (150, 120, 80)
KEY_MARK = (200, 130, 230)
REC = (40, 40, 230)
TEXT = (235, 235, 235)

AREA_SAMPLES = 120_000


@dataclass(frozen=True)
class View:
    """Chain units <-> pixels for an n-bone chain in a (width, height) frame."""

    n_bones: int
    width: int
    height: int

    @property
    def extent(self) -> float:
        return self.n_bones + 1.0

    @property
    def scale(self) -> float:
        """Pixels per chain unit."""
        return min(self.width, self.height) / (2.0 * self.extent)

    def to_px(self, xy) -> np.ndarray:
        """(..., 2) chain units -> (..., 2) float pixels, x right, y down (pixel centres at integers)."""
        p = np.asarray(xy, dtype=np.float64)
        u = (self.width - 1) / 2.0 + self.scale * p[..., 0]
        v = (self.height - 1) / 2.0 - self.scale * p[..., 1]
        return np.stack([u, v], axis=-1)

    def to_world(self, px, py) -> np.ndarray:
        """Pixel coordinates (x right, y down) -> (2,) chain units."""
        return np.array([(px - (self.width - 1) / 2.0) / self.scale, ((self.height - 1) / 2.0 - py) / self.scale])


def tips(thetas: np.ndarray) -> np.ndarray:
    """Vectorised forward kinematics of unit bones: thetas (M, n) radians -> tips (M, 2)."""
    phi = np.cumsum(thetas, axis=1)
    return np.stack([np.cos(phi).sum(axis=1), np.sin(phi).sum(axis=1)], axis=1)


def sample_reachable(n_bones: int, lo: np.ndarray, hi: np.ndarray, samples: int = AREA_SAMPLES, seed: int = 0) -> np.ndarray:
    """(samples, 2) tip positions of random poses within [lo, hi] (radians; +-inf = unlimited).

    Every sample is a pose within the limits, drawn from four families in equal parts, because
    uniform angles alone leave most of the area empty (their tips bunch near the root, ever more
    so as bones are added): uniform in the box; near-straight (the first joint anywhere), which
    reach the rim; arcs of every curvature from straight to curled up (theta_2..n = c + noise),
    which spread the tips over all radii; and poses with each joint at a limit half of the time,
    which trace the edges a limited chain's area has there.
    """
    rng = np.random.default_rng(seed)
    n = n_bones
    lo_f = np.where(np.isfinite(lo), lo, -np.pi)
    hi_f = np.where(np.isfinite(hi), hi, np.pi)
    m = samples // 4
    uniform = rng.uniform(lo_f, hi_f, size=(samples - 3 * m, n))
    straight = rng.normal(0.0, 0.35, size=(m, n))
    c = rng.uniform(-2.0, 2.0, size=(m, 1)) * np.pi / max(n - 1, 1)
    arcs = c + rng.normal(0.0, 0.5, size=(m, 1)) * rng.normal(0.0, 1.0, size=(m, n)) * np.pi / max(n - 1, 1)
    corner = rng.uniform(lo_f, hi_f, size=(m, n))
    pick = rng.integers(0, 4, size=(m, n))
    corner = np.where(pick == 0, lo_f, np.where(pick == 1, hi_f, corner))
    poses = np.vstack([uniform, straight, arcs, corner])
    poses[samples - 3 * m : samples - m, 0] = rng.uniform(lo_f[0], hi_f[0], size=2 * m)  # any first angle
    return tips(np.clip(poses, lo_f, hi_f))


AREA_GRID = 200  # cells across the view's square


def reachable_mask(view: View, lo: np.ndarray, hi: np.ndarray, samples: int = AREA_SAMPLES) -> np.ndarray:
    """(H, W) bool: pixels the chain's tip can reach within the limits (sampled, gaps closed).

    Tips are splatted into a grid of AREA_GRID cells across the view, closed morphologically,
    small enclosed holes (under 60 cells) filled, then smoothed and scaled to the frame.
    """
    side = AREA_GRID
    cell = 2 * view.extent / side
    ij = np.floor((sample_reachable(view.n_bones, lo, hi, samples) + view.extent) / cell).astype(np.int64)
    grid = np.zeros((side, side), np.uint8)
    keep = np.all((ij >= 0) & (ij < side), axis=1)
    grid[side - 1 - ij[keep, 1], ij[keep, 0]] = 255  # row 0 at the top: y up
    grid = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(255 - grid, connectivity=4)
    for k in range(1, count):
        x, y, w, h, area = stats[k]
        if x > 0 and y > 0 and x + w < side and y + h < side and area < 60:
            grid[labels == k] = 255
    # the grid spans the view's square; place it on the frame's centred square
    s = int(round(2 * view.extent * view.scale))
    big = cv2.resize(cv2.GaussianBlur(grid, (3, 3), 0), (s, s), interpolation=cv2.INTER_LINEAR) >= 128
    mask = np.zeros((view.height, view.width), bool)
    x0, y0 = (view.width - s) // 2, (view.height - s) // 2
    mask[max(0, y0):y0 + s, max(0, x0):x0 + s] = big[max(0, -y0):, max(0, -x0):][: view.height, : view.width]
    return mask


@dataclass
class ChainPicture:
    """Everything one planar frame shows."""

    joints: np.ndarray  # (n+1, 2) chain units
    target: np.ndarray | None = None  # (2,) chain units, or None (keyframe replay)
    lost: bool = False
    background: np.ndarray | None = None  # (H, W, 3) from draw_background (grid, area, reach circle)
    hud: list[str] = field(default_factory=list)
    legend: list[str] = field(default_factory=list)
    trail: np.ndarray | None = None  # (T, 2) recent tip positions, oldest first
    marks: np.ndarray | None = None  # (K, 2) key-pose tips
    recording: bool = False


def _pt(p) -> tuple[int, int]:
    """Float pixel -> OpenCV fixed point with 4 fractional bits (shift=4)."""
    return int(round(p[0] * 16)), int(round(p[1] * 16))


def draw_grid(frame: np.ndarray, view: View) -> None:
    """Faint lines at every whole chain unit, slightly brighter axes."""
    h, w = frame.shape[:2]
    m = int(np.ceil(view.extent))
    for k in range(-m, m + 1):
        u, v = view.to_px([k, k])
        colour = tuple(c + 14 for c in GRID) if k == 0 else GRID
        cv2.line(frame, (int(round(u)), 0), (int(round(u)), h - 1), colour, 1)
        cv2.line(frame, (0, int(round(v))), (w - 1, int(round(v))), colour, 1)


def draw_legend(frame: np.ndarray, lines: list[str]) -> None:
    """Lines of key help at the bottom-left on a dark band."""
    if not lines:
        return
    h, w = frame.shape[:2]
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, max(0.33, 0.45 * h / 720.0)
    line_h = cv2.getTextSize("Ag", font, scale, 1)[0][1] + max(4, int(round(9 * scale)))
    top = max(0, h - line_h * len(lines) - 6)
    band = frame[top:]
    band[:] = (band.astype(np.uint16) * 110 >> 8).astype(np.uint8)
    for i, s in enumerate(lines):
        cv2.putText(frame, s, (8, top + line_h * (i + 1) - 2), font, scale, TEXT, 1, cv2.LINE_AA)


def draw_background(view: View, area: np.ndarray | None = None) -> np.ndarray:
    """The frame's static layer: grid, reachable area (an (H, W) bool mask) and reach circle."""
    frame = np.empty((view.height, view.width, 3), np.uint8)
    frame[:] = BACKGROUND
    draw_grid(frame, view)
    if area is not None:
        blend = (frame * (1 - AREA_ALPHA) + np.array(AREA) * AREA_ALPHA).astype(np.uint8)
        frame = np.where(area[..., None], blend, frame)
    centre = view.to_px([0.0, 0.0])
    cv2.circle(frame, _pt(centre), int(round(view.n_bones * view.scale * 16)), REACH, 2, cv2.LINE_AA, 4)
    return frame


def draw_chain_frame(view: View, pic: ChainPicture) -> np.ndarray:
    """The planar view as an (H, W, 3) uint8 BGR frame."""
    frame = draw_background(view) if pic.background is None else pic.background.copy()
    px = view.to_px(pic.joints)
    s = view.scale
    if pic.trail is not None and len(pic.trail) > 1:
        tr = np.round(view.to_px(pic.trail) * 16).astype(np.int32)
        cv2.polylines(frame, [tr], False, TRAIL, max(1, int(round(0.03 * s))), cv2.LINE_AA, 4)
    if pic.marks is not None:
        for m in view.to_px(pic.marks):
            cv2.circle(frame, _pt(m), int(round(0.1 * s * 16)), KEY_MARK, 1, cv2.LINE_AA, 4)
    thick = max(2, int(round(0.09 * s)))
    for a, b in zip(px[:-1], px[1:]):
        cv2.line(frame, _pt(a), _pt(b), BONE, thick, cv2.LINE_AA, 4)
    r = max(2.0, 0.08 * s)
    half = max(2, int(round(0.11 * s)))
    c = np.round(px[0]).astype(int)
    cv2.rectangle(frame, (c[0] - half, c[1] - half), (c[0] + half, c[1] + half), ROOT, -1)
    for p in px[1:-1]:
        cv2.circle(frame, _pt(p), int(round(r * 16)), JOINT, -1, cv2.LINE_AA, 4)
    cv2.circle(frame, _pt(px[-1]), int(round(r * 16)), JOINT, 2, cv2.LINE_AA, 4)
    if pic.target is not None:
        t = view.to_px(pic.target)
        colour = LOST if pic.lost else TARGET
        cv2.circle(frame, _pt(t), int(round(max(3.0, 0.12 * s) * 16)), colour, -1, cv2.LINE_AA, 4)
        if pic.lost:
            cv2.line(frame, _pt(px[-1]), _pt(t), LOST, 1, cv2.LINE_AA, 4)
            cv2.circle(frame, _pt(t), int(round(max(5.0, 0.2 * s) * 16)), colour, 1, cv2.LINE_AA, 4)
    if pic.hud:
        draw_hud(frame, pic.hud)
    draw_legend(frame, pic.legend)
    if pic.recording:
        h, w = frame.shape[:2]
        rr = max(4, int(round(0.012 * min(h, w))))
        scale = max(0.35, 0.5 * h / 720.0)
        (tw, th), _ = cv2.getTextSize("REC", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        cv2.circle(frame, (w - 3 * rr, 3 * rr), rr, REC, -1, cv2.LINE_AA)
        cv2.putText(frame, "REC", (w - 5 * rr - tw, 3 * rr + th // 2), cv2.FONT_HERSHEY_SIMPLEX, scale, REC, 1, cv2.LINE_AA)
    return frame


# ---------------------------------------------------------------------------------------------
# humanoid


def body_capsules(rig, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Capsules from each joint to its parent: (a (J-1, 3), b (J-1, 3), radii (J-1,)), metres."""
    parent = rig.arrays["parent"]
    child = np.arange(1, rig.n_joints)
    radii = rig.arrays["radius"][child]
    return joints[parent[child]], joints[child], radii


def draw_effectors(frame: np.ndarray, pixels: np.ndarray, names: list[str], active: int | None,
                   target_px: np.ndarray | None) -> None:
    """Mark the effectors (rings, the dragged one filled) and the drag target (red, with a line)."""
    h = frame.shape[0]
    r = max(5, int(round(0.014 * h)))
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, max(0.33, 0.42 * h / 720.0)
    finite = np.all(np.isfinite(pixels), axis=1)
    middle = float(np.median(pixels[finite, 0])) if finite.any() else 0.0
    for k, (p, name) in enumerate(zip(pixels, names)):
        if not finite[k]:
            continue
        cv2.circle(frame, _pt(p), r * 16, JOINT, -1 if k == active else 2, cv2.LINE_AA, 4)
        width = cv2.getTextSize(name, font, scale, 1)[0][0]
        x = int(p[0]) + r + 3 if p[0] >= middle else int(p[0]) - r - 3 - width  # labels away from the body
        cv2.putText(frame, name, (x, int(p[1]) + r // 2), font, scale, TEXT, 1, cv2.LINE_AA)
    if active is not None and target_px is not None and np.all(np.isfinite(target_px)):
        cv2.line(frame, _pt(pixels[active]), _pt(target_px), TARGET, 1, cv2.LINE_AA, 4)
        cv2.circle(frame, _pt(target_px), max(3, r // 2) * 16, TARGET, -1, cv2.LINE_AA, 4)


BODY_COLOUR = (0.82, 0.70, 0.56)  # BGR in 0..1
HUMANOID_LEGEND = ["drag a hand, foot or head: the body follows", "2 dls  3 fabrik  4 ccd   R reset  Esc quit"]


class HumanoidSession:
    """The 3D humanoid seen by a fixed camera, posed by dragging one effector at a time.

    :meth:`press` picks the effector nearest the cursor on screen (within ``pick_radius`` pixels)
    and holds every other effector where it stands; :meth:`drag_to` puts the dragged effector's
    target where the cursor's ray meets the plane facing the camera at the effector's view depth;
    :meth:`step` solves the whole body (a Crowd of one) toward the targets.
    """

    def __init__(self, size=(720, 720), method: str = DEFAULT_METHOD, iterations: int = 20):
        from crowd_ik.crowd import Crowd
        from crowd_ik.rig import Rig
        from crowd_ik.view.render import Camera

        self.size, self.method, self.iterations = tuple(size), method, iterations
        w, h = self.size
        self.rig = Rig.humanoid()
        self.crowd = Crowd(self.rig, n=1)
        self.camera = Camera((0.0, 1.15, 3.6), (0.0, 0.9, 0.0), 40.0, w, h)
        self.pick_radius = 0.08 * h
        self._renderer = None
        self.reset()
        # compile the solver now (the targets are where the effectors are, so the pose stays)
        self.crowd.solve(self.targets[None].astype(np.float32), method=method, max_iterations=1)

    def reset(self) -> None:
        self.crowd.set_angles(np.zeros(self.rig.n_dof, np.float32))
        self.targets = self.effectors()
        self.active: int | None = None
        self.depth = 0.0

    def effectors(self) -> np.ndarray:
        """(E, 3) float64 world positions of the effectors, metres."""
        return self.crowd.effector_positions()[0].astype(np.float64)

    def cursor_point(self, px: float, py: float) -> np.ndarray:
        """Where the ray through pixel (px, py) meets the view plane at the dragged depth, (3,)."""
        origin, d = self.camera.ray(px, py)
        return origin + d * (self.depth / float(d @ self.camera.forward))

    def press(self, px: float, py: float) -> int | None:
        """Start dragging the effector nearest (px, py); None when none is within pick_radius."""
        pix, depth = self.camera.project(self.effectors())
        dist = np.hypot(pix[:, 0] - px, pix[:, 1] - py)
        dist[~np.isfinite(dist)] = np.inf
        k = int(np.argmin(dist))
        if dist[k] > self.pick_radius:
            return None
        self.targets = self.effectors()  # hold the others where they stand now
        self.active, self.depth = k, float(depth[k])
        self.drag_to(px, py)
        return k

    def drag_to(self, px: float, py: float) -> None:
        if self.active is not None:
            self.targets[self.active] = self.cursor_point(px, py)

    def release(self) -> None:
        self.active = None

    def step(self):
        """Solve toward the targets while dragging; returns the SolveReport (None when idle)."""
        if self.active is None:
            return None
        return self.crowd.solve(self.targets[None].astype(np.float32), method=self.method,
                                max_iterations=self.iterations, tolerance=1e-3)

    def render(self) -> np.ndarray:
        """The body, the effectors and the drag target as an (H, W, 3) uint8 BGR frame."""
        from crowd_ik.view.render import Renderer

        if self._renderer is None:
            self._renderer = Renderer(self.camera, max_capsules=self.rig.n_joints - 1)
        joints = self.crowd.joint_positions()[0]
        a, b, r = body_capsules(self.rig, joints)
        eff = self.effectors()
        error = float(np.linalg.norm(eff - self.targets, axis=1).max())
        hud = [f"humanoid   {self.method} (Taichi, N=1)",
               f"dragging {self.rig.effector_names[self.active]}   error {100 * error:.1f} cm" if self.active is not None
               else "click near a marker and drag"]
        frame = self._renderer.render(a, b, r, BODY_COLOUR, hud_lines=hud)
        pix, _ = self.camera.project(eff)
        target_px = None
        if self.active is not None:
            target_px = self.camera.project(self.targets[self.active][None])[0][0]
        draw_effectors(frame, pix, self.rig.effector_names, self.active, target_px)
        draw_legend(frame, HUMANOID_LEGEND)
        return frame


def to_gui_image(frame: np.ndarray) -> np.ndarray:
    """BGR (H, W, 3) row 0 at the top -> Taichi GUI's RGB (W, H, 3) indexed [x, y] with y up."""
    # out[x, y] = frame[H - 1 - y, x]: a quarter turn clockwise (4x faster than a strided copy)
    return cv2.rotate(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), cv2.ROTATE_90_CLOCKWISE)


__all__ = ["View", "ChainPicture", "HumanoidSession", "tips", "sample_reachable", "reachable_mask", "draw_background",
           "draw_chain_frame",
           "draw_legend", "body_capsules", "draw_effectors", "to_gui_image"]
