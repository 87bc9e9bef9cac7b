"""Which pixels of a screen row a capsule may cover, so raster_capsules (kernels/raster.py) skips the rest
of its screen box (a quarter of an arena frame's box pixels).

A row's ray directions are d(px) = D + px R (D, R fixed along the row), and "the ray's line passes within
r of the axis line" or "... within the bounding sphere" is a quadratic q(px) = qa px^2 + qb px + qc <= 0.
The spans are conservative: the quadratics are formed in float64 from the float32 inputs with the shape
enlarged (margins far above float32 rounding) and widened by a pixel at each end, so every pixel whose
exact test could pass stays in the span, and the per-pixel code (unchanged) decides as before: the same
keys bit for bit, for less work.

The camera is read here from its array, not taken from the raster loop's float32 values: under fast math
(reassociation) giving an intermediate value such as the ray origin d0 one more use changes how LLVM groups
the sums it feeds, and with it the last bit of some depths (seen on tilted cameras)."""

import taichi as ti

F64 = ti.f64
GROW = 1.0e-3  # relative enlargement of a radius
SLACK = 1.0e-5  # absolute enlargement per metre of distance from the eye


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
    dd = cam64(cam, 9) * ti.cast(cam[12], F64) - rx * ti.cast(cam[13], F64) - cam64(cam, 6) * (ti.cast(py, F64) - ti.cast(cam[14], F64))
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

