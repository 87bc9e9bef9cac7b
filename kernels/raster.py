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
  it once per camera and a ground pixel costs one multiply-add per channel.
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
The NumPy twin is crowd_ik/reference/raster.py; it imports the constants below.
"""

import math

import taichi as ti

ndarray = ti.types.ndarray

# --- look of the frame (shared with the NumPy twin). Colours are BGR, 0..1. ---
_L = (0.45, 0.80, 0.35)  # light direction (x, y, z), towards the light
_LN = math.sqrt(sum(c * c for c in _L))
LIGHT_X, LIGHT_Y, LIGHT_Z = (c / _LN for c in _L)
SKY_HORIZON = (0.93, 0.90, 0.86)
SKY_ZENITH = (0.86, 0.62, 0.42)
GROUND = (0.58, 0.63, 0.66)
GRID_WIDTH = 0.035  # metres, lines every metre
GRID_DARK = 0.16  # a fully covered grid pixel is this much darker
FOG_DISTANCE = 350.0  # metres: fog = 1 - exp(-(distance / FOG_DISTANCE)^2)
AMBIENT = 0.36
AMBIENT_SKY = 0.14  # hemisphere term: ambient + AMBIENT_SKY * n.y
DIFFUSE = 0.72
RIM = 0.28
RIM_POWER = 3.0  # an integer: the kernels raise to it by repeated multiplication
SPECULAR = 0.18
SHININESS = 24.0  # an integer too
AO_MIN = 0.55  # capsule brightness factor at y = 0, rising to 1 at AO_HEIGHT
AO_HEIGHT = 0.6
SHADOW_DARK = 0.6  # darkness of a shadow cast from height 0
SHADOW_FALLOFF = 2.5  # metres: darkness *= exp(-height / SHADOW_FALLOFF)
SHADOW_SOFT0 = 0.05  # half-width of the soft edge at height 0, metres
SHADOW_SOFT_K = 0.35  # ... growing by this much per metre of height
SHADOW_HEIGHT_WEIGHT = 0.3  # height counts this much against ground distance when picking the casting point
SHADOW_MAX_HEIGHT = 12.0  # primitives wholly above this cast no shadow
SHADOW_SCALE = 65535  # shadow buffer units per unit darkness
MIN_PIXEL_RADIUS = 0.72  # pixels; > sqrt(2)/2 so every primitive in view covers a pixel centre
EMPTY_ID = 0x7FFFFFFF  # id field of an empty key
TILE = 16  # pixels: the side of the square tiles whose dirty flags let frames skip untouched ground
BIG = 1.0e30
_CORNER_X = (0.0, 1.0, 1.0, 0.0)  # the footprint rectangle's corners in order around it
_CORNER_Z = (0.0, 0.0, 1.0, 1.0)


@ti.func
def cam_vec(cam: ti.template(), k):
    return ti.Vector([cam[k], cam[k + 1], cam[k + 2]])


@ti.func
def row3(arr: ti.template(), i):
    return ti.Vector([arr[i, 0], arr[i, 1], arr[i, 2]])


@ti.func
def pixel_dir(cam: ti.template(), px, py):
    """World direction (not normalised) of the ray through pixel centre (px, py)."""
    return (
        cam_vec(cam, 9) * cam[12]
        + cam_vec(cam, 3) * (ti.cast(px, ti.f32) - cam[13])
        - cam_vec(cam, 6) * (ti.cast(py, ti.f32) - cam[14])
    )


@ti.func
def dir_origin(cam: ti.template()):
    """Direction of the ray through pixel (0, 0); pixel (px, py)'s is this + right px - up py.
    Kernels load it once per primitive: camera reads in the pixel loops would be repeated after
    every atomic (a memory fence)."""
    return cam_vec(cam, 9) * cam[12] - cam_vec(cam, 3) * cam[13] + cam_vec(cam, 6) * cam[14]


@ti.func
def pixel_ray(cam: ti.template(), px, py):
    """Unit world direction of the ray through pixel centre (px, py)."""
    return pixel_dir(cam, px, py).normalized()


@ti.func
def effective_radius(za, zb, r, focal):
    """Radius inflated to MIN_PIXEL_RADIUS pixels at the farther end's view depth."""
    return ti.max(r, MIN_PIXEL_RADIUS * ti.max(ti.max(za, zb), 0.0) / focal)


@ti.func
def empty_key():
    return (ti.cast(0x7F800000, ti.i64) << 32) | ti.cast(EMPTY_ID, ti.i64)


@ti.func
def sphere_entry(rd, oc, rr):
    """Entry parameter of the ray o + t rd into a sphere, oc = o - centre; BIG when it misses."""
    b = rd.dot(oc)
    h = b * b - (oc.dot(oc) - rr)
    t = BIG
    if h >= 0.0:
        t = -b - ti.sqrt(h)
    return t


@ti.func
def capsule_hit(rd, pa, pb, r):
    """Distance along the unit ray from the eye (the origin) to where it enters the capsule pa-pb
    of radius r (eye-relative coordinates); -1 when it misses or enters behind the eye.

    The capsule is the union of a finite cylinder's side and two end spheres, so its entry point is
    the nearest entry among the three. The ray origin is first moved to the ray's closest approach
    to the capsule's centre (t0): the quadratics then work with lengths of the capsule's size, not
    of the eye distance, and keep their precision in float32 a hundred metres away.
    """
    ba = pb - pa
    t0 = 0.5 * (pa + pb).dot(rd)
    oa = rd * t0 - pa
    ob = rd * t0 - pb
    rr = r * r
    baba = ba.dot(ba)
    bard = ba.dot(rd)
    baoa = ba.dot(oa)
    best = BIG
    k2 = baba - bard * bard
    if k2 > 1e-6 * baba:
        k1 = baba * rd.dot(oa) - baoa * bard
        k0 = baba * oa.dot(oa) - baoa * baoa - rr * baba
        h = k1 * k1 - k2 * k0
        if h >= 0.0:
            t = (-k1 - ti.sqrt(h)) / k2
            y = baoa + t * bard
            if y > 0.0 and y < baba and t0 + t > 0.0:
                best = t
    ta = sphere_entry(rd, oa, rr)
    if ta < best and t0 + ta > 0.0:
        best = ta
    tb = sphere_entry(rd, ob, rr)
    if tb < best and t0 + tb > 0.0:
        best = tb
    result = -1.0
    if best < BIG:
        result = t0 + best
    return result


@ti.func
def capsule_normal(p, pa, pb):
    """Unit outward normal at surface point p of the capsule pa-pb (any common origin)."""
    ba = pb - pa
    baba = ba.dot(ba)
    h = 0.0
    if baba > 1e-20:
        h = ti.math.clamp((p - pa).dot(ba) / baba, 0.0, 1.0)
    return (p - pa - ba * h).normalized()


@ti.func
def sphere_bounds(x, z, r):
    """Range (lo, hi) of X/Z over the ball of radius r around (x, z), Z > 0 throughout (z > r)."""
    hi = (x + r) / (z + r)
    if x + r >= 0.0:
        hi = (x + r) / (z - r)
    lo = (x - r) / (z + r)
    if x - r <= 0.0:
        lo = (x - r) / (z - r)
    return ti.Vector([lo, hi])


@ti.func
def pixel_range(lo, hi, size):
    """Integer pixel centres [i0, i1] inside the screen interval [lo, hi], clipped to [0, size-1]."""
    a = ti.math.clamp(lo - 0.01, -1.0, ti.cast(size, ti.f32))
    b = ti.math.clamp(hi + 0.01, -1.0, ti.cast(size, ti.f32))
    i0 = ti.max(ti.cast(ti.ceil(a), ti.i32), 0)
    i1 = ti.min(ti.cast(ti.floor(b), ti.i32), size - 1)
    return ti.Vector([i0, i1])


@ti.func
def shadow_soft(h):
    return SHADOW_SOFT0 + SHADOW_SOFT_K * h


@ti.func
def shadow_value(gx, gz, a, b, r):
    """Darkness (0..SHADOW_DARK) that the capsule a-b of radius r casts on ground point (gx, 0, gz).

    The casting point is the capsule axis point nearest the ground point, with height weighted by
    SHADOW_HEIGHT_WEIGHT (so a standing leg casts from its foot, a level arm from its whole length);
    its height sets the edge softness and the darkness.
    """
    ha = ti.max(a[1], 0.0)
    hb = ti.max(b[1], 0.0)
    w = SHADOW_HEIGHT_WEIGHT
    ex = b[0] - a[0]
    ey = w * (hb - ha)
    ez = b[2] - a[2]
    ee = ex * ex + ey * ey + ez * ez
    u = 0.0
    if ee > 1e-12:
        u = ti.math.clamp(((gx - a[0]) * ex + (-w * ha) * ey + (gz - a[2]) * ez) / ee, 0.0, 1.0)
    dx = gx - (a[0] + u * ex)
    dz = gz - (a[2] + u * ez)
    dd = dx * dx + dz * dz
    h = ha + u * (hb - ha)
    s = shadow_soft(h)
    value = 0.0
    if dd < (r + s) * (r + s):  # most of a footprint's screen box lies outside it
        cover = 1.0 - ti.math.smoothstep(r - s, r + s, ti.sqrt(dd))
        value = SHADOW_DARK * ti.exp(-h / SHADOW_FALLOFF) * cover
    return value


@ti.func
def ground_hit(eye, rd):
    """Distance along the unit ray eye + t rd to the ground y = 0 seen from above; -1 when the
    ray does not reach it."""
    t = -1.0
    if eye[1] > 0.0 and rd[1] < -1e-7:
        t = -eye[1] / rd[1]
    return t


@ti.func
def line_cover(u, fw):
    """Fraction of a pixel footprint fw (metres) around u covered by GRID_WIDTH lines at integers."""
    d = ti.abs(u - ti.floor(u + 0.5))
    lo = ti.max(d - 0.5 * fw, -0.5 * GRID_WIDTH)
    hi = ti.min(d + 0.5 * fw, 0.5 * GRID_WIDTH)
    return ti.max(hi - lo, 0.0) / fw


@ti.func
def fog(col, dist):
    f = 1.0 - ti.exp(-(dist / FOG_DISTANCE) * (dist / FOG_DISTANCE))
    horizon = ti.Vector([SKY_HORIZON[0], SKY_HORIZON[1], SKY_HORIZON[2]])
    return col + (horizon - col) * f


@ti.func
def mark_tiles(tiles: ti.template(), y0, y1, x0, x1):
    """Flag (bit 0) the tiles holding pixel rows y0..y1 and columns x0..x1 (inclusive, on screen).
    Writers only ever set that bit, so the unsynchronised read-modify-write gives the same flags
    whatever the thread order."""
    for ty in range(y0 // TILE, y1 // TILE + 1):
        for tx in range(x0 // TILE, x1 // TILE + 1):
            tiles[ty, tx] = tiles[ty, tx] | 1


@ti.kernel
def clear_buffers(keys: ndarray(dtype=ti.i64, ndim=2), shadow: ndarray(dtype=ti.i32, ndim=2),
                  tiles: ndarray(dtype=ti.i32, ndim=2)):
    """Start a frame: in every tile the last frame flagged (tiles bit 0), keys := empty (no hit,
    infinite depth) and the shadow texels (H/2, W/2) whose pixels (2i, 2j) lie in it := 0; then
    each tile's bit 1 <- bit 0 (drawn last frame: shade_frame repaints it) and bit 0 <- 0.

    tiles ((H + TILE - 1) // TILE, (W + TILE - 1) // TILE) int32; all ones clears everything.
    Image loops here run in parallel over rows with a serial loop along each row: on the CPU
    backend that is several times faster than a ti.ndrange over pixels (whose flat index is
    divided back into (row, column) for every pixel)."""
    height = keys.shape[0]
    width = keys.shape[1]
    for ty in range(tiles.shape[0]):
        for tx in range(tiles.shape[1]):
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
    for i in range(n):
        for c in ti.static(range(3)):
            pa[i, c] = src_a[i, c]
            pb[i, c] = src_b[i, c]
            color[i, c] = src_c[i, c]
        radius[i] = src_r[i]


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
    height = keys.shape[0]
    width = keys.shape[1]
    for i in range(n):
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
            if xr[0] <= xr[1] and yr[0] <= yr[1]:
                mark_tiles(tiles, yr[0], yr[1], xr[0], xr[1])
            d0 = dir_origin(cam)
            for py in range(yr[0], yr[1] + 1):
                for px in range(xr[0], xr[1] + 1):
                    rd = (d0 + right * ti.cast(px, ti.f32) - up * ti.cast(py, ti.f32)).normalized()
                    t = capsule_hit(rd, a, b, r)
                    if t > 0.0:
                        z = ti.cast(t * rd.dot(fwd), ti.f32)
                        if z >= near:
                            key = (ti.cast(ti.bit_cast(z, ti.i32), ti.i64) << 32) | ti.cast(i, ti.i64)
                            if key < keys[py, px]:  # keys only fall: a stale read costs an extra atomic
                                ti.atomic_min(keys[py, px], key)


@ti.func
def project_ground(p, eye, right, up, fwd, focal, cx, cy):
    q = p - eye
    z = q.dot(fwd)
    return ti.Vector([cx + focal * q.dot(right) / z, cy - focal * q.dot(up) / z])


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
    height = shadow.shape[0]
    width = shadow.shape[1]
    for i in range(n):
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
                if xr[0] <= xr[1] and yr[0] <= yr[1]:
                    mark_tiles(tiles, ti.max(2 * yr[0] - 1, 0), ti.min(2 * yr[1] + 2, 2 * height - 1),
                               ti.max(2 * xr[0] - 1, 0), ti.min(2 * xr[1] + 2, 2 * width - 1))
                d0 = dir_origin(cam)
                for py in range(yr[0], yr[1] + 1):
                    for px in range(xr[0], xr[1] + 1):
                        d = d0 + right * (2.0 * px + 0.5) - up * (2.0 * py + 0.5)
                        if d[1] < 0.0:
                            g = eye + d * (-eye[1] / d[1])
                            v = shadow_value(g[0], g[2], a, b, r)
                            level = ti.cast(v * SHADOW_SCALE + 0.5, ti.i32)
                            if level > shadow[py, px]:  # levels only rise
                                ti.atomic_max(shadow[py, px], level)


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
    for py in range(background.shape[0]):
        for px in range(background.shape[1]):
            eye = cam_vec(cam, 0)
            fwd = cam_vec(cam, 9)
            d = pixel_dir(cam, px, py)
            rd = d.normalized()
            tg = ground_hit(eye, rd)
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
                background[py, px, 0] = tg * rd.dot(fwd)
                background[py, px, 1] = (1.0 - GRID_DARK * grid) * (1.0 - f)
                background[py, px, 2] = f
            else:
                background[py, px, 0] = ti.math.inf
                background[py, px, 1] = ti.sqrt(ti.math.clamp(rd[1], 0.0, 1.0))
                background[py, px, 2] = 0.0


@ti.func
def shade_pixel(cam: ti.template(), pa: ti.template(), pb: ti.template(), color: ti.template(), keys: ti.template(),
                shadow: ti.template(), background: ti.template(), frame: ti.template(), depth: ti.template(), i0, i1,
                fv, px, py):
    """Shade pixel (px, py) into frame and depth (see shade_frame)."""
    ground_z = background[py, px, 0]
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
        col = (ti.Vector([GROUND[0], GROUND[1], GROUND[2]]) * (background[py, px, 1] * (1.0 - dark))
               + ti.Vector([SKY_HORIZON[0], SKY_HORIZON[1], SKY_HORIZON[2]]) * background[py, px, 2])
    else:
        horizon = ti.Vector([SKY_HORIZON[0], SKY_HORIZON[1], SKY_HORIZON[2]])
        zenith = ti.Vector([SKY_ZENITH[0], SKY_ZENITH[1], SKY_ZENITH[2]])
        col = horizon + (zenith - horizon) * background[py, px, 1]
    for c in ti.static(range(3)):
        frame[py, px, c] = ti.cast(ti.math.clamp(col[c], 0.0, 1.0) * 255.0 + 0.5, ti.u8)
    depth[py, px] = seen


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
    width = keys.shape[1]
    for py in range(keys.shape[0]):
        i0, i1, fv = shadow_row(shadow, py)
        ty = py // TILE
        for tx in range(tiles.shape[1]):
            if tiles[ty, tx] != 0:
                for px in range(tx * TILE, ti.min(tx * TILE + TILE, width)):
                    shade_pixel(cam, pa, pb, color, keys, shadow, background, frame, depth, i0, i1, fv, px, py)
