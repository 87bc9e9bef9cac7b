"""Broad phase of the bullets' hits: a uniform ground grid on (x, z) built with integer atomics only
(count, exclusive prefix sum, scatter), in the cells the bullets can reach, of the owners that have
a segment there."""

import taichi as ti

ndarray = ti.types.ndarray
vec3 = ti.math.vec3

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
