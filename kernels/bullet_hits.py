"""Narrow phase of the bullets' hits: the earliest time of impact of each bullet's swept sphere on
the limb capsules of its grid cells, then one winner per character by an int64 atomic_min on
key = (sub-step, quantised toi) << 32 | bullet id; and how many sub-steps a step's limb motion needs."""

import taichi as ti

from crowd_ik.kernels.bullet_grid import cell_span, swept_box

ndarray = ti.types.ndarray
vec3 = ti.math.vec3

NO_HIT = 0x7FFFFFFFFFFFFFFF  # hit_key of a character that no bullet hit (int64 max)
TOI_BITS = 24  # a toi in [0, 1] of a sub-step is quantised to 2^-24
MAX_SUBSTEPS = 64  # (sub-step, toi) then fits in 30 bits above the 32-bit bullet id

_GOLDEN = 0.6180339887498949
_GOLDEN_ITERS = 36  # interval 0.618^36 = 3e-8 of the step
_BISECT_ITERS = 26  # toi resolution 2^-26 of the step, finer than the 2^-24 quantisation


@ti.func
def point_segment_dist2(p, a, b):
    """Squared distance from point p to segment [a, b] (a point when a == b)."""
    e = b - a
    ee = e.dot(e)
    u = 0.0
    if ee > 0.0:
        u = ti.math.clamp((p - a).dot(e) / ee, 0.0, 1.0)
    q = p - (a + u * e)
    return q.dot(q)


@ti.func
def sweep_sphere_capsule(p0, p1, a, b, r):
    """Smallest t in [0, 1] with dist(p0 + t (p1 - p0), segment [a, b]) <= r, or -1 when none.

    f(t) = dist^2(p(t), [a, b]) is convex in t (the distance to a convex set composed with an affine
    map, squared), so {t : f(t) <= r^2} is one interval. Golden-section search (Kiefer 1953) walks
    toward the minimiser of f and stops at the first probe inside the capsule; bisection on
    [0, probe] then finds the entry time, where f crosses r^2 exactly once. Robust for parallel and
    degenerate segments, where the closed-form segment-segment closest points (Ericson, Real-Time
    Collision Detection, 5.1.9) lose precision in float32.
    """
    d = p1 - p0
    r2 = r * r
    toi = -1.0
    # bounding spheres of the two segments: most broad-phase candidates end here
    gap = (p0 + 0.5 * d - 0.5 * (a + b)).norm() - 0.5 * d.norm() - 0.5 * (b - a).norm()
    if gap <= r:
        if point_segment_dist2(p0, a, b) <= r2:
            toi = 0.0
        else:
            probe = -1.0
            lo = 0.0
            hi = 1.0
            x1 = hi - _GOLDEN * (hi - lo)
            x2 = lo + _GOLDEN * (hi - lo)
            f1 = point_segment_dist2(p0 + x1 * d, a, b)
            f2 = point_segment_dist2(p0 + x2 * d, a, b)
            if point_segment_dist2(p1, a, b) <= r2:
                probe = 1.0
            for _ in range(_GOLDEN_ITERS):
                if probe >= 0.0:
                    break
                if f1 <= r2:
                    probe = x1
                elif f2 <= r2:
                    probe = x2
                elif f1 < f2:
                    hi = x2
                    x2 = x1
                    f2 = f1
                    x1 = hi - _GOLDEN * (hi - lo)
                    f1 = point_segment_dist2(p0 + x1 * d, a, b)
                else:
                    lo = x1
                    x1 = x2
                    f1 = f2
                    x2 = lo + _GOLDEN * (hi - lo)
                    f2 = point_segment_dist2(p0 + x2 * d, a, b)
            if probe >= 0.0:
                lo = 0.0
                hi = probe
                for _ in range(_BISECT_ITERS):
                    mid = 0.5 * (lo + hi)
                    if point_segment_dist2(p0 + mid * d, a, b) <= r2:
                        hi = mid
                    else:
                        lo = mid
                toi = hi
    return toi


@ti.kernel
def reset_hits(
    hit_key: ndarray(dtype=ti.i64, ndim=1),
    hit_bullet: ndarray(dtype=ti.i32, ndim=1),
    bullet_char: ndarray(dtype=ti.i32, ndim=1),
):
    """hit_key (N,) <- NO_HIT, hit_bullet (N,) <- -1, bullet_char (P,) <- -1."""
    for n in range(hit_key.shape[0]):
        hit_key[n] = ti.i64(NO_HIT)
        hit_bullet[n] = -1
    for p in range(bullet_char.shape[0]):
        bullet_char[p] = -1


@ti.func
def collide_bullet(p, prev: ti.template(), pos: ti.template(), alive: ti.template(), bullet_radius,
                   a0: ti.template(), b0: ti.template(), a1: ti.template(), b1: ti.template(), s, radius: ti.template(),
                   owner: ti.template(), char_alive: ti.template(), ox, oz, cell, nx, nz, cell_start: ti.template(),
                   entries: ti.template(), substep, n_substeps, hit_key: ti.template(), bullet_key: ti.template(),
                   bullet_char: ti.template(), bullet_toi: ti.template(), bullet_point: ti.template()):
    """collide_bullets for bullet p."""
    earlier = ti.i64(substep) << (TOI_BITS + 32)  # keys of hits on earlier sub-steps are below this
    if alive[p] != 0:
        q0 = prev[p]
        q1 = pos[p]
        x0, z0, x1, z1 = swept_box(q0, q1, q0, q1, bullet_radius)
        i0, i1 = cell_span(x0, x1, ox, cell, nx)
        k0, k1 = cell_span(z0, z1, oz, cell, nz)
        best_t = 2.0
        best_c = -1
        for k in range(k0, k1 + 1):
            for i in range(i0, i1 + 1):
                m = k * nx + i
                for e in range(cell_start[m], cell_start[m + 1]):
                    c = entries[e]
                    o = owner[c]
                    if char_alive[o] != 0 and hit_key[o] >= earlier:
                        a = (1.0 - s) * a0[c] + s * a1[c]
                        b = (1.0 - s) * b0[c] + s * b1[c]
                        t = sweep_sphere_capsule(q0, q1, a, b, bullet_radius + radius[c])
                        if t >= 0.0 and (t < best_t or (t == best_t and c < best_c)):
                            best_t = t
                            best_c = c
        if best_c >= 0:
            o = owner[best_c]
            qt = ti.min(ti.cast(best_t * (1 << TOI_BITS), ti.i64), (1 << TOI_BITS) - 1)
            key = (((ti.i64(substep) << TOI_BITS) + qt) << 32) | ti.i64(p)
            bullet_key[p] = key
            bullet_char[p] = o
            bullet_toi[p] = (substep + best_t) / n_substeps
            bullet_point[p] = q0 + best_t * (q1 - q0)
            ti.atomic_min(hit_key[o], key)


@ti.kernel
def collide_bullets(
    prev: ndarray(dtype=vec3, ndim=1),
    pos: ndarray(dtype=vec3, ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    bullet_radius: float,
    a0: ndarray(dtype=vec3, ndim=1),
    b0: ndarray(dtype=vec3, ndim=1),
    a1: ndarray(dtype=vec3, ndim=1),
    b1: ndarray(dtype=vec3, ndim=1),
    s: float,
    radius: ndarray(ndim=1),
    owner: ndarray(dtype=ti.i32, ndim=1),
    char_alive: ndarray(dtype=ti.i32, ndim=1),
    ox: float,
    oz: float,
    cell: float,
    nx: ti.i32,
    nz: ti.i32,
    cell_start: ndarray(dtype=ti.i32, ndim=1),
    entries: ndarray(dtype=ti.i32, ndim=1),
    substep: ti.i32,
    n_substeps: ti.i32,
    hit_key: ndarray(dtype=ti.i64, ndim=1),
    bullet_key: ndarray(dtype=ti.i64, ndim=1),
    bullet_char: ndarray(dtype=ti.i32, ndim=1),
    bullet_toi: ndarray(ndim=1),
    bullet_point: ndarray(dtype=vec3, ndim=1),
):
    """Earliest hit of each live bullet's segment prev -> pos (P, 3) on sub-step `substep` of n_substeps.

    Limb c is the capsule (1 - s) (a0, b0)[c] + s (a1, b1)[c] with radius[c] (s = (substep+1) /
    n_substeps: the limb's pose at the end of the sub-step; a0 = a1 when not sub-stepping). A hit
    is a point of the segment within bullet_radius + radius[c] of the limb's axis. Capsules whose
    character is dead, or was already hit on an earlier sub-step of this step, are skipped.
    The grid (cell_start, entries) was built from both poses, so it holds every s in between; the
    bullet walks the cells of its segment's box grown by bullet_radius (the capsules were binned
    with their own radius, so overlapping shapes always share a cell).

    Per bullet: the smallest (toi, capsule id); then bullet_char[p] <- character, bullet_toi[p] <-
    time of impact as a fraction of the whole step, bullet_point[p] <- where, bullet_key[p] <- key,
    and atomic_min(hit_key[character], key), key = ((substep << 24) + quantised toi) << 32 | p.
    """
    for p in range(pos.shape[0]):
        collide_bullet(p, prev, pos, alive, bullet_radius, a0, b0, a1, b1, s, radius, owner, char_alive, ox, oz, cell,
                       nx, nz, cell_start, entries, substep, n_substeps, hit_key, bullet_key, bullet_char, bullet_toi,
                       bullet_point)


@ti.func
def apply_hit(p, alive: ti.template(), bullet_char: ti.template(), bullet_key: ti.template(), hit_key: ti.template(),
              hit_bullet: ti.template()):
    """apply_hits for bullet p."""
    if alive[p] != 0 and bullet_char[p] >= 0:
        alive[p] = 0
        o = bullet_char[p]
        if hit_key[o] == bullet_key[p]:
            hit_bullet[o] = p


@ti.kernel
def apply_hits(
    alive: ndarray(dtype=ti.i32, ndim=1),
    bullet_char: ndarray(dtype=ti.i32, ndim=1),
    bullet_key: ndarray(dtype=ti.i64, ndim=1),
    hit_key: ndarray(dtype=ti.i64, ndim=1),
    hit_bullet: ndarray(dtype=ti.i32, ndim=1),
):
    """Every live bullet that struck a limb on this sub-step dies (the body stops it); the one whose
    key won its character's atomic_min is that character's hit: hit_bullet[character] <- bullet."""
    for p in range(alive.shape[0]):
        apply_hit(p, alive, bullet_char, bullet_key, hit_key, hit_bullet)


@ti.func
def limb_substeps(c, a0: ti.template(), b0: ti.template(), a1: ti.template(), b1: ti.template(),
                  radius: ti.template(), owner: ti.template(), char_alive: ti.template(), out: ti.template()):
    """count_substeps for limb c."""
    if char_alive[owner[c]] != 0:
        move = ti.max((a1[c] - a0[c]).norm(), (b1[c] - b0[c]).norm())
        k = ti.cast(ti.ceil(ti.min(move / radius[c], 1048576.0)), ti.i32)
        if k > out[0]:
            ti.atomic_max(out[0], k)


@ti.kernel
def count_substeps(
    a0: ndarray(dtype=vec3, ndim=1),
    b0: ndarray(dtype=vec3, ndim=1),
    a1: ndarray(dtype=vec3, ndim=1),
    b1: ndarray(dtype=vec3, ndim=1),
    radius: ndarray(ndim=1),
    owner: ndarray(dtype=ti.i32, ndim=1),
    char_alive: ndarray(dtype=ti.i32, ndim=1),
    out: ndarray(dtype=ti.i32, ndim=1),
):
    """out[0] <- max(out[0], max over live limbs of ceil(max(|a1 - a0|, |b1 - b0|) / radius)).

    The number of sub-steps after which no limb end moves more than its own radius per sub-step
    (integer atomic_max, so no float atomics). Capped at 2^20 before the cast. A limb only
    issues the atomic when it beats the value it reads (out[0] only grows, so a stale read just
    costs an extra atomic): hundreds of thousands of limbs then do not queue on one address.
    """
    for c in range(a0.shape[0]):
        limb_substeps(c, a0, b0, a1, b1, radius, owner, char_alive, out)
