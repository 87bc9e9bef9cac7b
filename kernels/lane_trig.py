"""sin, cos, atan2, asin and acos as polynomials on lane packets: element-wise code without libm calls.

Taichi compiles ``ti.sin`` (and the others) on a ``ti.types.vector(L, ti.f32)`` to one libm call per lane,
which does not vectorise; these are the same functions written with +, *, /, sqrt, floor and selects only, so
LLVM packs them like the arithmetic around them, and every lane performs the same operations whatever its
lane-mates hold. On a lane vector each is a call of the one real function compiled once per kernel and width; on a
scalar it is inlined.

The polynomials are Cephes' single-precision minimax fits (Moshier), the range reductions theirs too:
- sin, cos: x = k pi/2 + r with k = round(2x/pi), r = (x - k C1) - k C2 (pi/2 = C1 + C2, the first product
  in float64 and exact), a polynomial for sin or cos of r on [-pi/4, pi/4] chosen and signed by k mod 4.
  Within 1.5 float32 ulp of the true value on [-4, 4] and 2.3 ulp for |x| <= TRIG_RANGE (about 205,000)
  (tests/test_lane_trig.py: float64 NumPy on dense grids and at the float32 nearest each k pi/2, where the
  result is tiny); beyond it the error grows as |x| 2^-53 (k C1 rounds) and the result stays finite and
  within [-1, 1]. (The kernels' angles are within a few pi.)
- atan2(y, x): a = min(|x|, |y|) / max(|x|, |y|) on [0, 1], above tan(pi/8) reduced by atan(a) = pi/4 +
  atan((a - 1) / (a + 1)) (numerator and denominator selected before the one division), an odd polynomial on
  [-tan(pi/8), tan(pi/8)], then the octant. atan2(0, 0) = 0; the sign of a zero is ignored (fast math does
  not keep it): atan2(+-0, x < 0) = pi. Within 2.9 ulp.
- asin, acos: for |x| <= 1/2 asin(x) = x + x^3 P(x^2); above, asin(|x|) = pi/2 - 2 asin(sqrt((1 - |x|) / 2)),
  so one polynomial of a selected argument serves both halves and both functions. Within 2.4 ulp (just above
  1/2, where pi/2 - 2p doubles p's rounding); NaN outside [-1, 1].
"""

import functools

import taichi as ti
from crowd_ik.kernels import lane_math as lm

PI = 3.141592653589793
HALF_PI = 1.5707963267948966
QUARTER_PI = 0.7853981633974483
TWO_OVER_PI = 0.6366197723675814
# pi/2 = C1 + C2: C1 has 36 significant bits, so k C1 is exact in float64 for |k| < 2^17
C1, C2 = 1.5707963267923333, 2.563344151594519e-12
TRIG_RANGE = 2.0**17 * HALF_PI  # |x| up to which the reduction is exact (about 205,000)
TAN_PI_8 = 0.41421356237309503


@ti.func
def _sin_poly(r, z):
    """sin(r) for |r| <= pi/4, z = r^2."""
    return ((-1.9515295891e-4 * z + 8.3321608736e-3) * z - 1.6666654611e-1) * z * r + r


@ti.func
def _cos_poly(z):
    """cos(r) for |r| <= pi/4, z = r^2."""
    return ((2.443315711809948e-5 * z - 1.388731625493765e-3) * z + 4.166664568298827e-2) * z * z - 0.5 * z + 1.0


@ti.func
def _sin_cos(x):
    """(sin x, cos x) from one range reduction."""
    # r = x - k pi/2 as (x - k C1) in float64, exact, then - k C2 in float32. Fast math reassociates a split done
    # in one type, x - k P1 - k P2 -> x - k (P1 + P2), which loses it (sin near pi was 15 % off), but not
    # across the conversion.
    xd = ti.cast(x, ti.f64)
    k = ti.floor(xd * ti.f64(TWO_OVER_PI) + 0.5)  # ti.f64(): a bare literal would be a float32 constant
    r = ti.cast(xd - k * ti.f64(C1), ti.f32) - ti.cast(k, ti.f32) * C2
    q = ti.cast(k - 4.0 * ti.floor(0.25 * k), ti.f32)  # k mod 4 as 0.0, 1.0, 2.0 or 3.0
    r = ti.math.clamp(r, -0.8, 0.8)  # only far past TRIG_RANGE does r leave [-pi/4, pi/4]: keep the result bounded
    z = r * r
    s = _sin_poly(r, z)
    c = _cos_poly(z)
    odd = (q == 1.0) | (q == 3.0)
    sv = ti.select(odd, c, s)
    cv = ti.select(odd, s, c)
    sv = ti.select(q >= 2.0, -sv, sv)
    cv = ti.select((q == 1.0) | (q == 2.0), -cv, cv)
    return sv, cv


@ti.func
def _atan2(y, x):
    """The angle of (x, y) in [-pi, pi]; 0 at (0, 0)."""
    ax, ay = ti.abs(x), ti.abs(y)
    mn, mx = ti.min(ax, ay), ti.max(ax, ay)
    big = mn > TAN_PI_8 * mx  # a = mn / mx > tan(pi/8): atan(a) = pi/4 + atan((mn - mx) / (mn + mx))
    num = ti.select(big, mn - mx, mn)
    den = ti.select(big, mn + mx, mx)
    t = num / ti.select(den > 0.0, den, 1.0)
    z = t * t
    a = (((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1) * z * t + t
    a = ti.select(big, a + QUARTER_PI, a)
    a = ti.select(ay > ax, HALF_PI - a, a)
    a = ti.select(x < 0.0, PI - a, a)
    return ti.select(y < 0.0, -a, a)


@ti.func
def _asin_half(x):
    """(asin |x| folded: p with asin|x| = p for |x| <= 1/2 or pi/2 - 2p above, big = |x| > 1/2)."""
    a = ti.abs(x)
    big = a > 0.5
    z = ti.select(big, 0.5 * (1.0 - a), a * a)
    s = ti.select(big, ti.sqrt(z), a)
    p = ((((4.2163199048e-2 * z + 2.4181311049e-2) * z + 4.5470025998e-2) * z + 7.4953002686e-2) * z
         + 1.6666752422e-1) * z * s + s
    return p, big


@ti.func
def _asin(x):
    p, big = _asin_half(x)
    a = ti.select(big, HALF_PI - 2.0 * p, p)
    return ti.select(x < 0.0, -a, a)


@ti.func
def _acos(x):
    p, big = _asin_half(x)
    neg = x < 0.0
    small = HALF_PI - ti.select(neg, -p, p)
    return ti.select(big, ti.select(neg, PI - 2.0 * p, 2.0 * p), small)


# ---------------------------------------------------------------------------------------------- the functions
# On a lane vector each is a call of one real function compiled once per kernel and width (ti.real_func): inlined
# at every call site, the polynomials tripled the limited lane kernel's cold compile (4 lanes, every trigonometric
# call replaced: 30 -> 88 s of CPU; as real functions 46 s); on a scalar the code is inlined.
# One real function, not one per operation: Taichi 1.7.4's offline-cache key serialises a kernel's real functions
# in the order of a hash map keyed by their addresses, so a kernel calling two or more of them got one of several
# keys at random from run to run, and a warm cache missed (the limited FABRIK kernel: two keys, a 10-25 s compile
# in about every other fresh process, until both were cached; tests/test_lane_trig.py).

SIN_COS, ATAN2, ASIN, ACOS = 0, 1, 2, 3  # the operations of the real function


def lanes_of(x) -> int:
    """The width of a lane vector, 0 for a scalar (at compile time)."""
    return x.get_shape()[0] if hasattr(x, "is_tensor") and x.is_tensor() else 0


@functools.cache
def _real(L: int):
    """The real function for L lanes: trig_l(op, a, b) -> (s, c): (sin a, cos a) for SIN_COS, (atan2(a, b), b) for
    ATAN2, (asin a, b) for ASIN and (acos a, b) for ACOS."""
    V = ti.types.vector(L, ti.f32)
    SC = ti.types.struct(s=V, c=V)

    @ti.real_func
    def trig_l(op: ti.i32, a: V, b: V) -> SC:
        s, c = a, b
        if op == SIN_COS:
            s, c = _sin_cos(a)
        elif op == ATAN2:
            s = _atan2(a, b)
        elif op == ASIN:
            s = _asin(a)
        else:
            s = _acos(a)
        return SC(s=s, c=c)

    return trig_l


@ti.func
def sin_cos(x):
    """(sin x, cos x) from one range reduction."""
    s, c = x, x
    if ti.static(lanes_of(x) > 0):
        r = ti.static(_real(lanes_of(x)))(SIN_COS, x, x)
        s, c = r.s, r.c
    else:
        s, c = _sin_cos(x)
    return s, c


@ti.func
def sin(x):
    s, _c = sin_cos(x)
    return s


@ti.func
def cos(x):
    _s, c = sin_cos(x)
    return c


@ti.func
def atan2(y, x):
    """The angle of (x, y) in [-pi, pi]; 0 at (0, 0). y and x both lane vectors or both scalars."""
    a = x
    if ti.static(lanes_of(x) > 0):
        a = ti.static(_real(lanes_of(x)))(ATAN2, y, x).s
    else:
        a = _atan2(y, x)
    return a


@ti.func
def asin(x):
    a = x
    if ti.static(lanes_of(x) > 0):
        a = ti.static(_real(lanes_of(x)))(ASIN, x, x).s
    else:
        a = _asin(x)
    return a


@ti.func
def acos(x):
    a = x
    if ti.static(lanes_of(x) > 0):
        a = ti.static(_real(lanes_of(x)))(ACOS, x, x).s
    else:
        a = _acos(x)
    return a


# ---------------------------------------------------------------------------------------------- quaternion helpers
# kernels/quat.py's helpers that call trigonometry, per lane with the functions above (the same operations otherwise)


@ti.func
def axis_angle(ax, ay, az, angle):
    """quat.axis_angle per lane: the rotation by angle about a unit axis."""
    s, c = sin_cos(0.5 * angle)
    return ax * s, ay * s, az * s, c


@ti.func
def twist_angle(qx, qy, qz, qw, ax, ay, az):
    """quat.twist_angle per lane: the angle of q's twist about a unit axis, in (-pi, pi]."""
    return lm.wrap_angle(2.0 * atan2(lm.dot3(qx, qy, qz, ax, ay, az), qw))


@ti.func
def best_angle_about(ax, ay, az, ux, uy, uz, vx, vy, vz):
    """quat.best_angle_about per lane: the angle about a unit axis that best turns u toward v."""
    du = lm.dot3(ux, uy, uz, ax, ay, az)
    dv = lm.dot3(vx, vy, vz, ax, ay, az)
    px, py, pz = ux - du * ax, uy - du * ay, uz - du * az
    rx, ry, rz = vx - dv * ax, vy - dv * ay, vz - dv * az
    cx, cy, cz = lm.cross(px, py, pz, rx, ry, rz)
    return atan2(lm.dot3(ax, ay, az, cx, cy, cz), lm.dot3(px, py, pz, rx, ry, rz))
