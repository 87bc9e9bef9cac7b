"""What is drawn over a rasterised frame with OpenCV: bullet trails (anti-aliased lines fading along their
length, a per-piece depth test against the frame's depth buffer) and the HUD text on a dark box.

plan_trails works a frame's trails out (projection, near clipping, depth test) while its depth buffer is at hand;
paint_trails draws a plan later, possibly on another thread (view.render.Renderer's defer_overlay, the video
pipeline's writer), with the same operations, so a frame is the same bit for bit either way. Overlay carries a
frame's plan and HUD lines.
"""

from __future__ import annotations

import numpy as np

TRAIL_NEAR = 0.1  # metres: trails are clipped at twice the raster's near plane (view.render.NEAR)
TRAIL_COLOR = (90, 200, 255)  # BGR: warm yellow-orange
TRAIL_ALPHA = 0.85  # opacity at a trail's head, fading to 0 at its tail
TRAIL_WIDTH = 0.04  # metres: trail thickness in the world, at least 1 pixel, at most 3
TRAIL_PIECES = 8  # fade steps (and depth-test pieces) along a trail
HUD_MARGIN = 8  # pixels


def _clip_near(p0: np.ndarray, p1: np.ndarray, z0: np.ndarray, z1: np.ndarray, near: float):
    """Move the end of each segment that lies behind the near plane onto it."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s0 = np.where(z0 < near, (near - z0) / (z1 - z0), 0.0)
        s1 = np.where(z1 < near, (near - z1) / (z0 - z1), 0.0)
    return p0 + (p1 - p0) * s0[:, None], p1 + (p0 - p1) * s1[:, None]


def draw_trails(frame: np.ndarray, camera, trails, depth: np.ndarray | None = None) -> None:
    """Draw (T, 2, 3) world segments into frame in place: anti-aliased lines, opaque at [:, 0]
    fading to transparent at [:, 1], composited through one alpha layer.

    depth: the frame's (H, W) view depth (Renderer.depth_buffer); when given, each of a trail's
    TRAIL_PIECES pieces is dropped where the scene at its midpoint's pixel is nearer than it
    (a per-piece depth test: a trail passing behind a limb is hidden there).
    """
    paint_trails(frame, plan_trails(frame.shape, camera, trails, depth))


class TrailPlan:
    """Trails worked out for one frame (plan_trails): per trail its fixed-point pixel polyline
    (T, P+1, 2) int32 (4 fractional bits), thickness (T,), which pieces pass the depth test (T, P),
    and the pixel box (x0, y0, x1, y1) the alpha layer is composited in."""

    __slots__ = ("box", "fixed", "shown", "thick")

    def __init__(self, fixed, thick, shown, box):
        self.fixed, self.thick, self.shown, self.box = fixed, thick, shown, box


def plan_trails(shape, camera, trails, depth: np.ndarray | None = None) -> TrailPlan | None:
    """The geometry of draw_trails for a frame of `shape` (H, W, 3): projection, clipping and the
    depth test (which reads `depth`, so it runs before the next frame overwrites it). None when no
    trail is in view."""
    seg = np.asarray(trails, dtype=np.float64)
    if seg.ndim != 3 or seg.shape[1:] != (2, 3):
        raise ValueError(f"render: trails: expected shape (T, 2, 3) (got {seg.shape})")
    if not np.all(np.isfinite(seg)):
        raise ValueError("render: trails: values must be finite (got NaN or inf)")
    h, w = shape[:2]
    near = TRAIL_NEAR
    z0 = (seg[:, 0] - camera.position) @ camera.forward
    z1 = (seg[:, 1] - camera.position) @ camera.forward
    keep = (z0 > near) | (z1 > near)
    if not np.any(keep):
        return None
    p0, p1 = _clip_near(seg[keep, 0], seg[keep, 1], z0[keep], z1[keep], near)
    steps = np.linspace(0.0, 1.0, TRAIL_PIECES + 1)
    pts = p0[:, None, :] + (p1 - p0)[:, None, :] * steps[None, :, None]  # (T, P+1, 3)
    pix, z = camera.project(pts.reshape(-1, 3))
    pix = np.clip(np.nan_to_num(pix, nan=-1e6), -1e6, 1e6).reshape(len(p0), TRAIL_PIECES + 1, 2)
    lo, hi = pix.min(axis=1), pix.max(axis=1)
    visible = (hi[:, 0] >= -4) & (lo[:, 0] <= w + 4) & (hi[:, 1] >= -4) & (lo[:, 1] <= h + 4)
    if not np.any(visible):
        return None
    fixed = np.round(pix * 16.0).astype(np.int32)  # 4 fractional bits (shift=4)
    z = z.reshape(len(p0), TRAIL_PIECES + 1)
    thick = np.clip(np.rint(camera.pixel_scale(z[:, 0]) * TRAIL_WIDTH), 1, 3).astype(int)
    shown = np.ones((len(p0), TRAIL_PIECES), bool)
    if depth is not None:
        mid_pix = np.rint(0.5 * (pix[:, 1:] + pix[:, :-1])).astype(np.int64)  # (T, P, 2)
        mid_z = 0.5 * (z[:, 1:] + z[:, :-1])
        inside = (mid_pix[..., 0] >= 0) & (mid_pix[..., 0] < w) & (mid_pix[..., 1] >= 0) & (mid_pix[..., 1] < h)
        scene = np.full(mid_z.shape, np.inf)
        scene[inside] = depth[mid_pix[..., 1][inside], mid_pix[..., 0][inside]]
        shown = scene >= mid_z * 0.99 - 0.05
    box = pix[visible].reshape(-1, 2)  # pixel box of the drawn trails, plus the line half-width
    x0, y0 = np.clip(np.floor(box.min(axis=0)) - 4, 0, [w, h]).astype(int)
    x1, y1 = np.clip(np.ceil(box.max(axis=0)) + 5, 0, [w, h]).astype(int)
    return TrailPlan(fixed[visible], thick[visible], shown[visible], (int(x0), int(y0), int(x1), int(y1)))


def paint_trails(frame: np.ndarray, plan: TrailPlan | None) -> None:
    """Draw planned trails into frame in place (the drawing half of draw_trails). The alpha layer
    covers only the plan's pixel box, so a frame costs what its trails cover, not its size."""
    import cv2

    if plan is None:
        return
    x0, y0, x1, y1 = plan.box
    if x1 <= x0 or y1 <= y0:
        return
    alpha = np.zeros((y1 - y0, x1 - x0), np.uint8)
    origin = np.array([x0, y0], np.int32) * 16  # the layer's (0, 0) in 4-bit fixed point
    fixed = plan.fixed - origin
    for k in range(TRAIL_PIECES - 1, -1, -1):  # tail first, so brighter pieces overwrite fainter ones
        value = int(round(255 * TRAIL_ALPHA * (1.0 - k / TRAIL_PIECES)))
        for th in np.unique(plan.thick):
            sel = (plan.thick == th) & plan.shown[:, k]
            lines = np.ascontiguousarray(fixed[sel][:, k : k + 2])  # (S, 2, 2): S two-point polylines
            cv2.polylines(alpha, lines, False, value, int(th), cv2.LINE_AA, 4)
    ys, xs = np.nonzero(alpha)
    a = alpha[ys, xs, None].astype(np.float32) * np.float32(1.0 / 255.0)
    ys += y0
    xs += x0
    under = frame[ys, xs].astype(np.float32)
    color = np.array(TRAIL_COLOR, np.float32)
    frame[ys, xs] = (under + (color - under) * a + 0.5).astype(np.uint8)


class Overlay:
    """What goes over a rasterised frame: planned trails and HUD lines; paint(frame) draws them in
    place exactly as Renderer.render does when defer_overlay is off."""

    __slots__ = ("hud_lines", "trails")

    def __init__(self, trails: TrailPlan | None, hud_lines: list[str] | None):
        self.trails, self.hud_lines = trails, hud_lines

    def paint(self, frame: np.ndarray) -> None:
        paint_trails(frame, self.trails)
        if self.hud_lines:
            draw_hud(frame, self.hud_lines)


def draw_hud(frame: np.ndarray, lines) -> None:
    """Write lines of text top-left in frame, in place, white on a translucent dark box."""
    import cv2

    if isinstance(lines, str) or not all(isinstance(s, str) for s in lines):
        raise ValueError(f"render: hud_lines: expected a list of str (got {lines!r:.80})")
    h, w = frame.shape[:2]
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = max(0.35, 0.55 * h / 720.0)
    thickness = 1 if h < 1000 else 2
    sizes = [cv2.getTextSize(s, font, scale, thickness) for s in lines]
    line_h = max(sz[0][1] + sz[1] for sz in sizes) + int(round(6 * scale))
    pad = int(round(8 * scale))
    box_w = max(sz[0][0] for sz in sizes) + 2 * pad
    box_h = line_h * len(lines) + pad
    x0, y0 = HUD_MARGIN, HUD_MARGIN
    x1, y1 = min(w, x0 + box_w), min(h, y0 + box_h)
    region = frame[y0:y1, x0:x1]
    region[:] = (region.astype(np.uint16) * 90 >> 8).astype(np.uint8)  # ~35% brightness
    for i, s in enumerate(lines):
        baseline_y = y0 + pad // 2 + line_h * (i + 1) - sizes[i][1]
        cv2.putText(frame, s, (x0 + pad, baseline_y), font, scale, (245, 245, 245), thickness, cv2.LINE_AA)
