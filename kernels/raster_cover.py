"""Which pixels of a screen row a primitive may cover, so raster_capsules and splat_shadows
(kernels/raster.py) skip the rest of their screen boxes (arena frame: a quarter of the raster's box
pixels, two fifths of the shadow texels).

A row's ray directions are d(px) = D + px R (D, R fixed along the row), and "the ray's line passes within
r of the axis line", "... within the bounding sphere", "the ground point is within a radius of a point" are
quadratics q(px) = qa px^2 + qb px + qc <= 0 (see shadow_row_span for the ground). The spans are
conservative: the quadratics are formed in float64 from the float32 inputs with the shapes enlarged
(margins far above float32 rounding) and widened by a pixel at each end, so every pixel whose exact test
could pass stays in the span, and the per-pixel code (unchanged) decides as before: the same keys and
shadow levels bit for bit, for less work. Boxes at most ROW_SPAN_MIN pixels wide loop over whole rows (a
span costs a few float64 square roots and divisions, more than it saves there).

The camera is read here from its array, not taken from the raster loop's float32 values: under fast math
(reassociation) giving an intermediate value such as the ray origin d0 one more use changes how LLVM groups
the sums it feeds, and with it the last bit of some depths (seen on tilted cameras)."""

import taichi as ti

from crowd_ik.kernels.raster_geometry import SHADOW_HEIGHT_WEIGHT, SHADOW_SOFT0, SHADOW_SOFT_K

F64 = ti.f64
GROW = 1.0e-3  # relative enlargement of a radius
SLACK = 1.0e-5  # absolute enlargement per metre of distance from the eye
ROW_SPAN_MIN = 16  # boxes at most this many pixels wide loop over whole rows


@ti.func
def vec64(v):
    return ti.Vector([ti.cast(v[0], F64), ti.cast(v[1], F64), ti.cast(v[2], F64)])


@ti.func
def cam64(cam: ti.template(), k):
    return ti.Vector([ti.cast(cam[k], F64), ti.cast(cam[k + 1], F64), ti.cast(cam[k + 2], F64)])


@ti.func
def quad_span(qa, qb, qc, lo, hi):
    """Integer pixels px in [lo, hi] that may satisfy qa px^2 + qb px + qc <= 0, widened by one pixel each
    side: all of [lo, hi] when qa <= 0 (the set is then not bounded), none (s0 > s1) when no real px does."""
    s0 = lo
    s1 = hi
    if qa > 0.0:
        disc = qb * qb - 4.0 * qa * qc
        if disc < 0.0:
            s0 = hi + 1
        else:
            root = ti.sqrt(disc)
            p0 = ti.math.clamp((-qb - root) / (2.0 * qa), ti.cast(lo - 2, F64), ti.cast(hi + 2, F64))
            p1 = ti.math.clamp((-qb + root) / (2.0 * qa), ti.cast(lo - 2, F64), ti.cast(hi + 2, F64))
            s0 = ti.max(lo, ti.cast(ti.floor(p0), ti.i32) - 1)
            s1 = ti.min(hi, ti.cast(ti.ceil(p1), ti.i32) + 1)
    return s0, s1


@ti.func
def capsule_row(a, b, r, cam: ti.template(), py, lo, hi):
    """Span [x0, x1] of pixel columns in [lo, hi] of row py whose rays may enter the capsule a-b of radius r
    (eye-relative), for rays d0 + right px - up py: the rays that pass within r of the capsule's axis line
    and of its bounding sphere's centre within that sphere's radius. x0 > x1: none."""
    a64 = vec64(a)
    e = vec64(b) - a64
    rr = ti.cast(r, F64)
    big = ti.sqrt(a64.dot(a64)) + ti.sqrt(e.dot(e))
    rx = cam64(cam, 3)
    dd = (cam64(cam, 9) * ti.cast(cam[12], F64) - rx * ti.cast(cam[13], F64)
          - cam64(cam, 6) * (ti.cast(py, F64) - ti.cast(cam[14], F64)))
    # Axis line: the distance of the line along d from the line a + s e is |a . (d x e)| / |d x e|.
    m = e.cross(a64)
    f0 = dd.dot(m)
    f1 = rx.dot(m)
    n0 = dd.cross(e)
    n1 = rx.cross(e)
    rc = rr * (1.0 + GROW) + SLACK * big
    x0, x1 = quad_span(f1 * f1 - rc * rc * n1.dot(n1), 2.0 * (f0 * f1 - rc * rc * n0.dot(n1)),
                       f0 * f0 - rc * rc * n0.dot(n0), lo, hi)
    # Bounding sphere (centre c, radius rs): |c x d|^2 <= rs^2 |d|^2.
    c = a64 + 0.5 * e
    rs = rr + 0.5 * ti.sqrt(e.dot(e))
    rs = rs * (1.0 + GROW) + SLACK * big
    k = c.dot(c) - rs * rs
    cd = c.dot(dd)
    cr = c.dot(rx)
    y0, y1 = quad_span(k * rx.dot(rx) - cr * cr, 2.0 * (k * dd.dot(rx) - cd * cr), k * dd.dot(dd) - cd * cd, lo, hi)
    return ti.max(x0, y0), ti.min(x1, y1)



@ti.func
def half_line(l0, l1, lo, hi):
    """Integer px in [lo, hi] that may satisfy l0 + l1 px >= 0 (float64), widened by one pixel."""
    s0 = lo
    s1 = hi
    if l1 != 0.0:
        p = ti.math.clamp(-l0 / l1, ti.cast(lo - 2, F64), ti.cast(hi + 2, F64))
        if l1 > 0.0:
            s0 = ti.max(lo, ti.cast(ti.floor(p), ti.i32) - 1)
        else:
            s1 = ti.min(hi, ti.cast(ti.ceil(p), ti.i32) + 1)
    elif l0 < 0.0:  # 0 px + l0 >= 0 nowhere
        s0 = hi + 1
    return s0, s1


@ti.func
def join(x0, x1, y0, y1):
    """The hull of two spans, either possibly empty."""
    if y0 <= y1:
        if x0 <= x1:
            x0 = ti.min(x0, y0)
            x1 = ti.max(x1, y1)
        else:
            x0 = y0
            x1 = y1
    return x0, x1


@ti.func
def shadow_row_span(a, b, r, cam: ti.template(), py, lo, hi):
    """Span [x0, x1] of shadow texel columns in [lo, hi] of texel row py (rays through pixel coordinates
    (2 px + 0.5, 2 py + 0.5)) whose ground points may get a shadow from the capsule a-b of radius r (world
    frame), following shadow_value: the casting point P(u) = a + u e (x, z) with u = clamp(u_lin, 0, 1),
    u_lin affine in the ground point g, and a shadow only where |g - P(u)| < r + shadow_soft(h(u)). So the
    texels lie in the union of: the disc around a of radius R(0) where u_lin <= 0, the disc around b of
    radius R(1) where u_lin >= 1, and where 0 < u_lin < 1, |g - P(u_lin)| < R(u_lin). With s = -d.y > 0,
    g = eye + d eye.y / s, so s (g - a), s u_lin and s R(u_lin) are linear in px along the row: the discs
    and the middle are quadratics in px, the u_lin bounds half-lines. x0 > x1: none."""
    eye = cam64(cam, 0)
    right = cam64(cam, 3)
    up = cam64(cam, 6)
    d0 = cam64(cam, 9) * ti.cast(cam[12], F64) - right * ti.cast(cam[13], F64) + up * ti.cast(cam[14], F64)
    dd = d0 + right * 0.5 - up * (2.0 * ti.cast(py, F64) + 0.5)
    dx = right * 2.0
    a64 = vec64(a)
    b64 = vec64(b)
    ha = ti.max(a64[1], 0.0)
    hb = ti.max(b64[1], 0.0)
    w = SHADOW_HEIGHT_WEIGHT
    ex = b64[0] - a64[0]
    ey = w * (hb - ha)
    ez = b64[2] - a64[2]
    ee = ex * ex + ey * ey + ez * ez
    far = ti.sqrt((eye - a64).dot(eye - a64)) + ti.sqrt(ex * ex + ez * ez)
    slack = SLACK * far + 1.0e-3
    rr = ti.cast(r, F64)
    s0 = -dd[1]
    s1 = -dx[1]
    # G(px) = s (g - a) (x and z) = g0 + px g1
    g0x = s0 * (eye[0] - a64[0]) + eye[1] * dd[0]
    g0z = s0 * (eye[2] - a64[2]) + eye[1] * dd[2]
    g1x = s1 * (eye[0] - a64[0]) + eye[1] * dx[0]
    g1z = s1 * (eye[2] - a64[2]) + eye[1] * dx[2]
    x0 = hi + 1
    x1 = lo - 1
    if ee > 1e-12:
        # U(px) = s u_lin = u0 + px u1
        u0 = (g0x * ex + g0z * ez - s0 * w * ha * ey) / ee
        u1 = (g1x * ex + g1z * ez - s1 * w * ha * ey) / ee
        grow = 1.0e-3
        # the disc around a where u_lin <= grow: U - grow s <= 0
        ra = (rr + SHADOW_SOFT0 + SHADOW_SOFT_K * ha) * (1.0 + GROW) + slack
        p0, p1 = quad_span(g1x * g1x + g1z * g1z - ra * ra * s1 * s1,
                           2.0 * (g0x * g1x + g0z * g1z - ra * ra * s0 * s1), g0x * g0x + g0z * g0z - ra * ra * s0 * s0,
                           lo, hi)
        q0, q1 = half_line(grow * s0 - u0, grow * s1 - u1, lo, hi)
        x0, x1 = join(x0, x1, ti.max(p0, q0), ti.min(p1, q1))
        # the disc around b where u_lin >= 1 - grow
        rb = (rr + SHADOW_SOFT0 + SHADOW_SOFT_K * hb) * (1.0 + GROW) + slack
        h0x = g0x - s0 * ex
        h0z = g0z - s0 * ez
        h1x = g1x - s1 * ex
        h1z = g1z - s1 * ez
        p0, p1 = quad_span(h1x * h1x + h1z * h1z - rb * rb * s1 * s1,
                           2.0 * (h0x * h1x + h0z * h1z - rb * rb * s0 * s1), h0x * h0x + h0z * h0z - rb * rb * s0 * s0,
                           lo, hi)
        q0, q1 = half_line(u0 - (1.0 - grow) * s0, u1 - (1.0 - grow) * s1, lo, hi)
        x0, x1 = join(x0, x1, ti.max(p0, q0), ti.min(p1, q1))
        # the middle, -grow < u_lin < 1 + grow: |G - U e| < s R(u_lin) = c0 + px c1 (enlarged)
        m0x = g0x - u0 * ex
        m0z = g0z - u0 * ez
        m1x = g1x - u1 * ex
        m1z = g1z - u1 * ez
        k = SHADOW_SOFT_K * (hb - ha)
        base = rr + SHADOW_SOFT0 + SHADOW_SOFT_K * ha
        c0 = (s0 * base + u0 * k) * (1.0 + GROW) + s0 * slack + grow * ti.abs(k) * s0
        c1 = (s1 * base + u1 * k) * (1.0 + GROW) + s1 * slack + grow * ti.abs(k) * s1
        p0, p1 = quad_span(m1x * m1x + m1z * m1z - c1 * c1, 2.0 * (m0x * m1x + m0z * m1z - c0 * c1),
                           m0x * m0x + m0z * m0z - c0 * c0, lo, hi)
        q0, q1 = half_line(u0 + grow * s0, u1 + grow * s1, lo, hi)
        t0, t1 = half_line((1.0 + grow) * s0 - u0, (1.0 + grow) * s1 - u1, lo, hi)
        x0, x1 = join(x0, x1, ti.max(ti.max(p0, q0), t0), ti.min(ti.min(p1, q1), t1))
    else:  # shadow_value takes u = 0: the disc around a
        ra = (rr + SHADOW_SOFT0 + SHADOW_SOFT_K * ha) * (1.0 + GROW) + slack
        x0, x1 = quad_span(g1x * g1x + g1z * g1z - ra * ra * s1 * s1,
                           2.0 * (g0x * g1x + g0z * g1z - ra * ra * s0 * s1), g0x * g0x + g0z * g0z - ra * ra * s0 * s0,
                           lo, hi)
    return x0, x1
