"""Vector and quaternion helpers (@ti.func) on lane packets: each argument is a tuple of lane vectors.

A 3-vector is (x, y, z), a quaternion (x, y, z, w), every component a ``ti.types.vector(L, ti.f32)``
holding one character per lane; branches of the one-character helpers in kernels/quat.py become
per-lane selects. Each helper performs the same floating-point operations in the same order as its
twin in kernels/quat.py (and Taichi's own ``cross``, ``dot``, ``norm`` and ``normalized``), except that
the normalisations multiply by one reciprocal instead of dividing each component (within an ulp; the
lane kernels are division-bound), so a lane gets what the one-character kernel gets up to rounding. The
functions are generic in L: Taichi instantiates them for the lane vectors they are called with. The helpers
that need trigonometry (axis_angle, twist_angle, best_angle_about) are in kernels/lane_trig.py, on its
polynomials.
"""

import taichi as ti

PI = 3.141592653589793


@ti.func
def cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@ti.func
def dot3(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@ti.func
def norm3(x, y, z):
    return ti.sqrt(x * x + y * y + z * z + 0.0)


@ti.func
def normalized(x, y, z):
    """v / |v| as Taichi's ``normalized`` computes it (times the reciprocal of the norm)."""
    inv = 1.0 / norm3(x, y, z)
    return inv * x, inv * y, inv * z


@ti.func
def safe_normalize(x, y, z, fx, fy, fz):
    """Per lane: v / |v|, or the fallback where |v| <= 1e-9 (quat.safe_normalize), as v times one reciprocal."""
    n = norm3(x, y, z)
    big = n > 1e-9
    inv = 1.0 / ti.select(big, n, 1.0)
    return ti.select(big, x * inv, fx), ti.select(big, y * inv, fy), ti.select(big, z * inv, fz)


@ti.func
def qmul(ax, ay, az, aw, bx, by, bz, bw):
    """Hamilton product a * b (quat.qmul)."""
    cx, cy, cz = cross(ax, ay, az, bx, by, bz)
    return (aw * bx + bw * ax + cx, aw * by + bw * ay + cy, aw * bz + bw * az + cz,
            aw * bw - dot3(ax, ay, az, bx, by, bz))


@ti.func
def qrot(qx, qy, qz, qw, vx, vy, vz):
    """Rotate v by unit quaternion q (quat.qrot: t = 2 q.xyz x v; v + w t + q.xyz x t)."""
    cx, cy, cz = cross(qx, qy, qz, vx, vy, vz)
    tx, ty, tz = 2.0 * cx, 2.0 * cy, 2.0 * cz
    ux, uy, uz = cross(qx, qy, qz, tx, ty, tz)
    return vx + qw * tx + ux, vy + qw * ty + uy, vz + qw * tz + uz


@ti.func
def qnormalize(x, y, z, w):
    """q / |q|, or the identity where |q| <= 1e-12 (quat.qnormalize), as q times one reciprocal."""
    n = ti.sqrt(x * x + y * y + z * z + w * w + 0.0)
    big = n > 1e-12
    inv = 1.0 / ti.select(big, n, 1.0)
    return (ti.select(big, x * inv, 0.0), ti.select(big, y * inv, 0.0), ti.select(big, z * inv, 0.0),
            ti.select(big, w * inv, 1.0))


@ti.func
def swing(ux, uy, uz, vx, vy, vz):
    """The minimal rotation taking unit u to unit v (quat.swing), the antiparallel case selected per lane
    (computed for every lane: a branch on it split the vector code and made FABRIK's recovery slower)."""
    d = dot3(ux, uy, uz, vx, vy, vz)
    ax, ay, az = cross(ux, uy, uz, 1.0, 0.0, 0.0)
    bx, by, bz = cross(ux, uy, uz, 0.0, 1.0, 0.0)
    along_x = ax * ax + ay * ay + az * az < 1e-8
    ax, ay, az = ti.select(along_x, bx, ax), ti.select(along_x, by, ay), ti.select(along_x, bz, az)
    ax, ay, az = normalized(ax, ay, az)
    cx, cy, cz = cross(ux, uy, uz, vx, vy, vz)
    qx, qy, qz, qw = qnormalize(cx, cy, cz, 1.0 + d)
    anti = d < -0.999999
    return ti.select(anti, ax, qx), ti.select(anti, ay, qy), ti.select(anti, az, qz), ti.select(anti, 0.0, qw)




@ti.func
def any_lane(mask):
    """Whether any lane of a comparison's mask is set (.max() of an integer vector fails to compile)."""
    return ti.select(mask, 1.0, 0.0).max() > 0.0


@ti.func
def wrap_angle(t):
    """quat.wrap_angle: to (-pi, pi]."""
    return t - 2.0 * PI * ti.floor((t + PI) / (2.0 * PI))


@ti.func
def half_turn(x, y):
    """(cos h, sin h) times a positive factor, h = atan2(y, x) / 2 in (-pi/2, pi/2] (h = 0 at (0, 0)), without
    trigonometry: the half-angle identities (1 + cos, sin) = 2 cos h (cos h, sin h) and (sin, 1 - cos) =
    2 sin h (cos h, sin h) with cos, sin = (x, y) / r, the first where x >= 0 and the second (signed) where it would
    cancel. For |(x, y)| within 1e-18..1e18 (x * x + y * y in float32's normal range); the lane kernels pass
    rotation entries, at most 1."""
    r = ti.sqrt(x * x + y * y)
    right = x >= 0.0
    hc = ti.select(right, r + x, ti.abs(y))
    hs = ti.select(right, y, ti.select(y < 0.0, x - r, r - x))
    zero = r == 0.0
    return ti.select(zero, 1.0, hc), ti.select(zero, 0.0, hs)


@ti.func
def unit_half_turn(x, y):
    """half_turn normalised: (cos h, sin h)."""
    hc, hs = half_turn(x, y)
    inv = 1.0 / ti.sqrt(hc * hc + hs * hs)
    return hc * inv, hs * inv


@ti.func
def pseudo_angle(x, y):
    """quat.pseudo_angle per lane: atan2's order on (-pi, pi] without trigonometry."""
    p = y / ti.max(ti.abs(x) + ti.abs(y), 1e-30)
    return ti.select(x < 0.0, ti.select(y >= 0.0, 2.0 - p, -2.0 - p), p)
