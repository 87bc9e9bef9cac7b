"""The renderer's shading passes (kernels/raster.py): the background once per camera, then per pixel the
winning primitive's colour (Lambert, hemisphere ambient, rim, specular, ground darkening) or the ground
with its bilinearly sampled soft shadows and fog."""


import taichi as ti

from crowd_ik.kernels.compile_settings import with_cfg_passes
from crowd_ik.kernels.raster_geometry import (
    AMBIENT, AMBIENT_SKY, AO_HEIGHT, AO_MIN, DIFFUSE, EMPTY_ID, FOG_DISTANCE, GRID_DARK, GROUND, LIGHT_X,
    LIGHT_Y, LIGHT_Z, RIM, RIM_POWER, SHADOW_SCALE, SHININESS, SKY_HORIZON, SKY_ZENITH, SPAN, SPECULAR, TILE, cam_vec,
    capsule_normal, fog, ground_hit, line_cover, pixel_dir, pixel_ray, row3,
)
from crowd_ik.kernels.raster_lanes import L as LANES
from crowd_ik.kernels.raster_lanes import ground_lanes
from crowd_ik.kernels.work_split import banded_count, banded_item

ndarray = ti.types.ndarray


@ti.func
def shadow_row(shadow: ti.template(), py):
    """The half-resolution shadow rows (i0, i1) that pixel row py samples between, and the weight
    fv of row i1 (see shadow_at)."""
    h = shadow.shape[0]
    v = ti.max((ti.cast(py, ti.f32) - 0.5) * 0.5, 0.0)
    i0 = ti.min(ti.cast(v, ti.i32), h - 1)
    i1 = ti.min(i0 + 1, h - 1)
    fv = ti.min(v - ti.cast(i0, ti.f32), 1.0)
    return i0, i1, fv


@ti.func
def shadow_at(shadow: ti.template(), i0, i1, fv, px):
    """Bilinear sample (0..1) of the half-resolution shadow buffer at pixel (px, py), with
    (i0, i1, fv) = shadow_row(shadow, py) computed once per row. Texel (i, j) is seen through pixel
    coordinates (2j + 0.5, 2i + 0.5)."""
    w = shadow.shape[1]
    u = ti.max((ti.cast(px, ti.f32) - 0.5) * 0.5, 0.0)
    j0 = ti.min(ti.cast(u, ti.i32), w - 1)
    j1 = ti.min(j0 + 1, w - 1)
    s00 = shadow[i0, j0]
    s01 = shadow[i0, j1]
    s10 = shadow[i1, j0]
    s11 = shadow[i1, j1]
    dark = 0.0
    if (s00 | s01 | s10 | s11) != 0:  # most of the ground is unshadowed
        fu = ti.min(u - ti.cast(j0, ti.f32), 1.0)
        top = ti.cast(s00, ti.f32) * (1.0 - fu) + ti.cast(s01, ti.f32) * fu
        bottom = ti.cast(s10, ti.f32) * (1.0 - fu) + ti.cast(s11, ti.f32) * fu
        dark = (top * (1.0 - fv) + bottom * fv) / SHADOW_SCALE
    return dark


@ti.func
def ipow(x, n: ti.template()):
    """x ** n for a non-negative integer n fixed at compile time, by repeated squaring (no exp/log)."""
    result = x * 0.0 + 1.0
    square = x
    for bit in ti.static(range(max(n.bit_length(), 1))):
        if ti.static((n >> bit) & 1):
            result = result * square
        if ti.static(bit + 1 < n.bit_length()):
            square = square * square
    return result


@ti.func
def shade_capsule(base, n, rd, y):
    """Colour of a capsule surface point: base colour, unit normal n, view ray rd, height y."""
    light = ti.Vector([LIGHT_X, LIGHT_Y, LIGHT_Z])
    diffuse = ti.max(n.dot(light), 0.0)
    ambient = AMBIENT + AMBIENT_SKY * n[1]
    facing = ti.max(-n.dot(rd), 0.0)
    rim = RIM * ipow(1.0 - facing, ti.static(int(RIM_POWER)))
    half = (light - rd).normalized()
    spec = SPECULAR * ipow(ti.max(n.dot(half), 0.0), ti.static(int(SHININESS)))
    ao = AO_MIN + (1.0 - AO_MIN) * ti.math.clamp(y / AO_HEIGHT, 0.0, 1.0)
    return base * ((ambient + DIFFUSE * diffuse) * ao) + (rim + spec)


@ti.func
def ground_ray(cam: ti.template(), px, py):
    """The first half of background_pixel: pixel (px, py)'s ray direction d, its unit rd, the distance tg
    to the ground along rd (<= 0: the ray sees the sky) and the ground's view depth b0 (inf for the sky)."""
    eye = cam_vec(cam, 0)
    fwd = cam_vec(cam, 9)
    d = pixel_dir(cam, px, py)
    rd = d.normalized()
    tg = ground_hit(eye, rd)
    b0 = ti.math.inf
    if tg > 0.0:
        b0 = tg * rd.dot(fwd)
    return d, rd, tg, b0


@ti.func
def ground_look(cam: ti.template(), d, rd, tg):
    """The second half of background_pixel, from ground_ray's d, rd, tg: (brightness factor or sky gradient,
    fog factor or 0)."""
    eye = cam_vec(cam, 0)
    b1 = 0.0
    b2 = 0.0
    if tg > 0.0:
        g = eye + rd * tg
        # Pixel footprint on the ground from the neighbouring pixels' rays (for grid anti-aliasing).
        fwx = 1.0e3
        fwz = 1.0e3
        rx = d + cam_vec(cam, 3)  # rays through pixels (px + 1, py) and (px, py + 1)
        ry = d - cam_vec(cam, 6)
        if rx[1] < 0.0 and ry[1] < 0.0:
            gx = eye - rx * (eye[1] / rx[1])
            gy = eye - ry * (eye[1] / ry[1])
            fwx = ti.max(ti.max(ti.abs(gx[0] - g[0]), ti.abs(gy[0] - g[0])), 1e-4)
            fwz = ti.max(ti.max(ti.abs(gx[2] - g[2]), ti.abs(gy[2] - g[2])), 1e-4)
        grid = ti.max(line_cover(g[0], fwx), line_cover(g[2], fwz))
        f = 1.0 - ti.exp(-(tg / FOG_DISTANCE) * (tg / FOG_DISTANCE))
        b1 = (1.0 - GRID_DARK * grid) * (1.0 - f)
        b2 = f
    else:
        b1 = ti.sqrt(ti.math.clamp(rd[1], 0.0, 1.0))
    return b1, b2


@ti.func
def background_pixel(cam: ti.template(), px, py):
    """shade_background's three values for pixel (px, py): (ground view depth or inf, brightness
    factor or sky gradient, fog factor or 0)."""
    d, rd, tg, b0 = ground_ray(cam, px, py)
    b1, b2 = ground_look(cam, d, rd, tg)
    return b0, b1, b2


@ti.func
def background_span(cam: ti.template(), background: ti.template(), py, x0, x1):
    """background[py, x0:x1, :] for the camera."""
    for px in range(x0, x1):
        b0, b1, b2 = background_pixel(cam, px, py)
        background[py, px, 0] = b0
        background[py, px, 1] = b1
        background[py, px, 2] = b2


@with_cfg_passes
@ti.kernel
def shade_background(cam: ndarray(dtype=ti.f32, ndim=1), background: ndarray(dtype=ti.f32, ndim=3)):
    """What every pixel shows when no primitive covers it, for this camera: background (H, W, 3)
    float32 holds [0] the ground's view depth (inf where the ray sees the sky), [1] for the ground
    its brightness factor (1 - GRID_DARK grid) (1 - fog) and for the sky the gradient's
    sqrt(clamp(ray y, 0, 1)), [2] for the ground the fog factor (0 for the sky).

    None of this depends on the primitives or the shadows, so the renderer computes it once per
    camera; shade_frame then finishes a ground pixel as GROUND (1 - shadow) [1] + SKY_HORIZON [2],
    which is fog(GROUND (1 - GRID_DARK grid) (1 - shadow), distance) rearranged.
    """
    background_all(cam, background)


@ti.func
def shade_pixel(cam: ti.template(), pa: ti.template(), pb: ti.template(), color: ti.template(), keys: ti.template(),
                shadow: ti.template(), frame: ti.template(), depth: ti.template(), i0, i1, fv, px, py, ground_z, b1,
                b2):
    """Shade pixel (px, py) into frame and depth (see shade_frame), given its background values
    (ground_z, b1, b2) = background[py, px]."""
    col = ti.Vector([0.0, 0.0, 0.0])
    seen = ground_z
    key = keys[py, px]
    pid = ti.cast(key & ti.i64(0xFFFFFFFF), ti.i32)
    z = ti.bit_cast(ti.cast(key >> 32, ti.i32), ti.f32)
    if pid != EMPTY_ID and z < ground_z:
        eye = cam_vec(cam, 0)
        rd = pixel_ray(cam, px, py)
        t = z / rd.dot(cam_vec(cam, 9))
        a = row3(pa, pid) - eye
        b = row3(pb, pid) - eye
        nrm = capsule_normal(rd * t, a, b)
        col = fog(shade_capsule(row3(color, pid), nrm, rd, eye[1] + rd[1] * t), t)
        seen = z
    elif ground_z < ti.math.inf:
        dark = shadow_at(shadow, i0, i1, fv, px)
        col = (ti.Vector([GROUND[0], GROUND[1], GROUND[2]]) * (b1 * (1.0 - dark))
               + ti.Vector([SKY_HORIZON[0], SKY_HORIZON[1], SKY_HORIZON[2]]) * b2)
    else:
        horizon = ti.Vector([SKY_HORIZON[0], SKY_HORIZON[1], SKY_HORIZON[2]])
        zenith = ti.Vector([SKY_ZENITH[0], SKY_ZENITH[1], SKY_ZENITH[2]])
        col = horizon + (zenith - horizon) * b1
    for c in ti.static(range(3)):
        frame[py, px, c] = ti.cast(ti.math.clamp(col[c], 0.0, 1.0) * 255.0 + 0.5, ti.u8)
    depth[py, px] = seen


@with_cfg_passes
@ti.kernel
def shade_frame(
    cam: ndarray(dtype=ti.f32, ndim=1),
    pa: ndarray(dtype=ti.f32, ndim=2),
    pb: ndarray(dtype=ti.f32, ndim=2),
    color: ndarray(dtype=ti.f32, ndim=2),
    keys: ndarray(dtype=ti.i64, ndim=2),
    shadow: ndarray(dtype=ti.i32, ndim=2),
    background: ndarray(dtype=ti.f32, ndim=3),
    tiles: ndarray(dtype=ti.i32, ndim=2),
    frame: ndarray(dtype=ti.u8, ndim=3),
    depth: ndarray(dtype=ti.f32, ndim=2),
):
    """frame (H, W, 3) uint8 BGR from the z-buffer keys, the shadow buffer and the camera's
    background (shade_background); depth (H, W) float32: view depth of what each pixel shows (a
    primitive or the ground), inf for sky. A primitive hidden by the ground is not drawn.

    Only the tiles flagged in tiles (drawn on this frame or the last) are shaded: every other
    pixel has no primitive and no shadow, and still holds the background from an earlier frame.
    """
    shade_tiles(cam, pa, pb, color, keys, shadow, background, tiles, frame, depth)


@ti.func
def shade_tiles(cam: ti.template(), pa: ti.template(), pb: ti.template(), color: ti.template(), keys: ti.template(),
                shadow: ti.template(), background: ti.template(), tiles: ti.template(), frame: ti.template(),
                depth: ti.template()):
    """shade_frame's loop (the top-level, parallel loop of the kernel it is inlined in), over (row, tile
    column) pairs."""
    width = keys.shape[1]
    columns = tiles.shape[1]
    rows = keys.shape[0]
    for item in range(banded_count(rows) * columns):  # rows in bands (kernels/work_split.py)
        py = banded_item(item // columns, rows)
        if py >= rows:
            continue
        tx = item % columns
        if tiles[py // TILE, tx] != 0:
            i0, i1, fv = shadow_row(shadow, py)
            for px in range(tx * TILE, ti.min(tx * TILE + TILE, width)):
                shade_pixel(cam, pa, pb, color, keys, shadow, frame, depth, i0, i1, fv, px, py,
                            background[py, px, 0], background[py, px, 1], background[py, px, 2])


@with_cfg_passes
@ti.kernel
def shade_frame_background(
    cam: ndarray(dtype=ti.f32, ndim=1),
    pa: ndarray(dtype=ti.f32, ndim=2),
    pb: ndarray(dtype=ti.f32, ndim=2),
    color: ndarray(dtype=ti.f32, ndim=2),
    keys: ndarray(dtype=ti.i64, ndim=2),
    shadow: ndarray(dtype=ti.i32, ndim=2),
    background: ndarray(dtype=ti.f32, ndim=3),
    frame: ndarray(dtype=ti.u8, ndim=3),
    depth: ndarray(dtype=ti.f32, ndim=2),
):
    """shade_background then shade_frame of every pixel, in one pass (for a new camera, when every
    tile is shaded anyway): each pixel's background is computed, stored for the frames that keep
    this camera, and used at once, so the (H, W, 3) float32 buffer is not read back. The same
    functions run on the same values, so the frame, depth and background are the same bit for bit."""
    shade_all(cam, pa, pb, color, keys, shadow, background, frame, depth)


@ti.func
def shade_all(cam: ti.template(), pa: ti.template(), pb: ti.template(), color: ti.template(), keys: ti.template(),
              shadow: ti.template(), background: ti.template(), frame: ti.template(), depth: ti.template()):
    """shade_frame_background's loop (the top-level, parallel loop of the kernel it is inlined in), over
    SPAN-pixel pieces of rows: each piece's background is computed and stored, then read back (from the
    cache) to shade it."""
    width = keys.shape[1]
    spans = (width + SPAN - 1) // SPAN
    rows = keys.shape[0]
    for item in range(banded_count(rows) * spans):  # rows in bands (kernels/work_split.py)
        py = banded_item(item // spans, rows)
        if py >= rows:
            continue
        x0 = (item % spans) * SPAN
        x1 = ti.min(x0 + SPAN, width)
        background_span(cam, background, py, x0, x1)
        i0, i1, fv = shadow_row(shadow, py)
        for px in range(x0, x1):
            shade_pixel(cam, pa, pb, color, keys, shadow, frame, depth, i0, i1, fv, px, py,
                        background[py, px, 0], background[py, px, 1], background[py, px, 2])


@with_cfg_passes
@ti.kernel
def shade_frame_fresh(
    cam: ndarray(dtype=ti.f32, ndim=1),
    pa: ndarray(dtype=ti.f32, ndim=2),
    pb: ndarray(dtype=ti.f32, ndim=2),
    color: ndarray(dtype=ti.f32, ndim=2),
    keys: ndarray(dtype=ti.i64, ndim=2),
    shadow: ndarray(dtype=ti.i32, ndim=2),
    frame: ndarray(dtype=ti.u8, ndim=3),
    depth: ndarray(dtype=ti.f32, ndim=2),
):
    """shade_frame_background's frame and depth without its background buffer: each pixel's background is
    computed and used at once, and its grid and fog (ground_look) only where no primitive in front of the
    ground covers the pixel. For a camera seen once (every frame of a follow camera) the background is never
    read again; a renderer that keeps the camera computes it then (shade_background). The same functions on
    the same values: the frame and depth are shade_frame_background's bit for bit."""
    shade_fresh(cam, pa, pb, color, keys, shadow, frame, depth)


@ti.func
def shade_fresh(cam: ti.template(), pa: ti.template(), pb: ti.template(), color: ti.template(), keys: ti.template(),
                shadow: ti.template(), frame: ti.template(), depth: ti.template()):
    """shade_frame_fresh's loop (the top-level, parallel loop of the kernel it is inlined in), over SPAN-pixel
    pieces of rows: the background of each LANES-pixel packet in lanes (raster_lanes.ground_lanes), then each
    pixel shaded; a row's last pixels short of a packet as background_pixel does."""
    width = keys.shape[1]
    spans = (width + SPAN - 1) // SPAN
    rows = keys.shape[0]
    for item in range(banded_count(rows) * spans):  # rows in bands (kernels/work_split.py)
        py = banded_item(item // spans, rows)
        if py >= rows:
            continue
        x0 = (item % spans) * SPAN
        x1 = ti.min(x0 + SPAN, width)
        i0, i1, fv = shadow_row(shadow, py)
        for g in range((x1 - x0 + LANES - 1) // LANES):
            p0 = x0 + g * LANES
            if p0 + LANES <= x1:
                b0, b1, b2 = ground_lanes(cam, p0, py)
                for k in range(LANES):
                    shade_pixel(cam, pa, pb, color, keys, shadow, frame, depth, i0, i1, fv, p0 + k, py, b0[k], b1[k],
                                b2[k])
            else:
                for px in range(p0, x1):
                    d, rd, tg, ground_z = ground_ray(cam, px, py)
                    b1, b2 = ground_look(cam, d, rd, tg)
                    shade_pixel(cam, pa, pb, color, keys, shadow, frame, depth, i0, i1, fv, px, py, ground_z, b1, b2)


@ti.func
def background_all(cam: ti.template(), background: ti.template()):
    """shade_background's loop (the top-level, parallel loop of the kernel it is inlined in), over SPAN-pixel
    pieces of rows, in LANES-pixel packets (raster_lanes.ground_lanes; a row's last pixels short of a packet as
    background_span)."""
    width = background.shape[1]
    spans = (width + SPAN - 1) // SPAN
    rows = background.shape[0]
    for item in range(banded_count(rows) * spans):  # rows in bands (kernels/work_split.py)
        py = banded_item(item // spans, rows)
        if py >= rows:
            continue
        x0 = (item % spans) * SPAN
        x1 = ti.min(x0 + SPAN, width)
        for g in range((x1 - x0 + LANES - 1) // LANES):
            p0 = x0 + g * LANES
            if p0 + LANES <= x1:
                b0, b1, b2 = ground_lanes(cam, p0, py)
                for k in range(LANES):
                    background[py, p0 + k, 0] = b0[k]
                    background[py, p0 + k, 1] = b1[k]
                    background[py, p0 + k, 2] = b2[k]
            else:
                background_span(cam, background, py, p0, x1)
