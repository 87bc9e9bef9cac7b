"""The renderer's look (light, sky, ground, shading and shadow constants, shared with the NumPy twin) and
its per-pixel geometry: camera rays, exact ray-capsule and ray-sphere hits, shadow footprints, the ground.
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
# Taichi's CPU backend runs a parallel loop in tasks of at least 512 consecutive iterations (its adaptive
# block_dim), so a loop over fewer than 1024 items (the 720 rows of a frame, 926 primitives) leaves a core idle
# for most of it; the image passes loop over SPAN-pixel pieces of rows instead.
SPAN = 64
PRIMITIVE_ITEMS = 3072  # item count a primitive loop reaches by splitting primitives (when n is small)
MAX_PARTS = 64  # (so a duel's ~50 primitives still make ~3,000 items)
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
def shadow_axis(a, b):
    """The casting segment of shadow_value: end heights (ha, hb) clamped to the ground, the axis (ex, ey, ez)
    with its height weighted by SHADOW_HEIGHT_WEIGHT, and its squared length ee."""
    ha = ti.max(a[1], 0.0)
    hb = ti.max(b[1], 0.0)
    ex = b[0] - a[0]
    ey = SHADOW_HEIGHT_WEIGHT * (hb - ha)
    ez = b[2] - a[2]
    return ha, hb, ex, ey, ez, ex * ex + ey * ey + ez * ez


@ti.func
def shadow_value(gx, gz, a, b, r):
    """Darkness (0..SHADOW_DARK) that the capsule a-b of radius r casts on ground point (gx, 0, gz).

    The casting point is the capsule axis point nearest the ground point, with height weighted by
    SHADOW_HEIGHT_WEIGHT (so a standing leg casts from its foot, a level arm from its whole length);
    its height sets the edge softness and the darkness.
    """
    ha, hb, ex, ey, ez, ee = shadow_axis(a, b)
    w = SHADOW_HEIGHT_WEIGHT
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
def primitive_parts(n):
    """Items per primitive of a primitive loop: enough for PRIMITIVE_ITEMS items in all when n is small (a
    loop over fewer than 1024 items runs as at most two of Taichi's tasks, see SPAN), at most MAX_PARTS."""
    return ti.min(ti.max((PRIMITIVE_ITEMS + n - 1) // ti.max(n, 1), 1), MAX_PARTS)


@ti.func
def primitive_part(item, n, parts):
    """(primitive, part) of iteration `item` of a primitive loop over n * parts items (primitive_parts)."""
    i = item
    part = 0
    if parts > 1:  # (two integer divisions per item cost a crowd of 200,000 primitives ~1.5 ms)
        i = item % n
        part = item // n
    return i, part


@ti.func
def mark_tiles(tiles: ti.template(), y0, y1, x0, x1):
    """Flag (bit 0) the tiles holding pixel rows y0..y1 and columns x0..x1 (inclusive, on screen).
    Writers only ever set that bit, so the unsynchronised read-modify-write gives the same flags
    whatever the thread order."""
    for ty in range(y0 // TILE, y1 // TILE + 1):
        for tx in range(x0 // TILE, x1 // TILE + 1):
            tiles[ty, tx] = tiles[ty, tx] | 1
