"""BulletPool: the game's bullets in a fixed pool of slots, with swept hits on limb capsules and threats.

All state is `ti.ndarray`s allocated once (per-character outputs when the character count is first
seen); each phase is one kernel launch from `crowd_ik.kernels.projectiles`. Capsule and character
inputs may be NumPy arrays (converted and checked here) or `ti.ndarray`s (trusted, as inside the game).
Small results the host reads every step (the grid's entry count, each character's winning bullet,
each bullet's time and point of impact and sub-steps, the threats) are NumPy arrays the kernels
write directly: on the CPU backend that costs nothing, where a `to_numpy` is one more launch
(~0.1-0.3 ms) per array.

Rules (DESIGN "Game rules"):
- spawn fills the lowest free slots first; a request larger than the free slots keeps its first
  ones and drops the rest, and says how many it dropped;
- a hit is the bullet's segment of a (sub-)step passing within bullet radius + limb radius of a limb
  in the limb's end-of-(sub-)step pose; each bullet's earliest hit counts, ties to the lower capsule id;
- a character is hit at most once per step: the bullet with the smallest (quantised toi, bullet id)
  wins it (an int64 atomic_min), whatever the thread order;
- every bullet that strikes a limb dies, winner or not (the body stops it);
- `advance` sub-steps each bullet on its own, as finely as the limbs near its path move: k = the
  most that a limb near it needs for its ends to move no more than its radius per sub-step (at
  most max_substeps). The bullet moves linearly along its step's segment, the limbs linearly
  between the previous and the current pose, and sub-segment j is tested against the pose at
  (j + 1) / k, so a fast limb sweeping through a slow bullet is caught, while a limb flailing
  across the arena sub-steps only the bullets near it;
- `advance` bins limbs only into the grid cells a live bullet can reach during the step; given
  each character's box (`owner_boxes`), characters no bullet can reach are skipped before their
  limbs are read.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from crowd_ik.kernels.serial_loops import BOX, CELL, CHEAP, LIGHT, serial_for
from crowd_ik.prepared import prepared
from crowd_ik.runtime import ensure_init

MAX_GRID_CELLS = 256  # per axis: the serial prefix sum over at most 65,536 cells stays cheap
MARK_MARGIN = 0.01  # metres added around a bullet's path when marking the cells it can reach (float rounding)


class Hits(NamedTuple):
    """One step's hits, one row per character hit, sorted by character id."""

    chars: np.ndarray    # (H,) int32 character ids
    bullets: np.ndarray  # (H,) int32 winning bullet slots
    toi: np.ndarray      # (H,) float32 time of impact, fraction of the step in [0, 1]
    points: np.ndarray   # (H, 3) float32 bullet centre at impact, metres


class Threats(NamedTuple):
    """Per character, the approaching bullet that first passes within reach of its point (or none)."""

    bullet: np.ndarray     # (N,) int32 bullet slot, -1 when none
    time: np.ndarray       # (N,) float32 seconds to closest approach, -1 when none
    miss: np.ndarray       # (N,) float32 miss distance at closest approach, metres, -1 when none
    point: np.ndarray      # (N, 3) float32 bullet position at closest approach (0 when none)
    direction: np.ndarray  # (N, 3) float32 unit flight direction (0 when none)


def _is_ndarray(x) -> bool:
    from taichi.lang._ndarray import Ndarray

    return isinstance(x, Ndarray)


def _points(name: str, x, n: int | None = None):
    """(n, 3) float32 C-contiguous array (or a ti.ndarray passed through)."""
    if _is_ndarray(x):
        return x
    arr = np.ascontiguousarray(x, dtype=np.float32)
    if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and arr.shape[0] != n):
        want = f"({n}, 3)" if n is not None else "(n, 3)"
        raise ValueError(f"{name}: expected shape {want} (got {arr.shape})")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: expected finite values (got {arr[~np.isfinite(arr)][0]})")
    return arr


def _vector(name: str, x, n: int, dtype):
    if _is_ndarray(x):
        return x
    arr = np.ascontiguousarray(x, dtype=dtype)
    if arr.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},) (got {arr.shape})")
    return arr


def _length(x) -> int:
    return int(x.shape[0])


def _positive(name: str, value) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name}: expected a positive finite number (got {value!r})")
    return value


def _non_negative(name: str, value) -> float:
    value = float(value)
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"{name}: expected a non-negative finite number (got {value!r})")
    return value


class Grid:
    """A uniform grid on (x, z) listing segment ids per cell, rebuilt by `build` each step.

    bounds = (x_min, z_min, x_max, z_max) metres; cells are squares of `cell_size` metres, grown so
    that neither axis has more than MAX_GRID_CELLS. Anything outside the bounds clamps to the
    border cells (still correct, just slower there). `entries` starts at `capacity` slots and
    doubles when a build needs more (the only allocation after construction). `mask` (nx*nz,)
    marks the cells a masked build fills (see BulletPool.advance).
    """

    def __init__(self, bounds, cell_size: float, capacity: int):
        import taichi as ti

        x_min, z_min, x_max, z_max = (float(v) for v in bounds)
        if not (x_max > x_min and z_max > z_min) or not all(map(math.isfinite, (x_min, z_min, x_max, z_max))):
            raise ValueError(f"bounds: expected finite (x_min, z_min, x_max, z_max) with max > min (got {tuple(bounds)})")
        cell = max(_positive("cell_size", cell_size), (x_max - x_min) / MAX_GRID_CELLS, (z_max - z_min) / MAX_GRID_CELLS)
        self.origin = (x_min, z_min)
        self.cell = cell
        self.nx = max(1, min(MAX_GRID_CELLS, math.ceil((x_max - x_min) / cell)))
        self.nz = max(1, min(MAX_GRID_CELLS, math.ceil((z_max - z_min) / cell)))
        m = self.nx * self.nz
        self.cell_count = ti.ndarray(ti.i32, shape=(m,))
        self.cell_start = ti.ndarray(ti.i32, shape=(m + 1,))
        self.cursor = ti.ndarray(ti.i32, shape=(m,))
        self.mask = ti.ndarray(ti.i32, shape=(m,))
        self.total = np.zeros(1, np.int32)  # written by the kernel (host memory)
        self.entries = ti.ndarray(ti.i32, shape=(max(1, int(capacity)),))

    @property
    def geometry(self) -> tuple:
        """(ox, oz, cell, nx, nz): the scalar arguments the kernels take."""
        return (self.origin[0], self.origin[1], self.cell, self.nx, self.nz)

    def build(self, a0, b0, a1, b1, radius, pad: float, owner, owner_alive, masked: bool = False) -> int:
        """Bin segments (S, 3) x 4 (two poses), grown by radius (S,) + pad; only live owners; with
        masked=True only into the cells marked in `mask`. Returns entries used."""
        from crowd_ik.kernels import projectiles as kp

        args = (a0, b0, a1, b1, radius, pad, owner, owner_alive, *self.geometry, int(masked), self.mask,
                self.cell_count, self.cell_start, self.cursor, self.total)
        kp.build_grid(*args, self.entries)
        total = int(self.total[0])
        if self.grow(total):  # rare: bin again into the larger list
            kp.build_grid(*args, self.entries)
        return total

    def grow(self, total: int) -> bool:
        """Make room for `total` entries (at least doubling); False when they already fit."""
        import taichi as ti

        if total <= self.entries.shape[0]:
            return False
        self.entries = ti.ndarray(ti.i32, shape=(max(total, 2 * self.entries.shape[0]),))
        return True

    def pairs(self) -> np.ndarray:
        """(K, 2) int64 (cell, segment id) pairs sorted by cell then id: the grid's contents, for tests."""
        start = self.cell_start.to_numpy().astype(np.int64)
        total = int(start[-1])
        seg = self.entries.to_numpy()[:total].astype(np.int64)
        cell = np.repeat(np.arange(len(start) - 1), np.diff(start))
        pairs = np.stack([cell, seg], axis=1)
        return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


class BulletPool:
    """A fixed pool of `pool_size` bullet slots of one radius (metres), with its grids.

    bounds (x_min, z_min, x_max, z_max) and cell_size set the broad-phase grids: the bullets' threat
    grid, and the limbs' grid unless limb_cell_size says otherwise (the limbs' is best near a limb's
    length, the threats' near the spacing of the characters: a bullet's path over the threat horizon
    covers many cells); bullets farther than `far` metres from the origin die.
    """

    def __init__(self, pool_size: int, radius: float = 0.03, bounds=(-32.0, -32.0, 32.0, 32.0),
                 cell_size: float = 1.0, far: float = 1000.0, capsule_capacity: int = 4096,
                 limb_cell_size: float | None = None):
        import taichi as ti

        ensure_init()
        if isinstance(pool_size, bool) or not isinstance(pool_size, (int, np.integer)) or pool_size < 1:
            raise ValueError(f"pool_size: expected a positive integer (got {pool_size!r})")
        self.pool_size = int(pool_size)
        self.radius = _positive("radius", radius)
        self.far = _positive("far", far)
        P = self.pool_size
        vec3 = ti.math.vec3
        self.pos = ti.ndarray(vec3, shape=(P,))
        self.vel = ti.ndarray(vec3, shape=(P,))
        self.prev = ti.ndarray(vec3, shape=(P,))
        self.age = ti.ndarray(ti.f32, shape=(P,))
        self.alive = ti.ndarray(ti.i32, shape=(P,))
        self.bullet_char = ti.ndarray(ti.i32, shape=(P,))    # character struck on the last collide, -1
        self.bullet_key = ti.ndarray(ti.i64, shape=(P,))
        self.bullet_toi = np.zeros(P, np.float32)        # host memory, like the other per-hit results: the kernels
        self.bullet_point = np.zeros((P, 3), np.float32)  # write them in place, and Hits reads them without a launch
        self.bullet_char.fill(-1)
        limb_cell = cell_size if limb_cell_size is None else _positive("limb_cell_size", limb_cell_size)
        self.limb_grid = Grid(bounds, limb_cell, 4 * capsule_capacity)
        self.threat_grid = Grid(bounds, cell_size, 4 * P)
        self._n_chars = -1
        self._threat_out = None
        self.bullet_substeps = np.zeros(P, np.int32)  # (P,) each bullet's sub-steps on the last collide (host memory)
        self._spawn_in = None  # spawn_bullets' slots, origins and velocities, kept (grown when a spawn needs more)
        self.last_substeps = 0    # the most sub-steps a bullet took on the last collide/advance
        self.last_substepped = 0  # how many bullets took more than one
        self._no_boxes = np.zeros((1, 4), np.float32)  # owner boxes the hit kernels take when the grid lists capsules
        # slots [0, _used) have been alive at some time; spawn takes the lowest free slots, so this stays
        # near the largest number of bullets in flight at once, and the per-step kernels loop only over it
        self._used = 0

    # -- host views ---------------------------------------------------------------------------

    def positions(self) -> np.ndarray:
        """(P, 3) float32 positions of every slot (dead slots hold stale values; see alive_mask)."""
        return self.pos.to_numpy()

    def velocities(self) -> np.ndarray:
        """(P, 3) float32 velocities of every slot, m/s."""
        return self.vel.to_numpy()

    def alive_mask(self) -> np.ndarray:
        """(P,) bool: slots holding a live bullet."""
        return self.alive.to_numpy() != 0

    def count_alive(self) -> int:
        return int(np.count_nonzero(self.alive.to_numpy()))

    def export(self, pos: np.ndarray, vel: np.ndarray, alive: np.ndarray) -> None:
        """Copy every slot's position, velocity (P, 3) float32 and alive flag (P,) int32 into the
        caller's C-contiguous NumPy arrays, in one launch (what positions(), velocities() and
        alive_mask() give in three)."""
        from crowd_ik.kernels import projectiles as kp

        kp.export_bullets(self.pos, self.vel, self.alive, pos, vel, alive)

    def trails(self) -> tuple[np.ndarray, np.ndarray]:
        """(starts, ends), each (M, 3) float32: the live bullets' last segments prev -> pos, for drawing."""
        live = self.alive_mask()
        return self.prev.to_numpy()[live], self.pos.to_numpy()[live]

    def struck(self) -> np.ndarray:
        """(P,) int32: the character each bullet struck on the last collide/advance (winner or not), -1."""
        return self.bullet_char.to_numpy()

    def clear(self) -> None:
        """Kill every bullet."""
        self.alive.fill(0)

    def kill(self, slots) -> None:
        """Kill the bullets in `slots` (K,) ints (a hit decided outside the pool, e.g. on a shooter).

        One element write per slot from the host (~10 us each): meant for a few slots a step.
        """
        slots = np.asarray(slots, np.int64).reshape(-1)
        if slots.size and (slots.min() < 0 or slots.max() >= self.pool_size):
            bad = slots[(slots < 0) | (slots >= self.pool_size)][0]
            raise ValueError(f"slots: expected pool slots in [0, {self.pool_size}) (got {bad})")
        for s in np.unique(slots):
            self.alive[int(s)] = 0

    # -- phases -------------------------------------------------------------------------------

    def spawn(self, origins, velocities, free=None) -> tuple[np.ndarray, int]:
        """Start K bullets at origins (K, 3) m with velocities (K, 3) m/s in the lowest free slots.

        Returns (slots (K',) int32 used, in request order; dropped = K - K'): when fewer than K
        slots are free, the first K' requests get them and the rest are dropped. free: the free
        slots in ascending order when the caller keeps them (game.bullets.Bullets' host flags), so
        the pool need not read its alive flags back from the device; None reads them.
        """
        from crowd_ik.kernels import projectiles as kp

        origins = _points("origins", origins)
        velocities = _points("velocities", velocities, origins.shape[0])
        free = np.flatnonzero(self.alive.to_numpy() == 0) if free is None else np.asarray(free)
        n = min(len(free), origins.shape[0])
        slots = np.ascontiguousarray(free[:n], dtype=np.int32)
        if n:
            staged = self._spawn_in
            if staged is None or staged[0].shape[0] < n:  # kept, so that the launch stays bound (crowd_ik.prepared)
                k = max(n, 64 if staged is None else 2 * staged[0].shape[0])
                staged = self._spawn_in = (np.zeros(k, np.int32), np.zeros((k, 3), np.float32),
                                           np.zeros((k, 3), np.float32))
            staged[0][:n] = slots
            staged[1][:n] = origins[:n]
            staged[2][:n] = velocities[:n]
            prepared(kp.spawn_bullets)(*staged, self.pos, self.vel, self.age, self.alive, self.prev, n,
                                       serial_for(n))
            self._used = max(self._used, int(slots.max()) + 1)
        return slots, int(origins.shape[0] - n)

    def step(self, dt: float, gravity: float = 9.81, drag: float = 0.0, lifetime: float = 3.0) -> None:
        """Integrate every live bullet over dt seconds (gravity m/s^2 down, drag 1/m, lifetime s)."""
        from crowd_ik.kernels import projectiles as kp

        kp.integrate_bullets(self.pos, self.vel, self.age, self.alive, self.prev, _positive("dt", dt),
                             _non_negative("gravity", gravity), _non_negative("drag", drag),
                             _positive("lifetime", lifetime), self.far)

    def collide(self, capsules_a, capsules_b, radii, owner, char_alive, n_chars: int) -> Hits:
        """Hits of the live bullets' last segments on limbs in their end-of-step pose.

        capsules_a, capsules_b (C, 3) limb axis ends, metres; radii (C,) metres; owner (C,) character
        ids; char_alive (n_chars,) 0/1. Every bullet that struck a limb dies.
        """
        return self._run(None, capsules_a, capsules_b, capsules_a, capsules_b, radii, owner, char_alive, n_chars)

    def advance(self, dt: float, gravity: float, drag: float, lifetime: float, capsules_a, capsules_b, radii,
                owner, char_alive, n_chars: int, prev_a=None, prev_b=None, max_substeps: int = 16,
                owner_boxes=None, export_to=None, owner_stride: int = 0) -> Hits:
        """step + collide, each bullet sub-stepped as the limbs near it need (kernels.bullet_hits.collide_bullets).

        prev_a, prev_b (C, 3): the limbs at the previous step (None: the limbs did not move, k = 1).
        Sub-step j of k tests the limbs interpolated to (j + 1) / k of the way from prev to now; the
        most any bullet used is left in self.last_substeps, each bullet's in self.bullet_substeps, and
        how many used more than one in self.last_substepped. owner_boxes (n_chars, 4) float32, optional:
        x_min, z_min, x_max, z_max of each character's limbs in both poses grown by their radii;
        characters whose box no bullet can reach this step are left out, and the preparation is one
        launch (prepare_limbs); the bullets' step another (advance_bullets). export_to:
        (pos, vel, alive) host arrays to receive export() at the end of the step, or None. owner_stride
        S > 0 (with owner_boxes) says that owner[c] == c // S (each character's S capsules in one block,
        n_chars * S of them): the preparation then visits only the reachable characters' blocks.
        """
        args = (_positive("dt", dt), _non_negative("gravity", gravity), _non_negative("drag", drag),
                _positive("lifetime", lifetime))
        capsules_a = _points("capsules_a", capsules_a)
        if prev_a is None or prev_b is None:
            prev_a, prev_b = capsules_a, capsules_b
        return self._run(args, prev_a, prev_b, capsules_a, capsules_b, radii, owner, char_alive, n_chars,
                         max_substeps=max_substeps, owner_boxes=owner_boxes, export_to=export_to,
                         owner_stride=owner_stride)

    def threats(self, points, char_alive, horizon: float, reach: float) -> Threats:
        """Per character, the bullet that first passes within `reach` m of points (N, 3) within `horizon` s.

        Straight-line prediction (see kernels.projectiles.find_threats); the bullets are binned by
        their path over the horizon, so each character reads one grid cell.
        """
        from crowd_ik.kernels import projectiles as kp

        horizon = _positive("horizon", horizon)
        reach = _positive("reach", reach)
        points = _points("points", points)
        n = _length(points)
        char_alive = _vector("char_alive", char_alive, n, np.int32)
        if self._threat_out is None or self._threat_out[0].shape[0] != n:
            self._threat_out = (np.zeros(n, np.int32), np.zeros(n, np.float32), np.zeros(n, np.float32),
                                np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32))
            self._threat_in = (np.zeros((n, 3), np.float32), np.zeros(n, np.int32))
        if isinstance(points, np.ndarray) and isinstance(char_alive, np.ndarray):  # into buffers the launch keeps bound
            np.copyto(self._threat_in[0], points)
            np.copyto(self._threat_in[1], char_alive)
            points, char_alive = self._threat_in
        g = self.threat_grid
        serial = serial_for(n * CHEAP + self._used + g.nx * g.nz * CELL, 1.0)
        for _ in range(2):  # a second launch only when the grid's entry list had to grow
            prepared(kp.threat_pass)(points, char_alive, self.pos, self.vel, self.alive, horizon, reach, *g.geometry,
                                     g.cell_count, g.cell_start, g.cursor, g.total, g.entries, *self._threat_out,
                                     self._used, serial)
            if not g.grow(int(g.total[0])):
                break
        return Threats(*(o.copy() for o in self._threat_out))

    # -- internals ----------------------------------------------------------------------------

    def _prepare_limbs(self, dt, a0, b0, a1, b1, radii, owner, char_alive, owner_boxes, owner_stride) -> None:
        """One launch of prepare_limbs (again if the limb grid had to grow)."""
        from crowd_ik.kernels import projectiles as kp

        grid = self.limb_grid
        n_chars = _length(owner_boxes)
        by_capsule = 0 if owner_stride else _length(a0)  # stride 0: the limb loops visit every capsule
        serial = serial_for((n_chars + by_capsule) * CHEAP + self._used + grid.nx * grid.nz * CELL, 1.0)
        launch = prepared(kp.prepare_limbs)
        for _ in range(2):
            launch(self.pos, self.vel, self.alive, dt, self.radius + MARK_MARGIN, *grid.geometry, grid.mask,
                   owner_boxes, char_alive, self._reachable, a0, b0, a1, b1, radii, owner, self.hit_key,
                   self.hit_bullet, self.bullet_char, grid.cell_count, grid.cell_start, grid.cursor,
                   grid.total, grid.entries, self._used, owner_stride, serial)
            if not grid.grow(int(grid.total[0])):
                break

    def _characters(self, n_chars: int) -> None:
        import taichi as ti

        if n_chars != self._n_chars:
            self.hit_key = ti.ndarray(ti.i64, shape=(n_chars,))  # (N,) winning key, NO_HIT when none
            self.hit_bullet = np.zeros(n_chars, np.int32)        # (N,) winning bullet slot, -1 when none (host)
            self._reachable = ti.ndarray(ti.i32, shape=(n_chars,))  # (N,) live and within a bullet's reach
            self._n_chars = n_chars

    def _run(self, step_args, a0, b0, a1, b1, radii, owner, char_alive, n_chars, max_substeps=16,
             owner_boxes=None, export_to=None, owner_stride=0) -> Hits:
        from crowd_ik.kernels import projectiles as kp

        if isinstance(n_chars, bool) or not isinstance(n_chars, (int, np.integer)) or n_chars < 1:
            raise ValueError(f"n_chars: expected a positive integer (got {n_chars!r})")
        n_chars = int(n_chars)
        a1 = _points("capsules_a", a1)
        n_caps = _length(a1)
        b1 = _points("capsules_b", b1, n_caps)
        a0 = _points("prev_a", a0, n_caps)
        b0 = _points("prev_b", b0, n_caps)
        radii = _vector("radii", radii, n_caps, np.float32)
        owner = _vector("owner", owner, n_caps, np.int32)
        char_alive = _vector("char_alive", char_alive, n_chars, np.int32)
        if isinstance(radii, np.ndarray) and n_caps and not np.all(radii > 0):
            raise ValueError(f"radii: expected positive radii (got {radii[~(radii > 0)][0]})")
        if isinstance(owner, np.ndarray) and n_caps and (owner.min() < 0 or owner.max() >= n_chars):
            bad = owner[(owner < 0) | (owner >= n_chars)][0]
            raise ValueError(f"owner: expected character ids in [0, {n_chars}) (got {bad})")
        if isinstance(owner_stride, bool) or not isinstance(owner_stride, (int, np.integer)) or owner_stride < 0:
            raise ValueError(f"owner_stride: expected an integer >= 0 (got {owner_stride!r})")
        if owner_stride and n_caps != n_chars * owner_stride:
            raise ValueError(f"owner_stride: {n_chars} characters x {owner_stride} capsules != {n_caps} capsules")
        if owner_stride and isinstance(owner, np.ndarray) and not np.array_equal(owner,
                                                                                 np.arange(n_caps) // owner_stride):
            raise ValueError(f"owner_stride: owner[c] is not c // {owner_stride} for every capsule")
        if owner_boxes is not None and not _is_ndarray(owner_boxes):
            owner_boxes = np.ascontiguousarray(owner_boxes, dtype=np.float32)
            if owner_boxes.shape != (n_chars, 4) or not np.all(np.isfinite(owner_boxes)):
                raise ValueError(f"owner_boxes: expected finite values of shape ({n_chars}, 4) "
                                 f"(got {owner_boxes.shape})")
        if n_caps == 0:  # nothing to hit: bullets only fly
            a0 = b0 = a1 = b1 = np.zeros((1, 3), np.float32)
            radii = np.ones(1, np.float32)
            owner = np.zeros(1, np.int32)
            char_alive = np.zeros(n_chars, np.int32)
            owner_boxes = None
        max_substeps = int(max_substeps)
        if not 1 <= max_substeps <= kp.MAX_SUBSTEPS:
            raise ValueError(f"max_substeps: expected 1..{kp.MAX_SUBSTEPS} (got {max_substeps})")
        self._characters(n_chars)
        grid = self.limb_grid
        stride = 0  # the limb grid lists capsules; with stride > 0 owners (prepare_limbs)
        if step_args is not None and owner_boxes is not None:
            stride = int(owner_stride) if n_caps else 0
            self._prepare_limbs(step_args[0], a0, b0, a1, b1, radii, owner, char_alive, owner_boxes, stride)
            char_alive = self._reachable
        else:
            owner_boxes = self._no_boxes
            if step_args is not None:  # only the cells the bullets can reach this step take limbs
                kp.mark_bullet_cells(self.pos, self.vel, self.alive, step_args[0], self.radius + MARK_MARGIN,
                                     *grid.geometry, grid.mask)
            grid.build(a0, b0, a1, b1, radii, 0.0, owner, char_alive, masked=step_args is not None)
            kp.reset_hits(self.hit_key, self.hit_bullet, self.bullet_char)
        hits_in = (self.radius, a0, b0, a1, b1, radii, owner, char_alive, *grid.geometry, grid.cell_start, grid.entries,
                   stride, owner_boxes, max_substeps, self.hit_key, self.bullet_key, self.bullet_char, self.bullet_toi,
                   self.bullet_point, self.bullet_substeps)
        if step_args is not None:  # integrate + collide, apply (+ export): one launch
            out = (self.pos, self.vel, self.alive) if export_to is None else export_to
            # its work: each bullet's step, and each limb-grid entry (a character's capsules, or one capsule) tested
            # against the bullets in its cell (a full pool among 10,000 characters: ~11,000 entries, 2.2 ms on one
            # thread, 1.7 on two)
            work = self._used * LIGHT + int(grid.total[0]) * (BOX if stride else CHEAP)
            prepared(kp.advance_bullets)(self.pos, self.vel, self.age, self.alive, self.prev, *step_args, self.far,
                                         *hits_in, self.hit_bullet, int(export_to is not None), *out, self._used,
                                         serial_for(work, 1.0))
        else:
            kp.collide_bullets(self.prev, self.pos, self.alive, *hits_in)
            kp.apply_hits(self.alive, self.bullet_char, self.bullet_key, self.hit_key, self.hit_bullet)
            if export_to is not None:
                self.export(*export_to)
        used = self.bullet_substeps[:self._used] if step_args is not None else self.bullet_substeps
        self.last_substeps = int(used.max()) if len(used) else 0
        self.last_substepped = int(np.count_nonzero(used > 1))
        chars = np.flatnonzero(self.hit_bullet >= 0).astype(np.int32)
        bullets = self.hit_bullet[chars]
        if len(chars) == 0:
            return Hits(chars, bullets, np.zeros(0, np.float32), np.zeros((0, 3), np.float32))
        return Hits(chars, bullets, self.bullet_toi[bullets], self.bullet_point[bullets])
