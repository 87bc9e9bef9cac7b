"""NumPy twins of kernels/projectiles.py: brute force (no grid), vectorised, written for clarity.

The swept test here is analytic (Ericson, Real-Time Collision Detection, 5.3.7: segment against
cylinder and spheres), an independent oracle for the kernels' cutting-plane + Newton search.
Shapes and units as in the kernels: P bullets, C capsules, N characters; metres, seconds.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.sweep import point_segment_distance, sweep_toi  # noqa: F401  (the tests' too)

NO_HIT = np.iinfo(np.int64).max
TOI_BITS = 24


def integrate(pos, vel, age, alive, dt, gravity, drag, lifetime, far):
    """One semi-implicit Euler step of the live bullets; returns (pos, vel, age, alive, prev) copies."""
    pos, vel, age, alive = (np.array(x) for x in (pos, vel, age, alive))
    live = alive != 0
    prev = pos.copy()
    w = vel[live] + np.array([0.0, -gravity, 0.0], dtype=vel.dtype) * vel.dtype.type(dt)
    v = w / (1.0 + drag * np.linalg.norm(w, axis=1, keepdims=True) * dt)
    vel[live] = v
    pos[live] = pos[live] + v * vel.dtype.type(dt)
    age[live] = age[live] + age.dtype.type(dt)
    dead = (age > lifetime) | (pos[:, 1] < -1.0) | (np.linalg.norm(pos, axis=1) > far)
    alive[live & dead] = 0
    return pos, vel, age, alive, prev


def spawn(slots, origins, velocities, pos, vel, age, alive, prev):
    """Bullets k go live in slots[k]; returns (pos, vel, age, alive, prev) copies."""
    pos, vel, age, alive, prev = (np.array(x) for x in (pos, vel, age, alive, prev))
    pos[slots] = origins
    prev[slots] = origins
    vel[slots] = velocities
    age[slots] = 0.0
    alive[slots] = 1
    return pos, vel, age, alive, prev


def cell_span(lo, hi, origin, cell, n):
    """First and last clamped cell index of [lo, hi] on one axis (arrays)."""
    i0 = np.floor(np.clip((lo - origin) / cell, 0.0, n - 1.0)).astype(np.int64)
    i1 = np.floor(np.clip((hi - origin) / cell, 0.0, n - 1.0)).astype(np.int64)
    return i0, i1


def grid_pairs(a0, b0, a1, b1, radius, pad, owner, owner_alive, ox, oz, cell, nx, nz, cell_mask=None):
    """(cell, segment) pairs of the grid as a (K, 2) int64 array sorted by cell then segment.

    Segment s covers the cells its two poses' (x, z) box, grown by radius[s] + pad, overlaps;
    dead owners' segments are left out; with cell_mask (nx*nz,) only cells marked non-zero are kept.
    """
    pts = np.stack([a0, b0, a1, b1])
    grow = (np.asarray(radius, np.float64) + pad)[:, None]
    lo = pts.min(axis=0) - grow
    hi = pts.max(axis=0) + grow
    i0, i1 = cell_span(lo[:, 0], hi[:, 0], ox, cell, nx)
    k0, k1 = cell_span(lo[:, 2], hi[:, 2], oz, cell, nz)
    live = np.asarray(owner_alive)[np.asarray(owner)] != 0
    ids = np.flatnonzero(live)
    wi, wk = (i1 - i0 + 1)[ids], (k1 - k0 + 1)[ids]
    seg = np.repeat(ids, wi * wk)
    local = np.arange(len(seg)) - np.repeat(np.cumsum(wi * wk) - wi * wk, wi * wk)
    ix = i0[seg] + local % np.repeat(wi, wi * wk)
    iz = k0[seg] + local // np.repeat(wi, wi * wk)
    pairs = np.stack([iz * nx + ix, seg], axis=1)
    if cell_mask is not None:
        pairs = pairs[np.asarray(cell_mask)[pairs[:, 0]] != 0]
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def bullet_cells(pos, vel, alive, dt, pad, ox, oz, cell, nx, nz):
    """(nx*nz,) int32 mask of the cells the live bullets' boxes pos -> pos + vel dt, grown by pad, overlap."""
    pos, vel = np.asarray(pos, np.float64), np.asarray(vel, np.float64)
    live = np.asarray(alive) != 0
    end = pos + vel * dt
    lo = np.minimum(pos, end)[live] - pad
    hi = np.maximum(pos, end)[live] + pad
    i0, i1 = cell_span(lo[:, 0], hi[:, 0], ox, cell, nx)
    k0, k1 = cell_span(lo[:, 2], hi[:, 2], oz, cell, nz)
    ix, iz = np.arange(nx), np.arange(nz)
    in_x = (ix >= i0[:, None]) & (ix <= i1[:, None])  # (B, nx)
    in_z = (iz >= k0[:, None]) & (iz <= k1[:, None])  # (B, nz)
    return np.any(in_z[:, :, None] & in_x[:, None, :], axis=0).astype(np.int32).reshape(-1)


def reachable_owners(owner_box, owner_alive, mask, ox, oz, cell, nx, nz):
    """(N,) int32: 1 for live owners whose (x, z) box (N, 4) overlaps a cell marked in mask (nx*nz,)."""
    box = np.asarray(owner_box, np.float64)
    i0, i1 = cell_span(box[:, 0], box[:, 2], ox, cell, nx)
    k0, k1 = cell_span(box[:, 1], box[:, 3], oz, cell, nz)
    marked = np.asarray(mask).reshape(nz, nx) != 0
    ix, iz = np.arange(nx), np.arange(nz)
    in_x = (ix >= i0[:, None]) & (ix <= i1[:, None])  # (N, nx)
    in_z = (iz >= k0[:, None]) & (iz <= k1[:, None])  # (N, nz)
    hit = np.any(in_z[:, :, None] & in_x[:, None, :] & marked[None], axis=(1, 2))
    return (hit & (np.asarray(owner_alive) != 0)).astype(np.int32)

def collide(prev, pos, alive, bullet_radius, a, b, radius, owner, char_alive, n_chars):
    """Brute-force hits of one step against capsules in their end-of-step pose (a, b).

    Returns (bullet_char (P,) int32, bullet_toi (P,) float64, hit_bullet (N,) int32):
    every live bullet's earliest (toi, capsule id) hit on a live character (or -1), and per
    character the winner by (quantised toi, bullet id) (or -1).
    """
    owner = np.asarray(owner)
    live_c = np.asarray(char_alive)[owner] != 0
    toi = sweep_toi(np.asarray(prev)[:, None], np.asarray(pos)[:, None], np.asarray(a)[None],
                    np.asarray(b)[None], bullet_radius + np.asarray(radius, np.float64)[None])
    toi = np.where((toi >= 0) & live_c[None] & (np.asarray(alive) != 0)[:, None], toi, np.inf)
    first = np.argmin(toi, axis=1)  # lowest capsule id among equal times
    t = toi[np.arange(len(toi)), first] if len(toi) else np.zeros(0)
    hit = np.isfinite(t)
    bullet_char = np.where(hit, owner[first] if len(owner) else -1, -1).astype(np.int32)
    bullet_toi = np.where(hit, t, -1.0)
    return bullet_char, bullet_toi, _winners(bullet_char, bullet_toi, n_chars)


def bullet_substeps(prev, pos, alive, bullet_radius, a0, b0, a1, b1, radius, owner, char_alive, max_substeps):
    """(P,) int32 sub-steps per bullet: over the live limbs whose box (both poses, grown by the radius) overlaps
    the bullet's segment box grown by bullet_radius, the most ceil(max end displacement / radius), in
    [1, max_substeps]; 0 for a dead bullet."""
    prev, pos = np.asarray(prev, np.float64), np.asarray(pos, np.float64)
    ends = np.stack([a0, b0, a1, b1]).astype(np.float64)
    r = np.asarray(radius, np.float64)[:, None]
    c_lo, c_hi = ends.min(axis=0) - r, ends.max(axis=0) + r
    b_lo = np.minimum(prev, pos) - bullet_radius
    b_hi = np.maximum(prev, pos) + bullet_radius
    near = np.all((c_lo[None] <= b_hi[:, None]) & (c_hi[None] >= b_lo[:, None]), axis=2)  # (P, C)
    near &= (np.asarray(char_alive)[np.asarray(owner)] != 0)[None]
    move = np.maximum(np.linalg.norm(ends[2] - ends[0], axis=1), np.linalg.norm(ends[3] - ends[1], axis=1))
    k_limb = np.minimum(np.ceil(np.minimum(move / r[:, 0], 2.0**20)), max_substeps)
    k = np.max(np.where(near, k_limb[None], 1), axis=1, initial=1).astype(np.int32)
    return np.where(np.asarray(alive) != 0, k, 0)


def collide_moving(prev, pos, alive, bullet_radius, a0, b0, a1, b1, radius, owner, char_alive, n_chars,
                   max_substeps=16):
    """Brute-force hits of one step against limbs moving linearly from (a0, b0) to (a1, b1).

    Bullet p takes k = bullet_substeps sub-steps: sub-segment j of its segment against the limbs at
    (j + 1) / k of the way, j = 0, 1, ... until one hits. Returns (bullet_char (P,) int32, bullet_toi
    (P,) float64 fraction of the step, k (P,) int32, hit_bullet (N,) int32) as collide does.
    """
    prev, pos = np.asarray(prev, np.float64), np.asarray(pos, np.float64)
    k = bullet_substeps(prev, pos, alive, bullet_radius, a0, b0, a1, b1, radius, owner, char_alive, max_substeps)
    owner = np.asarray(owner)
    live_c = np.asarray(char_alive)[owner] != 0
    R = bullet_radius + np.asarray(radius, np.float64)
    bullet_char = np.full(len(prev), -1, np.int32)
    bullet_toi = np.full(len(prev), -1.0)
    for p in np.flatnonzero(k > 0):
        for j in range(k[p]):
            s = (j + 1) / k[p]
            a = (1 - s) * np.asarray(a0, np.float64) + s * np.asarray(a1, np.float64)
            b = (1 - s) * np.asarray(b0, np.float64) + s * np.asarray(b1, np.float64)
            q0 = prev[p] + j / k[p] * (pos[p] - prev[p])
            q1 = prev[p] + s * (pos[p] - prev[p])
            t = np.where(live_c, sweep_toi(q0[None], q1[None], a, b, R), -1.0)
            t = np.where(t >= 0, t, np.inf)
            if np.isfinite(t).any():
                c = int(np.argmin(t))  # lowest capsule id among equal times
                bullet_char[p] = owner[c]
                bullet_toi[p] = (j + t[c]) / k[p]
                break
    return bullet_char, bullet_toi, k, _winners(bullet_char, bullet_toi, n_chars)


def _winners(bullet_char, bullet_toi, n_chars):
    """(N,) int32: per character the bullet with the smallest (quantised toi, bullet id) that struck it, or -1."""
    hit_bullet = np.full(n_chars, -1, np.int32)
    p = np.flatnonzero(bullet_char >= 0)
    qt = np.minimum(np.floor(bullet_toi[p] * 2**TOI_BITS), 2**TOI_BITS - 1)
    order = np.lexsort((p, qt))  # by quantised toi, then bullet id
    chars, firsts = np.unique(bullet_char[p][order], return_index=True)
    hit_bullet[chars] = p[order][firsts]
    return hit_bullet


def threats(points, char_alive, pos, vel, alive, horizon, reach):
    """Brute-force twin of find_threats (P >= 1): (bullet (N,), time (N,), miss (N,), point (N, 3), dir (N, 3))."""
    points, pos, vel = (np.asarray(x, np.float64) for x in (points, pos, vel))
    rel = points[:, None] - pos[None]                       # (N, P, 3)
    vv = np.sum(vel * vel, axis=1)[None]                    # (1, P)
    ahead = np.sum(rel * vel[None], axis=2)
    t = np.minimum(ahead / np.where(vv > 0, vv, 1.0), horizon)
    miss = np.linalg.norm(rel - t[..., None] * vel[None], axis=2)
    ok = (vv > 0) & (ahead > 0) & (miss <= reach) & (np.asarray(alive) != 0)[None]
    ok &= (np.asarray(char_alive) != 0)[:, None]
    key = np.where(ok, t, np.inf)
    best = np.argmin(key, axis=1)                           # lowest bullet id among equal times
    n = np.arange(len(points))
    found = np.isfinite(key[n, best])
    bullet = np.where(found, best, -1).astype(np.int32)
    time = np.where(found, t[n, best], -1.0)
    miss_d = np.where(found, miss[n, best], -1.0)
    v = vel[best]
    point = np.where(found[:, None], pos[best] + time[:, None] * v, 0.0)
    direction = np.where(found[:, None], v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-30), 0.0)
    return bullet, time, miss_d, point, direction
