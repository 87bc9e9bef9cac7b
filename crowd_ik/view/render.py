"""Off-screen frames: a pinhole Camera, and a Renderer that rasterises limbs, bullets and shards
in Taichi, then trails and the HUD over it (view/overlay.py, OpenCV).

A frame is an (H, W, 3) uint8 BGR array, row 0 at the top, so the same drawing serves the video
sinks, PNG stills and the mouse mode. The world is y up, metres, ground plane y = 0.

The heavy part is one kernel launch per frame whatever the number of primitives (kernels/raster.py
draw_frame, five passes in turn; kernels/raster.py explains the method): copy this frame's primitives in, clear the buffers,
rasterise every capsule and sphere into an integer z-buffer (exact ray-capsule hits, `atomic_min`
on (depth bits, id) keys, so frames are bit-identical across runs and thread counts), splat soft
ground shadows into a half-resolution buffer, shade every pixel (sky gradient, ground grid,
shadows, Lambert + ambient + rim capsules). A new camera's sky and ground are computed where used; the
second frame that keeps the camera stores them, later ones repaint only dirty tiles. Bullet trails
(anti-aliased lines fading along their length; drawn over the scene, without a depth test) and HUD
text on a dark box are drawn afterwards with OpenCV.

Spheres are capsules with both ends at the centre, stored after the capsules: primitive id
M + k is sphere k. `Renderer.timings` holds the last frame's milliseconds (raster: validation,
upload, kernels, copy out; overlay: trails and HUD).

For the video pipeline (crowd_ik.io.pipeline) the Renderer can hand its work on: with
`frame_source` set, each frame is copied into a buffer it supplies (a recycled slot, not a new
array), and with `defer_overlay` the trails and HUD are not drawn but left in `overlay` (an
Overlay: the trails' pixels and depth test are worked out here, from this frame's depth buffer; its
`paint(frame)` draws them later, on another thread, with the same operations as draw_trails and
draw_hud, so the frame is the same bit for bit).
"""

from __future__ import annotations

import math
import time

import numpy as np

from crowd_ik.runtime import ensure_init
from crowd_ik.view.overlay import Overlay, plan_trails

NEAR = 0.05  # metres: hits nearer than this view depth are clipped


def _vec3(name: str, value) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: expected 3 finite numbers (got {value!r})")
    return v


def _size(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 16 or value % 2:
        raise ValueError(f"{name}: expected an even integer >= 16 (got {value!r})")
    return int(value)


class Camera:
    """Perspective pinhole camera.

    position, look_at: (3,) world points, metres; fov_deg: vertical field of view in degrees
    (0 < fov < 180); width, height: image size in pixels (even, >= 16); up: world up hint.
    Pixel coordinates are x right, y down, with pixel (i, j)'s centre at (i, j) (OpenCV's
    convention), so the image centre is ((W - 1) / 2, (H - 1) / 2). Depth is the view depth: the
    distance along the viewing direction, negative behind the camera.
    """

    def __init__(self, position, look_at, fov_deg, width, height, up=(0.0, 1.0, 0.0)):
        self.position = _vec3("camera position", position)
        self.look_at = _vec3("camera look_at", look_at)
        up_hint = _vec3("camera up", up)
        numeric = isinstance(fov_deg, (int, float, np.floating, np.integer)) and not isinstance(fov_deg, bool)
        if not numeric or not 0.0 < float(fov_deg) < 180.0:
            raise ValueError(f"camera fov_deg: expected a number in (0, 180) (got {fov_deg!r})")
        self.fov_deg = float(fov_deg)
        self.width = _size("camera width", width)
        self.height = _size("camera height", height)
        forward = self.look_at - self.position
        dist = np.linalg.norm(forward)
        if dist < 1e-9:
            raise ValueError(f"camera look_at: must differ from position (got {list(self.look_at)})")
        self.forward = forward / dist
        right = np.cross(self.forward, up_hint)
        if np.linalg.norm(right) < 1e-6 * max(np.linalg.norm(up_hint), 1e-300):
            raise ValueError(f"camera up: must not be parallel to the viewing direction (got {list(up_hint)})")
        self.right = right / np.linalg.norm(right)
        self.up = np.cross(self.right, self.forward)
        self.focal = 0.5 * self.height / math.tan(math.radians(self.fov_deg) / 2.0)
        self.cx = (self.width - 1) / 2.0
        self.cy = (self.height - 1) / 2.0

    def __repr__(self) -> str:
        return (
            f"Camera(position={self.position.tolist()}, look_at={self.look_at.tolist()}, "
            f"fov_deg={self.fov_deg}, width={self.width}, height={self.height})"
        )

    @property
    def view_matrix(self) -> np.ndarray:
        """(4, 4) world -> camera transform, OpenGL style: camera x right, y up, looking down -z."""
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = self.right, self.up, -self.forward
        m[:3, 3] = -m[:3, :3] @ self.position
        return m

    @property
    def intrinsics(self) -> np.ndarray:
        """(3, 3) pixel matrix K: [u, v, 1] ~ K @ [x_right, y_down, depth]."""
        return np.array([[self.focal, 0.0, self.cx], [0.0, self.focal, self.cy], [0.0, 0.0, 1.0]])

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """points (M, 3) world -> (pixels (M, 2) float64 x right y down, depth (M,)).

        Points with depth <= NEAR (behind or at the camera) get NaN pixels.
        """
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise ValueError(f"project: points: expected shape (M, 3) (got {p.shape})")
        q = p - self.position
        depth = q @ self.forward
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.cx + self.focal * (q @ self.right) / depth
            v = self.cy - self.focal * (q @ self.up) / depth
        pix = np.stack([u, v], axis=1)
        pix[depth <= NEAR] = np.nan
        return pix, depth

    def ray(self, px, py) -> tuple[np.ndarray, np.ndarray]:
        """Ray through pixel coordinates (px, py) (scalars or arrays of one shape): (origin (3,),
        unit direction (..., 3)), for picking."""
        px = np.asarray(px, dtype=np.float64)
        py = np.asarray(py, dtype=np.float64)
        if px.shape != py.shape or not (np.all(np.isfinite(px)) and np.all(np.isfinite(py))):
            raise ValueError(f"ray: px, py: expected finite values of one shape (got shapes {px.shape}, {py.shape})")
        d = (
            self.forward * self.focal
            + self.right * (px - self.cx)[..., None]
            - self.up * (py - self.cy)[..., None]
        )
        return self.position.copy(), d / np.linalg.norm(d, axis=-1, keepdims=True)

    def pixel_scale(self, depth):
        """Pixels per metre (of a length facing the camera) at view depth `depth`."""
        return self.focal / np.asarray(depth, dtype=np.float64)

    def packed(self) -> np.ndarray:
        """(16,) float32: eye, right, up, forward, focal, cx, cy, near (the kernels' layout)."""
        return np.concatenate(
            [self.position, self.right, self.up, self.forward, [self.focal, self.cx, self.cy, NEAR]]
        ).astype(np.float32)


def decode_keys(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """z-buffer keys (H, W) int64 -> (ids (H, W) int32, -1 where empty; depth (H, W) float32, inf where empty)."""
    from crowd_ik.kernels.raster import EMPTY_ID

    ids = (keys & 0xFFFFFFFF).astype(np.int64)
    depth = (keys >> 32).astype(np.int32).view(np.float32)
    empty = ids == EMPTY_ID
    return np.where(empty, -1, ids).astype(np.int32), np.where(empty, np.float32(np.inf), depth)


def _points(name: str, value, limit: int, limit_name: str) -> np.ndarray:
    a = np.asarray(value, dtype=np.float32)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"render: {name}: expected shape (M, 3) (got {a.shape})")
    if a.shape[0] > limit:
        raise ValueError(f"render: {name}: {a.shape[0]} rows exceed {limit_name}={limit}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"render: {name}: values must be finite (got NaN or inf)")
    return a


def _radii(name: str, value, m: int) -> np.ndarray:
    r = np.asarray(value, dtype=np.float32)
    if r.shape != (m,):
        raise ValueError(f"render: {name}: expected shape ({m},) (got {r.shape})")
    if not np.all(np.isfinite(r)) or (m and r.min() < 0.0):
        raise ValueError(f"render: {name}: expected finite values >= 0 (got min {r.min() if m else None})")
    return r


def _colors(name: str, value, m: int) -> np.ndarray:
    c = np.asarray(value)
    if c.shape not in ((m, 3), (3,)):
        raise ValueError(f"render: {name}: expected shape ({m}, 3) or (3,) (got {c.shape})")
    if c.dtype == np.uint8:
        c = c.astype(np.float32) / 255.0
    else:
        c = c.astype(np.float32)
        if not np.all(np.isfinite(c)) or (c.size and (c.min() < 0.0 or c.max() > 1.0)):
            raise ValueError(f"render: {name}: float colours must lie in [0, 1] (got {c.min()}..{c.max()})")
    return np.broadcast_to(c, (m, 3))


class Renderer:
    """Draws frames of capsules (limbs) and spheres (bullets, shards) seen by `camera`.

    All Taichi buffers are allocated once here, sized for `max_capsules` + `max_spheres`
    primitives and the camera's image size; `render` only copies this frame's data in.
    `camera` may be replaced between frames by one of the same image size.
    """

    def __init__(self, camera: Camera, max_capsules: int, max_spheres: int = 0):
        if not isinstance(camera, Camera):
            raise ValueError(f"Renderer: camera: expected a Camera (got {type(camera).__name__})")
        for name, v in (("max_capsules", max_capsules), ("max_spheres", max_spheres)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"Renderer: {name}: expected an integer >= 0 (got {v!r})")
        ensure_init()
        import taichi as ti

        from crowd_ik.kernels import raster as kr

        self._camera = camera
        self.max_capsules = int(max_capsules)
        self.max_spheres = int(max_spheres)
        p = max(1, self.max_capsules + self.max_spheres)
        h, w = camera.height, camera.width
        self._host_a = np.zeros((p, 3), np.float32)
        self._host_b = np.zeros((p, 3), np.float32)
        self._host_r = np.zeros(p, np.float32)
        self._host_c = np.zeros((p, 3), np.float32)
        self._cam = ti.ndarray(ti.f32, shape=16)
        self._pa = ti.ndarray(ti.f32, shape=(p, 3))
        self._pb = ti.ndarray(ti.f32, shape=(p, 3))
        self._radius = ti.ndarray(ti.f32, shape=p)
        self._color = ti.ndarray(ti.f32, shape=(p, 3))
        self._keys = ti.ndarray(ti.i64, shape=(h, w))
        self._shadow = ti.ndarray(ti.i32, shape=(h // 2, w // 2))
        self._background = ti.ndarray(ti.f32, shape=(h, w, 3))  # ground and sky for _background_cam
        self._background_cam = None
        self._background_stored = False  # whether _background holds _background_cam's values yet
        # Dirty tiles (kernels/raster.py TILE): bit 0 drawn this frame, bit 1 drawn last frame; the
        # rest of the frame buffer keeps the background. All ones: clear and shade everything.
        self._tiles = ti.ndarray(ti.i32, shape=((h + kr.TILE - 1) // kr.TILE, (w + kr.TILE - 1) // kr.TILE))
        self._tiles.fill(1)
        # The colour buffer is a host array the shading kernel writes in place (zero-copy on the
        # CPU backend): an ndarray's to_numpy costs ~20 ns per uint8 element there (57 ms at 720p).
        self._frame = np.zeros((h, w, 3), np.uint8)
        self._depth = np.zeros((h, w), np.float32)  # what each pixel shows: view depth, inf = sky
        self._count = 0
        self.timings = {"raster_ms": 0.0, "overlay_ms": 0.0}
        self.frame_source = None  # callable -> (H, W, 3) uint8 buffer the next frame goes into; None: a new array
        self.defer_overlay = False  # True: render() leaves trails and HUD to self.overlay.paint(frame)
        self.overlay = None  # the last frame's Overlay when defer_overlay is set

    @property
    def camera(self) -> Camera:
        return self._camera

    @camera.setter
    def camera(self, camera: Camera) -> None:
        if not isinstance(camera, Camera):
            raise ValueError(f"Renderer.camera: expected a Camera (got {type(camera).__name__})")
        if (camera.width, camera.height) != (self._camera.width, self._camera.height):
            raise ValueError(
                f"Renderer.camera: image size must stay {self._camera.width}x{self._camera.height} "
                f"(got {camera.width}x{camera.height})"
            )
        self._camera = camera

    def render(
        self,
        capsules_a,
        capsules_b,
        radii,
        colors,
        spheres=None,
        sphere_radii=None,
        sphere_colors=None,
        trails=None,
        hud_lines=None,
    ) -> np.ndarray:
        """One frame: (H, W, 3) uint8 BGR.

        capsules_a, capsules_b: (M, 3) end points, metres; radii: (M,) metres; colors: (M, 3) or
        (3,), BGR floats in 0..1 or uint8. spheres: (K, 3) centres; sphere_radii (K,);
        sphere_colors (K, 3) or (3,). trails: (T, 2, 3) segments, [:, 0] the head (opaque) and
        [:, 1] the tail (transparent). hud_lines: list of str, drawn top-left.
        """
        t_start = time.perf_counter()
        a = _points("capsules_a", capsules_a, self.max_capsules, "max_capsules")
        b = _points("capsules_b", capsules_b, self.max_capsules, "max_capsules")
        if a.shape != b.shape:
            raise ValueError(f"render: capsules_b: expected shape {a.shape} like capsules_a (got {b.shape})")
        m = a.shape[0]
        r = _radii("radii", radii, m)
        c = _colors("colors", colors, m)
        if spheres is None:
            s = np.zeros((0, 3), np.float32)
            sr = np.zeros(0, np.float32)
            sc = np.zeros((0, 3), np.float32)
        else:
            s = _points("spheres", spheres, self.max_spheres, "max_spheres")
            k = s.shape[0]
            if sphere_radii is None or sphere_colors is None:
                raise ValueError("render: spheres given without sphere_radii and sphere_colors (got None)")
            sr = _radii("sphere_radii", sphere_radii, k)
            sc = _colors("sphere_colors", sphere_colors, k)
        k = s.shape[0]
        n = m + k
        self._host_a[:m], self._host_b[:m], self._host_r[:m], self._host_c[:m] = a, b, r, c
        self._host_a[m:n], self._host_b[m:n], self._host_r[m:n], self._host_c[m:n] = s, s, sr, sc
        self._count = n
        if hud_lines is not None and (isinstance(hud_lines, str) or not all(isinstance(x, str) for x in hud_lines)):
            raise ValueError(f"render: hud_lines: expected a list of str (got {hud_lines!r:.80})")
        frame = self._raster(n)
        t_mid = time.perf_counter()
        overlay = Overlay(plan_trails(frame.shape, self._camera, trails, self._depth) if trails is not None else None,
                          list(hud_lines) if hud_lines else None)
        if self.defer_overlay:
            self.overlay = overlay
        else:
            overlay.paint(frame)
        t_end = time.perf_counter()
        self.timings = {"raster_ms": 1e3 * (t_mid - t_start), "overlay_ms": 1e3 * (t_end - t_mid)}
        return frame

    def _raster(self, n: int) -> np.ndarray:
        from crowd_ik.kernels import raster as kr

        packed = self._camera.packed()
        self._cam.from_numpy(packed)
        if self._background_cam is None or not np.array_equal(packed, self._background_cam):
            # every pixel changes: shade all, each background value computed where used and not stored
            self._background_cam, self._background_stored, shading = packed, False, kr.SHADE_FRESH
            self._tiles.fill(1)
        elif not self._background_stored:  # the camera stays: its background is worth storing now
            self._background_stored, shading = True, kr.SHADE_FILL
        else:
            shading = kr.SHADE_TILES
        # load, clear, rasterise, splat shadows and shade (all pixels for a new camera, else the dirty tiles)
        kr.draw_frame(self._cam, self._host_a, self._host_b, self._host_r, self._host_c, n, self._pa, self._pb,
                      self._radius, self._color, self._keys, self._shadow, self._tiles, self._background,
                      self._frame, self._depth, shading)
        if self.frame_source is None:
            return self._frame.copy()
        out = self.frame_source()  # the frame buffer persists (dirty tiles): the frame is copied out
        np.copyto(out, self._frame)
        return out

    def id_buffer(self) -> tuple[np.ndarray, np.ndarray]:
        """The last frame's z-buffer: (ids (H, W) int32, -1 where no primitive; depth (H, W)
        float32 view depth, inf where none). Ids count capsules first, then spheres."""
        return decode_keys(self._keys.to_numpy())

    def depth_buffer(self) -> np.ndarray:
        """The last frame's (H, W) float32 view depth of what each pixel shows (a primitive or the
        ground; inf for sky): for picking, and the trails' depth test."""
        return self._depth.copy()

    def shadow_buffer(self) -> np.ndarray:
        """The last frame's ground darkness, (H/2, W/2) float32 in 0..1 (texel (i, j) is seen
        through pixel coordinates (2j + 0.5, 2i + 0.5))."""
        from crowd_ik.kernels.raster import SHADOW_SCALE

        return self._shadow.to_numpy().astype(np.float32) / SHADOW_SCALE


def warm_kernels() -> None:
    """Load (or compile) the three variants of the frame kernel on a 16x16 frame: a new camera's frame, then two
    with the same camera (the first stores its background). A window or the drawing process calls it before its
    first real frame, so that no frame waits for a kernel (a cache load takes a second or more)."""
    tiny = Renderer(Camera((0.0, 1.0, 3.0), (0.0, 1.0, 0.0), 50.0, 16, 16), 1, 1)
    for _ in range(3):
        tiny.render(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), np.full(1, 0.1, np.float32),
                    np.zeros((1, 3), np.float32))
