"""Narrow phase of the bullets' hits: the earliest time of impact of each bullet's swept sphere on
the limb capsules of its grid cells, then one winner per character by an int64 atomic_min on
key = quantised toi << 32 | bullet id, each bullet sub-stepped as finely as the limbs near it move."""

import taichi as ti

from crowd_ik.kernels.bullet_grid import cell_span

ndarray = ti.types.ndarray
vec3 = ti.math.vec3

NO_HIT = 0x7FFFFFFFFFFFFFFF  # hit_key of a character that no bullet hit (int64 max)
TOI_BITS = 24  # a toi in [0, 1] of the step is quantised to 2^-24 (the key's bits above the 32-bit bullet id)
MAX_SUBSTEPS = 64  # a bullet's sub-steps at most: each costs a walk over its near limbs

_BRACKET_ITERS = 40  # cutting-plane rounds at most (each at least halves the gap between the bounds; most end in 1-3)
_NEWTON_ITERS = 30  # Newton steps toward the entry at most (quadratic convergence; linear, 1/2, only for a graze)
_ENTRY_STEP = 1.0 / (1 << 26)  # Newton stops when its step is below 2^-26 of the step, under the 2^-24 quantisation


@ti.func
def dist2_slope(p0, d, t, a, b):
    """f(t) = dist^2(p0 + t d, segment [a, b]) and f'(t) = 2 (p - q) . d, q the closest point of the segment.

    The squared distance to a convex set is differentiable, with gradient 2 (p - q) (the projection
    theorem), so f is convex and C^1 in t; each tangent line is a lower bound of f."""
    p = p0 + t * d
    e = b - a
    ee = e.dot(e)
    u = 0.0
    if ee > 0.0:
        u = ti.math.clamp((p - a).dot(e) / ee, 0.0, 1.0)
    w = p - (a + u * e)
    return w.dot(w), 2.0 * w.dot(d)


@ti.func
def sweep_sphere_capsule(p0, p1, a, b, r):
    """Smallest t in [0, 1] with dist(p0 + t (p1 - p0), segment [a, b]) <= r, or -1 when none.

    f(t) = dist^2(p(t), [a, b]) is convex and C^1 (dist2_slope), so {t : f(t) <= r^2} is one interval.
    Hit or miss: a cutting-plane search (Kelley 1960) on [lo, hi], whose ends bracket the minimiser
    (f' < 0 at lo, > 0 at hi): the two end tangents meet at tc below f, so their value there bounds
    min f from below (> r^2: a miss, usually after one round); otherwise f(tc) is probed (<= r^2: a
    hit) and tc replaces the end whose slope has its sign. The entry: Newton on f - r^2 from t = 0,
    where f is convex and decreasing, so each tangent crosses r^2 before f does and the iterates
    climb to the entry without passing it. Only the distance to a segment is evaluated (robust for
    parallel and degenerate segments, where the closed-form segment-segment closest points, Ericson,
    Real-Time Collision Detection 5.1.9, lose precision in float32).
    """
    d = p1 - p0
    r2 = r * r
    toi = -1.0
    # bounding spheres of the two segments: most broad-phase candidates end here
    gap = (p0 + 0.5 * d - 0.5 * (a + b)).norm() - 0.5 * d.norm() - 0.5 * (b - a).norm()
    if gap <= r:
        f0, g0 = dist2_slope(p0, d, 0.0, a, b)
        if f0 <= r2:
            toi = 0.0
        elif g0 < 0.0:  # approaching: else f grows from f0 > r^2 on all of [0, 1]
            f1, g1 = dist2_slope(p0, d, 1.0, a, b)
            inside = f1 <= r2
            if not inside and g1 > 0.0:  # the minimiser is inside (0, 1); g1 <= 0: it is f1 > r^2, a miss
                lo, flo, glo = 0.0, f0, g0
                hi, fhi, ghi = 1.0, f1, g1
                for _ in range(_BRACKET_ITERS):
                    tc = ti.math.clamp((fhi - flo + glo * lo - ghi * hi) / (glo - ghi), lo, hi)
                    if flo + glo * (tc - lo) > r2 or tc <= lo or tc >= hi:
                        break  # the lower bound clears r^2 (or the bracket is down to rounding): a miss
                    fc, gc = dist2_slope(p0, d, tc, a, b)
                    if fc <= r2:
                        inside = True
                        break
                    if gc < 0.0:
                        lo, flo, glo = tc, fc, gc
                    else:
                        hi, fhi, ghi = tc, fc, gc
            if inside:
                t, ft, gt = 0.0, f0, g0
                for _ in range(_NEWTON_ITERS):
                    step = (ft - r2) / -gt
                    t = ti.min(t + step, 1.0)
                    ft, gt = dist2_slope(p0, d, t, a, b)
                    if ft <= r2 or step < _ENTRY_STEP or gt >= 0.0:
                        break
                toi = t
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
def limb_substeps(c, a0: ti.template(), b0: ti.template(), a1: ti.template(), b1: ti.template(), radius: ti.template()):
    """Sub-steps after which limb c's ends move at most its radius each: ceil(max(|a1 - a0|, |b1 - b0|) / radius),
    capped at 2^20 before the cast."""
    move = ti.max((a1[c] - a0[c]).norm(), (b1[c] - b0[c]).norm())
    return ti.cast(ti.ceil(ti.min(move / radius[c], 1048576.0)), ti.i32)


@ti.func
def limb_near(c, lo, hi, a0: ti.template(), b0: ti.template(), a1: ti.template(), b1: ti.template(),
              radius: ti.template()):
    """Whether limb c's box (its ends in both poses, grown by its radius: every pose in between lies inside)
    overlaps the box [lo, hi] in x, y and z. The same test whichever way the grid lists the limbs."""
    r = radius[c]
    c_lo = ti.min(ti.min(a0[c], b0[c]), ti.min(a1[c], b1[c])) - r
    c_hi = ti.max(ti.max(a0[c], b0[c]), ti.max(a1[c], b1[c])) + r
    return (c_lo <= hi).all() and (c_hi >= lo).all()


@ti.func
def entry_limbs(e, m, x0, z0, x1, z1, stride, owner_box: ti.template(), ox, oz, cell, nx, nz, entries: ti.template()):
    """The capsule ids [c0, c1) that grid entry e of cell m stands for, for a bullet whose (x, z) box is (x0, z0,
    x1, z1): the entry's capsule (stride 0), or the block of the entry's owner (stride > 0) when the owner's
    box overlaps the bullet's and m is the cell of the overlap's lower corner (so the bullet reads the block
    once, in a cell that both boxes cover: one where the owner was binned and the bullet walks), else none."""
    c0 = entries[e]
    c1 = c0 + 1
    if stride > 0:
        o = c0
        c0 = o * stride
        c1 = c0
        if owner_box[o, 0] <= x1 and owner_box[o, 2] >= x0 and owner_box[o, 1] <= z1 and owner_box[o, 3] >= z0:
            i, _ = cell_span(ti.max(owner_box[o, 0], x0), x1, ox, cell, nx)
            k, _ = cell_span(ti.max(owner_box[o, 1], z0), z1, oz, cell, nz)
            if k * nx + i == m:
                c1 = c0 + stride
    return c0, c1


@ti.func
def collide_bullet(p, prev: ti.template(), pos: ti.template(), alive: ti.template(), bullet_radius,
                   a0: ti.template(), b0: ti.template(), a1: ti.template(), b1: ti.template(), radius: ti.template(),
                   owner: ti.template(), char_alive: ti.template(), ox, oz, cell, nx, nz, cell_start: ti.template(),
                   entries: ti.template(), stride, owner_box: ti.template(), max_substeps, hit_key: ti.template(),
                   bullet_key: ti.template(), bullet_char: ti.template(), bullet_toi: ti.template(),
                   bullet_point: ti.template(), bullet_substeps: ti.template()):
    """collide_bullets for bullet p."""
    k = 0
    if alive[p] != 0:
        q0 = prev[p]
        q1 = pos[p]
        d = q1 - q0
        lo = ti.min(q0, q1) - bullet_radius
        hi = ti.max(q0, q1) + bullet_radius
        x0, z0, x1, z1 = lo[0], lo[2], hi[0], hi[2]
        i0, i1 = cell_span(x0, x1, ox, cell, nx)
        k0, k1 = cell_span(z0, z1, oz, cell, nz)
        k = 1
        best_t = 2.0
        best_c = -1
        # the limbs near the segment (limb_near): their sub-step counts, and while every one so far needs a single
        # step, the whole segment against the end pose (what one step tests)
        ni = i1 - i0 + 1
        for w in range((k1 - k0 + 1) * ni):  # the cells of the box, row by row
            m = (k0 + w // ni) * nx + i0 + w % ni
            for e in range(cell_start[m], cell_start[m + 1]):
                c0, c1 = entry_limbs(e, m, x0, z0, x1, z1, stride, owner_box, ox, oz, cell, nx, nz, entries)
                for c in range(c0, c1):
                    if char_alive[owner[c]] != 0 and limb_near(c, lo, hi, a0, b0, a1, b1, radius):
                        k = ti.max(k, ti.min(limb_substeps(c, a0, b0, a1, b1, radius), max_substeps))
                        if k == 1:
                            t = sweep_sphere_capsule(q0, q1, a1[c], b1[c], bullet_radius + radius[c])
                            if t >= 0.0 and (t < best_t or (t == best_t and c < best_c)):
                                best_t = t
                                best_c = c
        toi = best_t
        if k > 1:  # sub-segment j against the near limbs interpolated to (j + 1) / k; the first with a hit ends it
            best_c = -1
            j = 0
            while j < k and best_c < 0:
                s = (j + 1.0) / k
                p0 = q0 + (j / k) * d
                p1 = q0 + s * d
                best_t = 2.0
                for w in range((k1 - k0 + 1) * ni):
                    m = (k0 + w // ni) * nx + i0 + w % ni
                    for e in range(cell_start[m], cell_start[m + 1]):
                        c0, c1 = entry_limbs(e, m, x0, z0, x1, z1, stride, owner_box, ox, oz, cell, nx, nz,
                                             entries)
                        for c in range(c0, c1):
                            if char_alive[owner[c]] != 0 and limb_near(c, lo, hi, a0, b0, a1, b1, radius):
                                a = (1.0 - s) * a0[c] + s * a1[c]
                                b = (1.0 - s) * b0[c] + s * b1[c]
                                t = sweep_sphere_capsule(p0, p1, a, b, bullet_radius + radius[c])
                                if t >= 0.0 and (t < best_t or (t == best_t and c < best_c)):
                                    best_t = t
                                    best_c = c
                toi = (j + best_t) / k
                j += 1
        if best_c >= 0:
            o = owner[best_c]
            qt = ti.min(ti.cast(toi * (1 << TOI_BITS), ti.i64), (1 << TOI_BITS) - 1)
            key = (qt << 32) | ti.i64(p)
            bullet_key[p] = key
            bullet_char[p] = o
            bullet_toi[p] = toi
            bullet_point[p] = q0 + toi * d
            ti.atomic_min(hit_key[o], key)
    bullet_substeps[p] = k


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
    stride: ti.i32,
    owner_box: ndarray(ndim=2),
    max_substeps: ti.i32,
    hit_key: ndarray(dtype=ti.i64, ndim=1),
    bullet_key: ndarray(dtype=ti.i64, ndim=1),
    bullet_char: ndarray(dtype=ti.i32, ndim=1),
    bullet_toi: ndarray(ndim=1),
    bullet_point: ndarray(dtype=vec3, ndim=1),
    bullet_substeps: ndarray(dtype=ti.i32, ndim=1),
):
    """Earliest hit of each live bullet's segment prev -> pos (P, 3) on the limbs moving from (a0, b0) to (a1, b1).

    Limb c is a capsule of radius[c] about its axis; a hit is a point of the segment within bullet_radius +
    radius[c] of it. Each bullet takes its own number of sub-steps, k = min(max_substeps, the most that a limb
    near its segment needs: limb_substeps), and tests sub-segment j (the bullet moving linearly over the step)
    against the near limbs interpolated to (j + 1) / k of the way (their pose at the end of the sub-step), j = 0,
    1, ... until one hits; with k = 1 the whole segment against the end pose. Limbs of dead characters are
    skipped. The grid (cell_start, entries) was built from both poses, so it holds every pose in between; the
    bullet walks the cells of its segment's box grown by bullet_radius (the capsules were binned with their
    own radius, so overlapping shapes always share a cell). stride > 0: the grid lists owners by their boxes
    owner_box (N, 4), owner o holding capsules o * stride .. o * stride + stride - 1 (entry_limbs).

    Per bullet: the first sub-step with a hit, then the smallest (toi, capsule id) in it; then bullet_char[p] <-
    character, bullet_toi[p] <- time of impact as a fraction of the step, bullet_point[p] <- where,
    bullet_key[p] <- key, and atomic_min(hit_key[character], key), key = quantised toi << 32 | p.
    bullet_substeps[p] <- k (0 for a dead bullet).
    """
    for p in range(pos.shape[0]):
        collide_bullet(p, prev, pos, alive, bullet_radius, a0, b0, a1, b1, radius, owner, char_alive, ox, oz, cell,
                       nx, nz, cell_start, entries, stride, owner_box, max_substeps, hit_key, bullet_key, bullet_char,
                       bullet_toi, bullet_point, bullet_substeps)


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
