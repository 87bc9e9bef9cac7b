"""Taichi kernels of the off-screen renderer: capsules and spheres into a z-buffer, soft ground
shadows, and one shading pass per pixel.

Why this shape (see also crowd_ik/render.py):
- Primitives are capsules (segment a-b, radius r); a sphere is a capsule with a == b. A frame has
  up to ~150,000 of them, each covering a few to a few hundred pixels, so `raster_capsules` is
  parallel over primitives: each projects its capsule to an exact, conservative screen box (the
  box of its two end spheres), clipped to the screen, and loops over the pixel centres inside,
  intersecting the pixel's ray with the capsule exactly. A per-pixel loop over all primitives
  would need a spatial index; a per-primitive loop needs none and its cost follows covered area.
- The z-buffer is one int64 key per pixel, (float32 bits of the view depth << 32) | primitive id,
  lowered with `ti.atomic_min`. Positive float32 values order like their bit patterns, so the
  smallest key is the nearest hit, and equal depths go to the lower id: the result is the same
  bit for bit whatever the thread count or schedule (no float atomics anywhere).
- A capsule's radius is inflated to at least `MIN_PIXEL_RADIUS` pixels at its far end, so any
  primitive in view covers at least one pixel centre (a disc of radius sqrt(2)/2 always does)
  and thin far limbs draw as unbroken lines instead of dotted ones.
- Shadows come from a light straight overhead: `splat_shadows` is parallel over primitives too;
  each covers the screen box of its ground footprint and raises an integer darkness buffer with
  `ti.atomic_max` (deterministic again). The footprint is the capsule's vertical projection; its
  edge softens and its darkness fades with height. Shadows are soft, so the buffer has half the
  image's resolution (texel (i, j) is seen through pixel coordinates (2j + 0.5, 2i + 0.5), the
  centre of a 2x2 block) and is sampled bilinearly: a quarter of the splatting work, which
  otherwise dominates a crowd frame (footprints are wider than the limbs).
- `shade_frame` is parallel over pixels: the winning primitive id and depth give the hit point
  and normal (Lambert + hemisphere ambient + rim + a little specular, darkened near the ground);
  pixels without a hit see the ground plane y = 0 (anti-aliased 1 m grid, shadows, distance fog)
  or the sky gradient. The ground also hides the parts of capsules below y = 0. Everything about
  the ground and sky but the shadows depends on the camera alone, so `shade_background` computes
  it once per camera and a ground pixel costs one multiply-add per channel. A new camera's frame shades
  every pixel anyway, so there one pass (`shade_frame_fresh`) computes each pixel's background where it
  is used, its grid and fog only where no primitive in front of the ground hides them, and stores none
  of it (a follow camera never sees it again); the renderer stores it on the second frame that keeps
  the camera (draw_frame SHADE_FILL). `shade_frame_background` (compute, store and use) stays for tests.
- `raster_capsules` and `splat_shadows` loop, in each row of a wide enough box, only over the span of
  pixels whose rays may meet the capsule or whose ground points may be in its shadow
  (kernels/raster_cover.py: conservative, so keys and shadow levels stay the same bit for bit).
- Packets: a row span of PACKET_MIN or more pixels is tested LANES (16) pixels at a time, each pixel one lane
  of a `ti.types.vector(16, ti.f32)` (kernels/raster_lanes.capsule_hit_lanes, packed SIMD on the CPU); a
  narrower span, pixel by pixel with the same function. An arena frame's capsule raster costs 5 ms instead of
  8 (1280x720, 2 threads); small far capsules (stress_10k) gain nothing and lose nothing. `splat_shadows` does
  the same with texel rows (raster_lanes.shadow_lanes; narrow rows keep shadow_value): 8 ms -> 4.4-5.3.
- Work split for the cores: Taichi's CPU backend hands out a parallel loop in tasks of at least 512
  iterations, so the image passes loop over (row, SPAN-pixel piece), (row, tile column) or tiles, and
  `raster_capsules` and `splat_shadows` over several items per primitive (each every parts-th row) when there
  are few.
- Dirty tiles: `raster_capsules` and `splat_shadows` flag the TILE x TILE pixel tiles their screen
  boxes touch; `clear_buffers` and `shade_frame` work only on tiles drawn on this frame or the last,
  so the rest of a persistent frame buffer keeps its background (a crowd seen from afar covers a
  sixth of the tiles).

Camera, packed in a (16,) float32 array `cam` (see `crowd_ik.view.render.Camera.packed`):
eye [0:3], right [3:6], up [6:9], forward [9:12] (orthonormal, world frame), focal length in
pixels [12], principal point cx [13], cy [14], near plane depth [15]. Pixel (px, py) centres sit
at integer coordinates, x right, y down; their ray is forward*focal + right*(px-cx) - up*(py-cy).

Arrays: P primitives (only the first n are drawn), H x W pixels.
  pa, pb: (P, 3) float32 end points, metres, world frame; radius: (P,) float32 metres;
  color: (P, 3) float32 0..1, BGR; keys: (H, W) int64; shadow: (H/2, W/2) int32 (0..SHADOW_SCALE);
  frame: (H, W, 3) uint8 BGR, row 0 at the top; depth: (H, W) float32 view depth, metres.
Modules: raster_geometry (the look's constants, shared with the NumPy twin crowd_ik/reference/raster.py,
and the ray and shadow geometry), this one (buffers, primitives, the z-buffer and shadow splats),
raster_cover (the row spans), raster_shade (background and per-pixel shading; re-exported here).

Bit for bit: fast math puts `reassoc` on every float operation (no contraction: no FMA is emitted), so
LLVM regroups sums by where their terms come from. Hoisting the camera's reads out of a pixel loop, or
giving an intermediate value (the ray origin d0) one more use, changed the last bit of some tilted
cameras' pixels. The 16-pixel packets group some sums otherwise again (d0 has 16 uses in a packet), which is
why the golden frames were re-recorded with them (kernels/raster_lanes.py); a frame is still the same bit for
bit whatever the thread count, since which rows go through packets depends only on their span.
"""


import taichi as ti

from crowd_ik.kernels.compile_settings import with_cfg_passes
from crowd_ik.kernels.raster_geometry import (  # noqa: F401  (EMPTY_ID, GROUND: the renderer's too)
    _CORNER_X, _CORNER_Z, BIG, EMPTY_ID, GROUND, SHADOW_MAX_HEIGHT, SHADOW_SCALE, TILE, cam_vec, dir_origin,
    effective_radius, empty_key, mark_tiles, pixel_range, primitive_part, primitive_parts, row3, shadow_soft,
    shadow_value, sphere_bounds,
)
from crowd_ik.kernels.raster_cover import ROW_SPAN_MIN, capsule_row, shadow_row_span
from crowd_ik.kernels.raster_shade import (  # noqa: F401  (one module to launch from)
    background_all, shade_all, shade_background, shade_frame, shade_frame_background, shade_frame_fresh, shade_fresh,
    shade_tiles,
)
from crowd_ik.kernels.raster_lanes import L as LANES
from crowd_ik.kernels.raster_lanes import PACKET_MIN, capsule_hit_lanes, shadow_lanes
from crowd_ik.kernels.work_split import banded_count, banded_item

ndarray = ti.types.ndarray

# draw_frame's shading step (see there)
SHADE_TILES = 0
SHADE_FRESH = 1
SHADE_FILL = 2


@with_cfg_passes
@ti.kernel
def clear_buffers(keys: ndarray(dtype=ti.i64, ndim=2), shadow: ndarray(dtype=ti.i32, ndim=2),
                  tiles: ndarray(dtype=ti.i32, ndim=2)):
    """Start a frame: in every tile the last frame flagged (tiles bit 0), keys := empty (no hit,
    infinite depth) and the shadow texels (H/2, W/2) whose pixels (2i, 2j) lie in it := 0; then
    each tile's bit 1 <- bit 0 (drawn last frame: shade_frame repaints it) and bit 0 <- 0.

    tiles ((H + TILE - 1) // TILE, (W + TILE - 1) // TILE) int32; all ones clears everything.
    The image loops run in parallel over tiles or pieces of rows with serial loops inside: on the
    CPU backend that is several times faster than a ti.ndrange over pixels (whose flat index is
    divided back into (row, column) for every pixel), and gives Taichi's 512-iteration tasks
    (raster_geometry.SPAN) enough items to share among the cores."""
    clear_tiles(keys, shadow, tiles)


@ti.func
def clear_tiles(keys: ti.template(), shadow: ti.template(), tiles: ti.template()):
    """clear_buffers' loop (a top-level loop of the kernel it is inlined in: parallel over tiles)."""
    height = keys.shape[0]
    width = keys.shape[1]
    columns = tiles.shape[1]
    rows = tiles.shape[0]
    for item in range(banded_count(rows) * columns):  # tile rows in bands (kernels/work_split.py)
        ty = banded_item(item // columns, rows)
        if ty >= rows:
            continue
        tx = item % columns
        flags = tiles[ty, tx]
        if flags & 1:
            y0 = ty * TILE
            x0 = tx * TILE
            for py in range(y0, ti.min(y0 + TILE, height)):
                for px in range(x0, ti.min(x0 + TILE, width)):
                    keys[py, px] = empty_key()
            for i in range(y0 // 2, ti.min((y0 + TILE) // 2, shadow.shape[0])):
                for j in range(x0 // 2, ti.min((x0 + TILE) // 2, shadow.shape[1])):
                    shadow[i, j] = 0
        tiles[ty, tx] = (flags & 1) << 1


@with_cfg_passes
@ti.kernel
def load_primitives(
    src_a: ndarray(dtype=ti.f32, ndim=2),
    src_b: ndarray(dtype=ti.f32, ndim=2),
    src_r: ndarray(dtype=ti.f32, ndim=1),
    src_c: ndarray(dtype=ti.f32, ndim=2),
    n: ti.i32,
    pa: ndarray(dtype=ti.f32, ndim=2),
    pb: ndarray(dtype=ti.f32, ndim=2),
    radius: ndarray(dtype=ti.f32, ndim=1),
    color: ndarray(dtype=ti.f32, ndim=2),
):
    """Copy the first n rows of the host arrays into the renderer's ndarrays (one launch; an
    ndarray's from_numpy costs ~10 ns per element on the CPU backend, this ~1 ns)."""
    load_rows(src_a, src_b, src_r, src_c, n, pa, pb, radius, color)


@ti.func
def load_rows(src_a: ti.template(), src_b: ti.template(), src_r: ti.template(), src_c: ti.template(), n,
              pa: ti.template(), pb: ti.template(), radius: ti.template(), color: ti.template()):
    """load_primitives's loop (the top-level, parallel loop of the kernel it is inlined in)."""
    for i in range(n):
        for c in ti.static(range(3)):
            pa[i, c] = src_a[i, c]
            pb[i, c] = src_b[i, c]
            color[i, c] = src_c[i, c]
        radius[i] = src_r[i]


@with_cfg_passes
@ti.kernel
def raster_capsules(
    cam: ndarray(dtype=ti.f32, ndim=1),
    pa: ndarray(dtype=ti.f32, ndim=2),
    pb: ndarray(dtype=ti.f32, ndim=2),
    radius: ndarray(dtype=ti.f32, ndim=1),
    n: ti.i32,
    keys: ndarray(dtype=ti.i64, ndim=2),
    tiles: ndarray(dtype=ti.i32, ndim=2),
):
    """Lower keys[py, px] to (depth bits << 32 | i) for every primitive i < n whose capsule the
    pixel's ray enters at view depth >= near. keys must be cleared first. Every tile of a
    primitive's screen box is flagged in tiles (bit 0)."""
    raster_loop(cam, pa, pb, radius, n, keys, tiles)


@ti.func
def raster_loop(cam: ti.template(), pa: ti.template(), pb: ti.template(), radius: ti.template(), n,
                keys: ti.template(), tiles: ti.template()):
    """raster_capsules's loop (the top-level, parallel loop of the kernel it is inlined in), over
    primitive_parts(n) items per primitive, each doing every parts-th pixel row of its box (an arena's ~900
    primitives would otherwise be one of Taichi's tasks, on one thread)."""
    height = keys.shape[0]
    width = keys.shape[1]
    parts = primitive_parts(n)
    for item in range(n * parts):
        i, part = primitive_part(item, n, parts)
        eye = cam_vec(cam, 0)
        right = cam_vec(cam, 3)
        up = cam_vec(cam, 6)
        fwd = cam_vec(cam, 9)
        focal = cam[12]
        near = cam[15]
        a = row3(pa, i) - eye
        b = row3(pb, i) - eye
        za = a.dot(fwd)
        zb = b.dot(fwd)
        r = effective_radius(za, zb, radius[i], focal)
        if ti.max(za, zb) + r >= near:
            xr = ti.Vector([0, width - 1])
            yr = ti.Vector([0, height - 1])
            if ti.min(za, zb) - r > near:
                bxa = sphere_bounds(a.dot(right), za, r)
                bxb = sphere_bounds(b.dot(right), zb, r)
                bya = sphere_bounds(a.dot(up), za, r)
                byb = sphere_bounds(b.dot(up), zb, r)
                cx = cam[13]
                cy = cam[14]
                xr = pixel_range(cx + focal * ti.min(bxa[0], bxb[0]), cx + focal * ti.max(bxa[1], bxb[1]), width)
                yr = pixel_range(cy - focal * ti.max(bya[1], byb[1]), cy - focal * ti.min(bya[0], byb[0]), height)
            # else: the capsule crosses the near plane; test every pixel of the screen.
            if part == 0 and xr[0] <= xr[1] and yr[0] <= yr[1]:
                mark_tiles(tiles, yr[0], yr[1], xr[0], xr[1])
            d0 = dir_origin(cam)
            py = yr[0] + part
            while py <= yr[1]:
                x0 = xr[0]
                x1 = xr[1]
                if x1 - x0 >= ROW_SPAN_MIN:  # (a span costs more than it saves on a narrow box)
                    x0, x1 = capsule_row(a, b, r, cam, py, xr[0], xr[1])
                fy = ti.cast(py, ti.f32)
                if x1 - x0 >= PACKET_MIN:  # LANES pixels at a time (kernels/raster_lanes.py)
                    px0 = x0
                    while px0 <= x1:
                        fx = ti.Vector([ti.cast(px0 + k, ti.f32) for k in ti.static(range(LANES))])
                        t, zf = capsule_hit_lanes(d0, right, up, fwd, fx, fy, a, b, r)
                        for k in ti.static(range(LANES)):
                            if px0 + k <= x1 and t[k] > 0.0:
                                lower_key(keys, py, px0 + k, ti.cast(t[k] * zf[k], ti.f32), near, i)
                        px0 += LANES
                else:
                    for px in range(x0, x1 + 1):
                        t, zf = capsule_hit_lanes(d0, right, up, fwd, ti.cast(px, ti.f32), fy, a, b, r)
                        if t > 0.0:
                            lower_key(keys, py, px, ti.cast(t * zf, ti.f32), near, i)
                py += parts


@ti.func
def raise_shadow(shadow: ti.template(), py, px, v):
    """shadow[py, px] := max(shadow[py, px], round(SHADOW_SCALE v)) for a darkness v in 0..1."""
    level = ti.cast(v * SHADOW_SCALE + 0.5, ti.i32)
    if level > shadow[py, px]:  # levels only rise
        ti.atomic_max(shadow[py, px], level)


@ti.func
def lower_key(keys: ti.template(), py, px, z, near, i):
    """keys[py, px] := min(keys[py, px], (bits of view depth z << 32) | i) for a hit at z >= near."""
    if z >= near:
        key = (ti.cast(ti.bit_cast(z, ti.i32), ti.i64) << 32) | ti.cast(i, ti.i64)
        if key < keys[py, px]:  # keys only fall: a stale read costs an extra atomic
            ti.atomic_min(keys[py, px], key)


@ti.func
def project_ground(p, eye, right, up, fwd, focal, cx, cy):
    q = p - eye
    z = q.dot(fwd)
    return ti.Vector([cx + focal * q.dot(right) / z, cy - focal * q.dot(up) / z])


@with_cfg_passes
@ti.kernel
def splat_shadows(
    cam: ndarray(dtype=ti.f32, ndim=1),
    pa: ndarray(dtype=ti.f32, ndim=2),
    pb: ndarray(dtype=ti.f32, ndim=2),
    radius: ndarray(dtype=ti.f32, ndim=1),
    n: ti.i32,
    shadow: ndarray(dtype=ti.i32, ndim=2),
    tiles: ndarray(dtype=ti.i32, ndim=2),
):
    """Raise shadow[i, j] (H/2, W/2) to round(SHADOW_SCALE * shadow_value) of every primitive
    k < n at the ground point seen through pixel coordinates (2j + 0.5, 2i + 0.5). shadow must be
    cleared first. Every tile with a pixel that samples a texel of a primitive's texel box is
    flagged in tiles (bit 0): texel i is sampled by pixel rows 2i - 1 .. 2i + 2 (shadow_row)."""
    splat_loop(cam, pa, pb, radius, n, shadow, tiles)


@ti.func
def splat_loop(cam: ti.template(), pa: ti.template(), pb: ti.template(), radius: ti.template(), n,
               shadow: ti.template(), tiles: ti.template()):
    """splat_shadows's loop (the top-level, parallel loop of the kernel it is inlined in), over
    primitive_parts(n) items per primitive, each doing every parts-th texel row of its box."""
    height = shadow.shape[0]
    width = shadow.shape[1]
    parts = primitive_parts(n)
    for item in range(n * parts):
        i, part = primitive_part(item, n, parts)
        eye = cam_vec(cam, 0)
        right = cam_vec(cam, 3)
        up = cam_vec(cam, 6)
        fwd = cam_vec(cam, 9)
        focal = cam[12]
        cx = cam[13]
        cy = cam[14]
        near = cam[15]
        a = row3(pa, i)
        b = row3(pb, i)
        r = radius[i]
        ha = ti.max(a[1], 0.0)
        hb = ti.max(b[1], 0.0)
        if eye[1] > 0.0 and ti.min(ha, hb) < SHADOW_MAX_HEIGHT:
            reach = r + shadow_soft(ti.max(ha, hb))
            x_lo = ti.min(a[0], b[0]) - reach
            x_hi = ti.max(a[0], b[0]) + reach
            z_lo = ti.min(a[2], b[2]) - reach
            z_hi = ti.max(a[2], b[2]) + reach
            # Screen box of the footprint rectangle, clipped to the near plane (polygon clipping:
            # the kept corners plus the edges' crossings of the plane).
            s_lo = ti.Vector([BIG, BIG])
            s_hi = ti.Vector([-BIG, -BIG])
            for k in ti.static(range(4)):
                k1 = ti.static((k + 1) % 4)
                p = ti.Vector([x_lo + (x_hi - x_lo) * _CORNER_X[k], 0.0, z_lo + (z_hi - z_lo) * _CORNER_Z[k]])
                q = ti.Vector([x_lo + (x_hi - x_lo) * _CORNER_X[k1], 0.0, z_lo + (z_hi - z_lo) * _CORNER_Z[k1]])
                zp = (p - eye).dot(fwd) - near
                zq = (q - eye).dot(fwd) - near
                if zp >= 0.0:
                    s = project_ground(p, eye, right, up, fwd, focal, cx, cy)
                    s_lo = ti.min(s_lo, s)
                    s_hi = ti.max(s_hi, s)
                if zp * zq < 0.0:
                    c = p + (q - p) * (zp / (zp - zq))
                    s = project_ground(c, eye, right, up, fwd, focal, cx, cy)
                    s_lo = ti.min(s_lo, s)
                    s_hi = ti.max(s_hi, s)
            if s_lo[0] <= s_hi[0]:
                xr = pixel_range((s_lo[0] - 0.5) * 0.5, (s_hi[0] - 0.5) * 0.5, width)
                yr = pixel_range((s_lo[1] - 0.5) * 0.5, (s_hi[1] - 0.5) * 0.5, height)
                if part == 0 and xr[0] <= xr[1] and yr[0] <= yr[1]:
                    mark_tiles(tiles, ti.max(2 * yr[0] - 1, 0), ti.min(2 * yr[1] + 2, 2 * height - 1),
                               ti.max(2 * xr[0] - 1, 0), ti.min(2 * xr[1] + 2, 2 * width - 1))
                d0 = dir_origin(cam)
                py = yr[0] + part
                while py <= yr[1]:
                    x0 = xr[0]
                    x1 = xr[1]
                    if x1 - x0 >= ROW_SPAN_MIN:
                        x0, x1 = shadow_row_span(a, b, r, cam, py, xr[0], xr[1])
                    fy = 2.0 * py + 0.5
                    if x1 - x0 >= PACKET_MIN:  # LANES texels at a time (kernels/raster_lanes.py)
                        px0 = x0
                        while px0 <= x1:
                            fx = ti.Vector([2.0 * (px0 + k) + 0.5 for k in ti.static(range(LANES))])
                            v = shadow_lanes(d0, right, up, eye, fx, fy, a, b, r)
                            for k in ti.static(range(LANES)):
                                if px0 + k <= x1:
                                    raise_shadow(shadow, py, px0 + k, v[k])
                            px0 += LANES
                    else:
                        for px in range(x0, x1 + 1):
                            d = d0 + right * (2.0 * px + 0.5) - up * fy
                            if d[1] < 0.0:
                                g = eye + d * (-eye[1] / d[1])
                                raise_shadow(shadow, py, px, shadow_value(g[0], g[2], a, b, r))
                    py += parts


@with_cfg_passes
@ti.kernel
def draw_frame(
    cam: ndarray(dtype=ti.f32, ndim=1),
    src_a: ndarray(dtype=ti.f32, ndim=2),
    src_b: ndarray(dtype=ti.f32, ndim=2),
    src_r: ndarray(dtype=ti.f32, ndim=1),
    src_c: ndarray(dtype=ti.f32, ndim=2),
    n: ti.i32,
    pa: ndarray(dtype=ti.f32, ndim=2),
    pb: ndarray(dtype=ti.f32, ndim=2),
    radius: ndarray(dtype=ti.f32, ndim=1),
    color: ndarray(dtype=ti.f32, ndim=2),
    keys: ndarray(dtype=ti.i64, ndim=2),
    shadow: ndarray(dtype=ti.i32, ndim=2),
    tiles: ndarray(dtype=ti.i32, ndim=2),
    background: ndarray(dtype=ti.f32, ndim=3),
    frame: ndarray(dtype=ti.u8, ndim=3),
    depth: ndarray(dtype=ti.f32, ndim=2),
    shading: ti.template(),
):
    """A whole frame in one launch: load_primitives, clear_buffers, raster_capsules, splat_shadows,
    then by `shading` (SHADE_FRESH: every tile's tiles flag must be set)
      SHADE_TILES  shade_frame (the camera's background is in `background`),
      SHADE_FRESH  shade_frame_fresh (a new camera: every pixel, background not stored),
      SHADE_FILL   shade_background then shade_frame (the camera is kept, its background not yet stored).
    Each step is one top-level loop, and Taichi runs a kernel's top-level loops one after the other, so
    this is those kernels launched in turn, bit for bit, for the Python cost of one launch (~0.5-1 ms each
    on the CPU backend, mostly argument handling)."""
    load_rows(src_a, src_b, src_r, src_c, n, pa, pb, radius, color)
    clear_tiles(keys, shadow, tiles)
    raster_loop(cam, pa, pb, radius, n, keys, tiles)
    splat_loop(cam, pa, pb, radius, n, shadow, tiles)
    if ti.static(shading == SHADE_FRESH):
        shade_fresh(cam, pa, pb, color, keys, shadow, frame, depth)
    else:
        if ti.static(shading == SHADE_FILL):
            background_all(cam, background)
        shade_tiles(cam, pa, pb, color, keys, shadow, background, tiles, frame, depth)
