"""Bullet physics, a uniform ground grid, swept bullet-vs-limb hits and threat detection.

Arrays: P bullet slots, C limb capsules, N characters. Positions in metres, world frame (y up);
velocities in m/s; times in seconds.

Phases (one launch each; `crowd_ik.game.pool.BulletPool` runs them in this order), one module each:
  bullet_physics   integrate_bullets      semi-implicit Euler with gravity and quadratic drag
                   (spawn_bullets, export_bullets)
  bullet_grid      mark_bullet_cells,     broad phase: a uniform grid on (x, z) built with integer
                   reachable_owners,      atomics only (count, exclusive prefix sum, scatter), in the
                   build_grid             cells the bullets can reach, of the owners with a segment there
  bullet_hits      reset_hits,            narrow phase: earliest time of impact per bullet (each
                   collide_bullets,       sub-stepped as its near limbs need), then one winner per
                   apply_hits             character by an int64 atomic_min on key = quantised toi << 32 | id
  bullet_threats   threat_pass            per character, the first bullet that will pass near it
This module re-exports them and holds the fused kernels the game's step launches instead:
prepare_limbs (marking, reachable characters, limb grid, reset) and advance_bullets (integrate,
collide, apply, export), built from the same loop bodies.

Determinism: nothing here uses float atomics. The order of capsule ids inside a grid cell depends on
thread timing, but every result is a minimum under a total order ((toi, capsule id) per bullet,
(key) per character), so it is the same whatever order the candidates are visited in.
"""

import taichi as ti

from crowd_ik.kernels.bullet_grid import (build_grid, count_box, fill_box, mark_bullet, mark_bullet_cells,  # noqa: F401
                                          reachable_owner, reachable_owners, scan_cells, swept_box)
from crowd_ik.kernels.bullet_hits import (MAX_SUBSTEPS, NO_HIT, TOI_BITS, apply_hit, apply_hits,  # noqa: F401
                                          collide_bullet, collide_bullets, reset_hits)
from crowd_ik.kernels.bullet_physics import export_bullets, integrate_bullet, integrate_bullets, spawn_bullets  # noqa: F401
from crowd_ik.kernels.bullet_threats import threat_pass  # noqa: F401

ndarray = ti.types.ndarray
vec3 = ti.math.vec3

# ---------------------------------------------------------------------------------------------
# fused phases: the same loop bodies as above, several top-level loops (run one after the other,
# each in parallel, or all on the launching thread with serial=True: kernels/serial_loops.py) per
# launch. A launch costs ~0.05-0.3 ms on the CPU backend whatever its size, which is most of a small
# scene's step.


@ti.func
def count_limb(c, a0: ti.template(), b0: ti.template(), a1: ti.template(), b1: ti.template(), radius: ti.template(),
               ox, oz, cell, nx, nz, mask: ti.template(), cell_count: ti.template()):
    """Limb c of a reachable owner: its swept box counted into the marked cells."""
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
    serial: ti.template(),
):
    """Everything a step's collisions need before the bullets move, in one launch:
    mark_bullet_cells (pad, dt) + reachable_owners (owner_box, char_alive -> reachable) +
    build_grid of the reachable owners' limbs into the marked cells + reset_hits. The grid is valid when
    total[0] <= entries.shape[0] afterwards; otherwise the caller grows entries and launches again. Bullet
    loops stop at n_slots (slots beyond were never used). stride > 0 says that capsule c belongs to owner
    c // stride (each owner's capsules in one block): the grid then lists the reachable owners by their
    boxes instead of their limbs (a tenth of the entries for a humanoid, and no limb is read here), and
    collide_bullet reads each listed owner's block."""
    ti.loop_config(serialize=serial)
    for c in range(mask.shape[0]):
        mask[c] = 0
        cell_count[c] = 0
    ti.loop_config(serialize=serial)
    for p in range(n_slots):
        mark_bullet(p, pos, vel, alive, dt, pad, ox, oz, cell, nx, nz, mask)
        bullet_char[p] = -1
    ti.loop_config(serialize=serial)
    for n in range(owner_box.shape[0]):
        reachable[n] = reachable_owner(n, owner_box, char_alive, ox, oz, cell, nx, nz, mask)
        hit_key[n] = ti.i64(NO_HIT)
        hit_bullet[n] = -1
    # into the grid: the reachable owners' limbs (any layout), or with stride > 0 the reachable owners themselves
    # by their boxes (collide_bullet then reads each one's block of limbs); in each pair of loops one runs zero
    # times
    by_capsule = a0.shape[0] if stride == 0 else 0
    by_owner = owner_box.shape[0] if stride > 0 else 0
    ti.loop_config(serialize=serial)
    for c in range(by_capsule):
        if reachable[owner[c]] != 0:
            count_limb(c, a0, b0, a1, b1, radius, ox, oz, cell, nx, nz, mask, cell_count)
    ti.loop_config(serialize=serial)
    for n in range(by_owner):
        if reachable[n] != 0:
            count_box(owner_box[n, 0], owner_box[n, 1], owner_box[n, 2], owner_box[n, 3], ox, oz, cell, nx, nz, 1,
                      mask, cell_count)
    ti.loop_config(serialize=serial)
    for _ in range(1):
        scan_cells(cell_count, cell_start, cursor, total)
    ti.loop_config(serialize=serial)
    for c in range(by_capsule):
        if reachable[owner[c]] != 0:
            fill_limb(c, a0, b0, a1, b1, radius, ox, oz, cell, nx, nz, mask, cursor, entries)
    ti.loop_config(serialize=serial)
    for n in range(by_owner):
        if reachable[n] != 0:
            fill_box(n, owner_box[n, 0], owner_box[n, 1], owner_box[n, 2], owner_box[n, 3], ox, oz, cell, nx, nz, 1,
                     mask, cursor, entries)


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
    hit_bullet: ndarray(dtype=ti.i32, ndim=1),
    export: ti.i32,
    pos_out: ndarray(dtype=vec3, ndim=1),
    vel_out: ndarray(dtype=vec3, ndim=1),
    alive_out: ndarray(dtype=ti.i32, ndim=1),
    n_slots: ti.i32,
    serial: ti.template(),
):
    """A step in one launch: integrate_bullets (dt) then collide_bullets for each bullet (a bullet's
    collision reads only its own new segment), then apply_hits; with export != 0 also
    export_bullets into pos_out, vel_out, alive_out. Only slots below n_slots (the others were never used: their
    exported values stay as they are, dead)."""
    ti.loop_config(serialize=serial)
    for p in range(n_slots):
        integrate_bullet(p, pos, vel, age, alive, prev, dt, gravity, drag, lifetime, far)
        collide_bullet(p, prev, pos, alive, bullet_radius, a0, b0, a1, b1, radius, owner, char_alive, ox, oz, cell, nx,
                       nz, cell_start, entries, stride, owner_box, max_substeps, hit_key, bullet_key, bullet_char,
                       bullet_toi, bullet_point, bullet_substeps)
    ti.loop_config(serialize=serial)
    for p in range(n_slots):
        apply_hit(p, alive, bullet_char, bullet_key, hit_key, hit_bullet)
        if export != 0:
            pos_out[p] = pos[p]
            vel_out[p] = vel[p]
            alive_out[p] = alive[p]
