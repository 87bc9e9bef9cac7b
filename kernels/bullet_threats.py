"""Threats: per character, the first live bullet that will pass within reach of it within the horizon."""

import taichi as ti

from crowd_ik.kernels.bullet_grid import cell_span, count_box, fill_box, scan_cells, swept_box

ndarray = ti.types.ndarray
vec3 = ti.math.vec3


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
    serial: ti.template(),
):
    """predict_bullets + build_grid of the live bullets' paths pos -> pos + vel horizon grown by
    reach (segment id = slot) + find_threats, in one launch. Valid when total[0] <= entries.shape[0]
    afterwards; otherwise the caller grows entries and launches again. Slots n_slots and up were never
    used (BulletPool keeps that mark), so the loops over bullets stop there."""
    ti.loop_config(serialize=serial)
    for c in range(cell_count.shape[0]):
        cell_count[c] = 0
    ti.loop_config(serialize=serial)
    for p in range(n_slots):
        if alive[p] != 0:
            q0 = pos[p]
            q1 = q0 + vel[p] * horizon
            x0, z0, x1, z1 = swept_box(q0, q1, q0, q1, reach)
            count_box(x0, z0, x1, z1, ox, oz, cell, nx, nz, 0, cell_count, cell_count)  # unmasked: no mask
    ti.loop_config(serialize=serial)
    for _ in range(1):
        scan_cells(cell_count, cell_start, cursor, total)
    ti.loop_config(serialize=serial)
    for p in range(n_slots):
        if alive[p] != 0:
            q0 = pos[p]
            q1 = q0 + vel[p] * horizon
            x0, z0, x1, z1 = swept_box(q0, q1, q0, q1, reach)
            fill_box(p, x0, z0, x1, z1, ox, oz, cell, nx, nz, 0, cell_count, cursor, entries)
    ti.loop_config(serialize=serial)
    for n in range(points.shape[0]):
        if total[0] <= entries.shape[0]:  # else the grid overflowed: the caller launches again
            find_threat(n, points, char_alive, pos, vel, alive, horizon, reach, ox, oz, cell, nx, nz, cell_start,
                        entries, threat_bullet, threat_time, threat_miss, threat_point, threat_dir)
