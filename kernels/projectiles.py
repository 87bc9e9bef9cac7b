"""Bullet physics, a uniform ground grid, swept bullet-vs-limb hits and threat detection.

Arrays: P bullet slots, C limb capsules, N characters. Positions in metres, world frame (y up);
velocities in m/s; times in seconds.

Phases (one launch each; `crowd_ik.game.pool.BulletPool` runs them in this order):
  integrate_bullets                      semi-implicit Euler with gravity and quadratic drag
  mark_bullet_cells, reachable_owners,   broad phase: a uniform grid on (x, z) built with integer
  build_grid                             atomics only (count, exclusive prefix sum, scatter), in
                                         the cells the bullets can reach, of the owners that
                                         have a segment there
  reset_hits, collide_bullets,           narrow phase: earliest time of impact per bullet, then one
  apply_hits                             winner per character by an int64 atomic_min on
                                         key = (sub-step, quantised toi) << 32 | bullet id
  threat_pass                            per character, the first bullet that will pass near it
The game's step launches the fused kernels at the end of the file instead: threat_pass,
prepare_limbs (marking, reachable characters, sub-step count, limb grid, reset) and one
advance_bullets per sub-step (integrate, collide, apply, export), built from the same loop bodies.

Determinism: nothing here uses float atomics. The order of capsule ids inside a grid cell depends on
thread timing, but every result is a minimum under a total order ((toi, capsule id) per bullet,
(key) per character), so it is the same whatever order the candidates are visited in.
"""

import taichi as ti

ndarray = ti.types.ndarray
vec3 = ti.math.vec3

NO_HIT = 0x7FFFFFFFFFFFFFFF  # hit_key of a character that no bullet hit (int64 max)
TOI_BITS = 24  # a toi in [0, 1] of a sub-step is quantised to 2^-24
MAX_SUBSTEPS = 64  # (sub-step, toi) then fits in 30 bits above the 32-bit bullet id

_GOLDEN = 0.6180339887498949
_GOLDEN_ITERS = 36  # interval 0.618^36 = 3e-8 of the step
_BISECT_ITERS = 26  # toi resolution 2^-26 of the step, finer than the 2^-24 quantisation


# ---------------------------------------------------------------------------------------------
# physics


@ti.func
def integrate_bullet(i, pos: ti.template(), vel: ti.template(), age: ti.template(), alive: ti.template(),
                     prev: ti.template(), dt, gravity, drag, lifetime, far):
    """integrate_bullets for bullet i (the loop bodies here are functions, so that fused kernels
    share them: a loop inside a ti.func runs serially, only a kernel's top-level loops are parallel)."""
    if alive[i] != 0:
        x = pos[i]
        prev[i] = x
        w = vel[i] + vec3(0.0, -gravity, 0.0) * dt
        v = w / (1.0 + drag * w.norm() * dt)
        x = x + v * dt
        pos[i] = x
        vel[i] = v
        a = age[i] + dt
        age[i] = a
        if a > lifetime or x[1] < -1.0 or x.norm() > far:
            alive[i] = 0


@ti.kernel
def integrate_bullets(
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    age: ndarray(ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    prev: ndarray(dtype=vec3, ndim=1),
    dt: float,
    gravity: float,
    drag: float,
    lifetime: float,
    far: float,
):
    """One step of every live bullet (pos, vel, prev: (P, 3); age: (P,) s; alive: (P,) 0/1).

    prev <- pos (the start of this step's swept segment), then semi-implicit Euler:
        w = v + g dt                       g = (0, -gravity, 0) m/s^2
        v' = w / (1 + drag |w| dt)         quadratic drag dv/dt = -drag |v| v, drag in 1/m
        x' = x + v' dt
    The drag update is implicit in the speed, so it never reverses a bullet however large
    drag |v| dt is (the explicit v -= drag |v| v dt does once drag |v| dt > 1). age += dt; a bullet
    dies when age > lifetime, y < -1 m or |x| > far. A bullet killed here is not tested for hits
    on this step's segment.
    """
    for i in range(pos.shape[0]):
        integrate_bullet(i, pos, vel, age, alive, prev, dt, gravity, drag, lifetime, far)


@ti.kernel
def spawn_bullets(
    slots: ndarray(dtype=ti.i32, ndim=1),
    origins: ndarray(dtype=vec3, ndim=1),
    velocities: ndarray(dtype=vec3, ndim=1),
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    age: ndarray(ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    prev: ndarray(dtype=vec3, ndim=1),
):
    """Bullet k (origins, velocities: (K, 3)) goes live in slot slots[k] (K,) with age 0, prev = pos."""
    for k in range(slots.shape[0]):
        s = slots[k]
        pos[s] = origins[k]
        prev[s] = origins[k]
        vel[s] = velocities[k]
        age[s] = 0.0
        alive[s] = 1


# ---------------------------------------------------------------------------------------------
# uniform ground grid on (x, z): cell (ix, iz) covers [ox + ix*cell, ox + (ix+1)*cell) in x, the
# same in z; cell id iz*nx + ix. Coordinates outside the grid clamp to its border cells, so an
# object beyond the edge still shares a cell with everything it overlaps (clamping is monotone).


@ti.func
def cell_span(lo, hi, origin, cell, n):
    """First and last cell index (clamped to [0, n-1]) of the interval [lo, hi] on one axis."""
    i0 = ti.cast(ti.floor(ti.math.clamp((lo - origin) / cell, 0.0, n - 1.0)), ti.i32)
    i1 = ti.cast(ti.floor(ti.math.clamp((hi - origin) / cell, 0.0, n - 1.0)), ti.i32)
    return i0, i1


@ti.func
def swept_box(a0, b0, a1, b1, pad):
    """(x, z) bounding box of two segments (a0, b0) and (a1, b1), grown by pad on every side."""
    lo = ti.min(ti.min(a0, b0), ti.min(a1, b1)) - pad
    hi = ti.max(ti.max(a0, b0), ti.max(a1, b1)) + pad
    return lo[0], lo[2], hi[0], hi[2]


@ti.func
def cell_ok(masked, mask: ti.template(), m):
    """Whether cell m takes segments: every cell, or with masked != 0 only the marked ones."""
    return masked == 0 or mask[m] != 0


@ti.func
def count_box(x0, z0, x1, z1, ox, oz, cell, nx, nz, masked, mask: ti.template(), cell_count: ti.template()):
    """cell_count[c] += 1 for every (allowed) cell c the (x, z) box overlaps."""
    i0, i1 = cell_span(x0, x1, ox, cell, nx)
    k0, k1 = cell_span(z0, z1, oz, cell, nz)
    for k in range(k0, k1 + 1):
        for i in range(i0, i1 + 1):
            if cell_ok(masked, mask, k * nx + i):
                ti.atomic_add(cell_count[k * nx + i], 1)


@ti.func
def scan_cells(cell_count: ti.template(), cell_start: ti.template(), cursor: ti.template(), total: ti.template()):
    """Exclusive prefix sum (serial): cell_start (M+1,), cursor (M,) <- start of each cell; total[0] <- sum."""
    acc = 0
    for c in range(cell_count.shape[0]):
        cell_start[c] = acc
        cursor[c] = acc
        acc += cell_count[c]
    cell_start[cell_count.shape[0]] = acc
    total[0] = acc


@ti.func
def fill_box(s, x0, z0, x1, z1, ox, oz, cell, nx, nz, masked, mask: ti.template(), cursor: ti.template(),
             entries: ti.template()):
    """Write id s into the lists of the (allowed) cells the box overlaps, while entries has room."""
    i0, i1 = cell_span(x0, x1, ox, cell, nx)
    k0, k1 = cell_span(z0, z1, oz, cell, nz)
    for k in range(k0, k1 + 1):
        for i in range(i0, i1 + 1):
            if cell_ok(masked, mask, k * nx + i):
                slot = ti.atomic_add(cursor[k * nx + i], 1)
                if slot < entries.shape[0]:
                    entries[slot] = s


@ti.kernel
def build_grid(
    a0: ndarray(dtype=vec3, ndim=1),
    b0: ndarray(dtype=vec3, ndim=1),
    a1: ndarray(dtype=vec3, ndim=1),
    b1: ndarray(dtype=vec3, ndim=1),
    radius: ndarray(ndim=1),
    pad: float,
    owner: ndarray(dtype=ti.i32, ndim=1),
    owner_alive: ndarray(dtype=ti.i32, ndim=1),
    ox: float,
    oz: float,
    cell: float,
    nx: ti.i32,
    nz: ti.i32,
    masked: ti.i32,
    mask: ndarray(dtype=ti.i32, ndim=1),
    cell_count: ndarray(dtype=ti.i32, ndim=1),
    cell_start: ndarray(dtype=ti.i32, ndim=1),
    cursor: ndarray(dtype=ti.i32, ndim=1),
    total: ndarray(dtype=ti.i32, ndim=1),
    entries: ndarray(dtype=ti.i32, ndim=1),
):
    """Bin every live segment into the cells its box overlaps, in one launch of four phases.

    Segment s (a0, b0, a1, b1: (S, 3)) is the union of its two poses (a0, b0) and (a1, b1) grown
    by radius[s] + pad; it is live when owner_alive[owner[s]] != 0. With masked != 0 only cells
    with mask[c] != 0 (nx*nz,) take segments (cells nobody will read stay empty).
      1. cell_count (nx*nz,) <- 0;
      2. cell_count[c] += 1 for every (live segment, cell) pair (integer atomics);
      3. exclusive prefix sum: cell_start (M+1,), cursor (M,) <- start of each cell; total (1,) <-
         number of pairs. A serial loop: grids here have at most 256 x 256 cells;
      4. each pair writes its segment id at entries[atomic_add(cursor[c], 1)], only while that
         index is below entries.shape[0]: when total exceeds the capacity the caller grows
         entries and builds again.
    entries[cell_start[c] : cell_start[c+1]] then holds cell c's segment ids, in an order that may
    vary between runs (atomic cursor); every consumer takes an order-free minimum over them.
    """
    for c in range(cell_count.shape[0]):
        cell_count[c] = 0
    for s in range(a0.shape[0]):
        if owner_alive[owner[s]] != 0:
            x0, z0, x1, z1 = swept_box(a0[s], b0[s], a1[s], b1[s], radius[s] + pad)
            count_box(x0, z0, x1, z1, ox, oz, cell, nx, nz, masked, mask, cell_count)
    for _ in range(1):
        scan_cells(cell_count, cell_start, cursor, total)
    for s in range(a0.shape[0]):
        if owner_alive[owner[s]] != 0:
            x0, z0, x1, z1 = swept_box(a0[s], b0[s], a1[s], b1[s], radius[s] + pad)
            fill_box(s, x0, z0, x1, z1, ox, oz, cell, nx, nz, masked, mask, cursor, entries)


@ti.func
def mark_bullet(p, pos: ti.template(), vel: ti.template(), alive: ti.template(), dt, pad, ox, oz, cell, nx, nz,
                mask: ti.template()):
    """mark_bullet_cells for bullet p (the mask cleared first)."""
    if alive[p] != 0:
        q0 = pos[p]
        q1 = q0 + vel[p] * dt
        x0, z0, x1, z1 = swept_box(q0, q1, q0, q1, pad)
        i0, i1 = cell_span(x0, x1, ox, cell, nx)
        k0, k1 = cell_span(z0, z1, oz, cell, nz)
        for k in range(k0, k1 + 1):
            for i in range(i0, i1 + 1):
                mask[k * nx + i] = 1


@ti.kernel
def mark_bullet_cells(
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    dt: float,
    pad: float,
    ox: float,
    oz: float,
    cell: float,
    nx: ti.i32,
    nz: ti.i32,
    mask: ndarray(dtype=ti.i32, ndim=1),
):
    """mask (nx*nz,) <- 1 on the cells the live bullets can cross in the next dt seconds, else 0.

    A bullet's (x, z) path over the step is the segment pos -> pos + vel dt or part of it (gravity
    acts along y only; drag only shortens the velocity, never turns it in x, z), so the cells of
    that segment's box grown by `pad` (the bullet radius plus a rounding margin) hold every cell
    collide_bullets walks on any sub-step of the step.
    """
    for c in range(mask.shape[0]):
        mask[c] = 0
    for p in range(pos.shape[0]):
        mark_bullet(p, pos, vel, alive, dt, pad, ox, oz, cell, nx, nz, mask)


@ti.func
def reachable_owner(n, owner_box: ti.template(), owner_alive: ti.template(), ox, oz, cell, nx, nz,
                    mask: ti.template()):
    """1 if owner n is live and its box overlaps a marked cell, else 0 (see reachable_owners)."""
    hit = 0
    if owner_alive[n] != 0:
        i0, i1 = cell_span(owner_box[n, 0], owner_box[n, 2], ox, cell, nx)
        k0, k1 = cell_span(owner_box[n, 1], owner_box[n, 3], oz, cell, nz)
        for k in range(k0, k1 + 1):
            for i in range(i0, i1 + 1):
                if mask[k * nx + i] != 0:
                    hit = 1
    return hit


@ti.kernel
def reachable_owners(
    owner_box: ndarray(ndim=2),
    owner_alive: ndarray(dtype=ti.i32, ndim=1),
    ox: float,
    oz: float,
    cell: float,
    nx: ti.i32,
    nz: ti.i32,
    mask: ndarray(dtype=ti.i32, ndim=1),
    reachable: ndarray(dtype=ti.i32, ndim=1),
):
    """reachable (N,) <- 1 for each live owner whose (x, z) box overlaps a marked cell, else 0.

    owner_box (N, 4): x_min, z_min, x_max, z_max of all of an owner's segments in both poses,
    grown by their radii, so an owner that is not reachable has no segment in a marked cell.
    """
    for n in range(owner_box.shape[0]):
        reachable[n] = reachable_owner(n, owner_box, owner_alive, ox, oz, cell, nx, nz, mask)

# ---------------------------------------------------------------------------------------------
# narrow phase


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


# ---------------------------------------------------------------------------------------------
# threats


@ti.func
def find_threat(n, points: ti.template(), char_alive: ti.template(), pos: ti.template(), vel: ti.template(),
                alive: ti.template(), horizon, reach, ox, oz, cell, nx, nz, cell_start: ti.template(),
                entries: ti.template(), threat_bullet: ti.template(), threat_time: ti.template(),
                threat_miss: ti.template(), threat_point: ti.template(), threat_dir: ti.template()):
    """For character n (if live), the approaching bullet that first comes within `reach` of points[n].

    Bullets fly straight (gravity is ignored over the short horizon; the game re-asks every step).
    For bullet p: t* = clamp((point - pos) . vel / |vel|^2, 0, horizon), miss = |pos + vel t* - point|;
    a threat has (point - pos) . vel > 0 and miss <= reach. The one with the smallest (t*, p) wins.
    Outputs at n of (N,) arrays: threat_bullet (-1 when none), threat_time t* s, threat_miss m (both -1
    when none), threat_point (N, 3) the bullet's position at t*, threat_dir (N, 3) its unit direction
    (0 when none).
    The grid holds the bullets' segments pos -> pos + vel horizon grown by `reach`, so a character
    reads only the one cell its point falls in.
    """
    best_t = horizon + 1.0
    best_p = -1
    best_m = 0.0
    c = points[n]
    if char_alive[n] != 0:
        i, _ = cell_span(c[0], c[0], ox, cell, nx)
        k, _ = cell_span(c[2], c[2], oz, cell, nz)
        m = k * nx + i
        for e in range(cell_start[m], cell_start[m + 1]):
            p = entries[e]
            if alive[p] != 0:
                v = vel[p]
                rel = c - pos[p]
                vv = v.dot(v)
                ahead = rel.dot(v)
                if vv > 0.0 and ahead > 0.0:
                    t = ti.min(ahead / vv, horizon)
                    miss = (rel - t * v).norm()
                    if miss <= reach and (t < best_t or (t == best_t and p < best_p)):
                        best_t = t
                        best_p = p
                        best_m = miss
    threat_bullet[n] = best_p
    if best_p >= 0:
        v = vel[best_p]
        threat_time[n] = best_t
        threat_miss[n] = best_m
        threat_point[n] = pos[best_p] + best_t * v
        threat_dir[n] = v / v.norm()
    else:
        threat_time[n] = -1.0
        threat_miss[n] = -1.0
        threat_point[n] = vec3(0.0, 0.0, 0.0)
        threat_dir[n] = vec3(0.0, 0.0, 0.0)


@ti.kernel
def export_bullets(
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    pos_out: ndarray(dtype=vec3, ndim=1),
    vel_out: ndarray(dtype=vec3, ndim=1),
    alive_out: ndarray(dtype=ti.i32, ndim=1),
):
    """pos_out, vel_out (P, 3) <- pos, vel; alive_out (P,) <- alive: the pool's state copied out in
    one launch (the outputs are usually host NumPy arrays)."""
    for p in range(pos.shape[0]):
        pos_out[p] = pos[p]
        vel_out[p] = vel[p]
        alive_out[p] = alive[p]


# ---------------------------------------------------------------------------------------------
# fused phases: the same loop bodies as above, several top-level loops (run one after the other,
# each in parallel) per launch. A launch costs ~0.05-0.3 ms on the CPU backend whatever its size,
# which is most of a small scene's step.


@ti.kernel
def threat_pass(
    points: ndarray(dtype=vec3, ndim=1),
    char_alive: ndarray(dtype=ti.i32, ndim=1),
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    horizon: float,
    reach: float,
    ox: float,
    oz: float,
    cell: float,
    nx: ti.i32,
    nz: ti.i32,
    cell_count: ndarray(dtype=ti.i32, ndim=1),
    cell_start: ndarray(dtype=ti.i32, ndim=1),
    cursor: ndarray(dtype=ti.i32, ndim=1),
    total: ndarray(dtype=ti.i32, ndim=1),
    entries: ndarray(dtype=ti.i32, ndim=1),
    threat_bullet: ndarray(dtype=ti.i32, ndim=1),
    threat_time: ndarray(ndim=1),
    threat_miss: ndarray(ndim=1),
    threat_point: ndarray(dtype=vec3, ndim=1),
    threat_dir: ndarray(dtype=vec3, ndim=1),
    n_slots: ti.i32,
):
    """predict_bullets + build_grid of the live bullets' paths pos -> pos + vel horizon grown by
    reach (segment id = slot) + find_threats, in one launch. Valid when total[0] <= entries.shape[0]
    afterwards; otherwise the caller grows entries and launches again. Slots n_slots and up were never
    used (BulletPool keeps that mark), so the loops over bullets stop there."""
    for c in range(cell_count.shape[0]):
        cell_count[c] = 0
    for p in range(n_slots):
        if alive[p] != 0:
            q0 = pos[p]
            q1 = q0 + vel[p] * horizon
            x0, z0, x1, z1 = swept_box(q0, q1, q0, q1, reach)
            count_box(x0, z0, x1, z1, ox, oz, cell, nx, nz, 0, cell_count, cell_count)  # unmasked: no mask
    for _ in range(1):
        scan_cells(cell_count, cell_start, cursor, total)
    for p in range(n_slots):
        if alive[p] != 0:
            q0 = pos[p]
            q1 = q0 + vel[p] * horizon
            x0, z0, x1, z1 = swept_box(q0, q1, q0, q1, reach)
            fill_box(p, x0, z0, x1, z1, ox, oz, cell, nx, nz, 0, cell_count, cursor, entries)
    for n in range(points.shape[0]):
        if total[0] <= entries.shape[0]:  # else the grid overflowed: the caller launches again
            find_threat(n, points, char_alive, pos, vel, alive, horizon, reach, ox, oz, cell, nx, nz, cell_start,
                        entries, threat_bullet, threat_time, threat_miss, threat_point, threat_dir)


@ti.func
def count_limb(c, a0: ti.template(), b0: ti.template(), a1: ti.template(), b1: ti.template(), radius: ti.template(),
               owner: ti.template(), reachable: ti.template(), substeps: ti.template(), ox, oz, cell, nx, nz,
               mask: ti.template(), cell_count: ti.template()):
    """Limb c of a reachable owner: its sub-step count, and its swept box counted into the marked cells."""
    limb_substeps(c, a0, b0, a1, b1, radius, owner, reachable, substeps)
    x0, z0, x1, z1 = swept_box(a0[c], b0[c], a1[c], b1[c], radius[c])
    count_box(x0, z0, x1, z1, ox, oz, cell, nx, nz, 1, mask, cell_count)


@ti.func
def fill_limb(c, a0: ti.template(), b0: ti.template(), a1: ti.template(), b1: ti.template(), radius: ti.template(),
              ox, oz, cell, nx, nz, mask: ti.template(), cursor: ti.template(), entries: ti.template()):
    """Limb c of a reachable owner into the marked cells its swept box covers."""
    x0, z0, x1, z1 = swept_box(a0[c], b0[c], a1[c], b1[c], radius[c])
    fill_box(c, x0, z0, x1, z1, ox, oz, cell, nx, nz, 1, mask, cursor, entries)


@ti.kernel
def prepare_limbs(
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    dt: float,
    pad: float,
    ox: float,
    oz: float,
    cell: float,
    nx: ti.i32,
    nz: ti.i32,
    mask: ndarray(dtype=ti.i32, ndim=1),
    owner_box: ndarray(ndim=2),
    char_alive: ndarray(dtype=ti.i32, ndim=1),
    reachable: ndarray(dtype=ti.i32, ndim=1),
    a0: ndarray(dtype=vec3, ndim=1),
    b0: ndarray(dtype=vec3, ndim=1),
    a1: ndarray(dtype=vec3, ndim=1),
    b1: ndarray(dtype=vec3, ndim=1),
    radius: ndarray(ndim=1),
    owner: ndarray(dtype=ti.i32, ndim=1),
    substeps: ndarray(dtype=ti.i32, ndim=1),
    hit_key: ndarray(dtype=ti.i64, ndim=1),
    hit_bullet: ndarray(dtype=ti.i32, ndim=1),
    bullet_char: ndarray(dtype=ti.i32, ndim=1),
    cell_count: ndarray(dtype=ti.i32, ndim=1),
    cell_start: ndarray(dtype=ti.i32, ndim=1),
    cursor: ndarray(dtype=ti.i32, ndim=1),
    total: ndarray(dtype=ti.i32, ndim=1),
    entries: ndarray(dtype=ti.i32, ndim=1),
    n_slots: ti.i32,
    stride: ti.i32,
):
    """Everything a step's collisions need before the bullets move, in one launch:
    mark_bullet_cells (pad, dt) + reachable_owners (owner_box, char_alive -> reachable) +
    count_substeps over the reachable owners' limbs (into substeps[0], zeroed by the caller) +
    build_grid of those limbs into the marked cells + reset_hits. The grid is valid when total[0]
    <= entries.shape[0] afterwards; otherwise the caller grows entries and launches again. Bullet loops stop
    at n_slots (slots beyond were never used). stride > 0 says that capsule c belongs to owner c // stride
    (each owner's capsules in one block): the limb loops then visit the reachable owners' blocks only,
    instead of every capsule to look up its owner."""
    for c in range(mask.shape[0]):
        mask[c] = 0
        cell_count[c] = 0
    for p in range(n_slots):
        mark_bullet(p, pos, vel, alive, dt, pad, ox, oz, cell, nx, nz, mask)
        bullet_char[p] = -1
    for n in range(owner_box.shape[0]):
        reachable[n] = reachable_owner(n, owner_box, char_alive, ox, oz, cell, nx, nz, mask)
        hit_key[n] = ti.i64(NO_HIT)
        hit_bullet[n] = -1
    # the reachable owners' limbs, by capsule (any layout) or by owner block (stride > 0); in each pair of
    # loops one runs zero times
    by_capsule = a0.shape[0] if stride == 0 else 0
    by_owner = owner_box.shape[0] if stride > 0 else 0
    for c in range(by_capsule):
        if reachable[owner[c]] != 0:
            count_limb(c, a0, b0, a1, b1, radius, owner, reachable, substeps, ox, oz, cell, nx, nz, mask, cell_count)
    for n in range(by_owner):
        if reachable[n] != 0:
            for c in range(n * stride, (n + 1) * stride):
                count_limb(c, a0, b0, a1, b1, radius, owner, reachable, substeps, ox, oz, cell, nx, nz, mask,
                           cell_count)
    for _ in range(1):
        scan_cells(cell_count, cell_start, cursor, total)
    for c in range(by_capsule):
        if reachable[owner[c]] != 0:
            fill_limb(c, a0, b0, a1, b1, radius, ox, oz, cell, nx, nz, mask, cursor, entries)
    for n in range(by_owner):
        if reachable[n] != 0:
            for c in range(n * stride, (n + 1) * stride):
                fill_limb(c, a0, b0, a1, b1, radius, ox, oz, cell, nx, nz, mask, cursor, entries)


@ti.kernel
def advance_bullets(
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    age: ndarray(ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    prev: ndarray(dtype=vec3, ndim=1),
    dt: float,
    gravity: float,
    drag: float,
    lifetime: float,
    far: float,
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
    hit_bullet: ndarray(dtype=ti.i32, ndim=1),
    export: ti.i32,
    pos_out: ndarray(dtype=vec3, ndim=1),
    vel_out: ndarray(dtype=vec3, ndim=1),
    alive_out: ndarray(dtype=ti.i32, ndim=1),
    n_slots: ti.i32,
):
    """One sub-step in one launch: integrate_bullets (dt) then collide_bullets for each bullet (a
    bullet's collision reads only its own new segment), then apply_hits; with export != 0 also
    export_bullets into pos_out, vel_out, alive_out. Only slots below n_slots (the others were never used: their
    exported values stay as they are, dead)."""
    for p in range(n_slots):
        integrate_bullet(p, pos, vel, age, alive, prev, dt, gravity, drag, lifetime, far)
        collide_bullet(p, prev, pos, alive, bullet_radius, a0, b0, a1, b1, s, radius, owner, char_alive, ox, oz, cell,
                       nx, nz, cell_start, entries, substep, n_substeps, hit_key, bullet_key, bullet_char, bullet_toi,
                       bullet_point)
    for p in range(n_slots):
        apply_hit(p, alive, bullet_char, bullet_key, hit_key, hit_bullet)
        if export != 0:
            pos_out[p] = pos[p]
            vel_out[p] = vel[p]
            alive_out[p] = alive[p]
