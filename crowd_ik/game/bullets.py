"""Bullets: the one owner of the game's bullets - every slot, its team, and every hit.

The device pool (game.pool.BulletPool) moves bullets and finds their hits on the characters'
limbs; this class owns what the game knows about each slot besides: a serial number (a slot is
reused), where it was fired from (for trails), whose it is (the player's bullets also hit
shooters), and the host mirror of positions, velocities and alive flags exported once per step.

Hit rules (DESIGN "Game rules"): every bullet hits characters (pool rules: swept, sub-stepped,
one winner per character per step, a struck bullet dies). Then the player's live bullets are
tested against the standing shooters: each bullet's segment of this step (previous -> current
position, a chord of its arc) is swept against the shooters' limb capsules in their end-of-step
pose (analytic, crowd_ik.geometry.sweep.sweep_toi; no sub-steps: shooters only turn and move an
arm); each bullet's earliest hit counts (ties to the lower capsule id), the bullet dies there, and
a shooter hit by several bullets in one step is downed once, by the earliest (toi, slot). A
shooter's own bullets start in its hand among its own limbs, so only the player's are tested;
a bullet a character stopped this step is gone before this test.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.game.pool import BulletPool
from crowd_ik.geometry.sweep import sweep_toi


# Cells of the limbs' grid, metres. The game's grid lists characters by their boxes (BulletPool owner_stride), a
# metre or so across: finer cells put each character in more of them (more atomics to build it), coarser ones give a
# bullet more characters to box-test. 10,000 humanoids, 4096 bullets (bench game workload, stop 39, 2-core Xeon):
# bullets' step median 3.77-3.87 ms at 0.5 m, 3.57 at 0.75, 3.39-3.45 at 1.0, 3.36 at 1.5, 3.43 at 2.0 (prepare_limbs
# 1.34 -> 0.73-0.78 ms from 0.5 to 1 m, advance_bullets 1.8-1.9 ms throughout). When limbs were binned one by one
# (until stop 38), 0.5 m was best: 9.2 ms against 12.7 at 1 m.
LIMB_CELL = 1.0


class Bullets:
    """The pool and everything the game knows per slot; `spawn`, `advance`, `player_hits`."""

    def __init__(self, scene, extent: float, capsule_capacity: int):
        bounds = (-extent, -extent, extent, extent)
        cell = max(1.0, 1.2 * scene.characters.spacing)
        self.settings = bl = scene.bullets
        self.pool = BulletPool(bl.pool_size, bl.radius, bounds=bounds, cell_size=cell,
                               far=4.0 * extent + 50.0, capsule_capacity=capsule_capacity, limb_cell_size=LIMB_CELL)
        P = bl.pool_size
        self.serial = np.full(P, -1, np.int64)
        self.origin = np.zeros((P, 3), np.float32)
        self.pos = np.zeros((P, 3), np.float32)
        self.pos_prev = np.zeros((P, 3), np.float32)
        self.vel = np.zeros((P, 3), np.float32)
        self.alive = np.zeros(P, bool)
        self._alive_i32 = np.zeros(P, np.int32)  # the pool's alive flags, exported each step
        # slots holding the player's live bullets: only these hit shooters; cleared when the bullet
        # dies or the slot is reused
        self.players = np.zeros(P, bool)
        self._next_serial = 0
        self._alive_chars = None

    def begin_step(self) -> None:
        """This step's positions become the previous ones (for drawing between steps and for sweeps)."""
        np.copyto(self.pos_prev, self.pos)

    def spawn(self, origins: np.ndarray, velocities: np.ndarray, player: bool = False) -> np.ndarray:
        """Bullets into the pool's lowest free slots; player=True marks them as the player's."""
        slots, _dropped = self.pool.spawn(origins, velocities, free=np.flatnonzero(~self.alive))
        n = len(slots)
        self.players[slots] = bool(player)
        self.serial[slots] = self._next_serial + np.arange(n)
        self._next_serial += n
        self.origin[slots] = origins[:n]
        self.pos[slots] = origins[:n]
        self.pos_prev[slots] = origins[:n]
        self.vel[slots] = velocities[:n]
        self.alive[slots] = True
        return slots

    def advance(self, dt: float, characters):
        """Move every bullet one step against the characters' limbs; returns the pool's Hits."""
        bl = self.settings
        limbs = characters.limbs
        a, b = limbs.current
        prev_a, prev_b = limbs.previous
        hits = self.pool.advance(dt, bl.gravity, bl.drag, bl.lifetime, a, b, limbs.radius, limbs.owner,
                                 self._char_alive(characters.alive), characters.n, prev_a=prev_a, prev_b=prev_b,
                                 owner_boxes=limbs.owner_box, export_to=(self.pos, self.vel, self._alive_i32),
                                 owner_stride=characters.body.n_bones)
        np.not_equal(self._alive_i32, 0, out=self.alive)
        return hits

    def _char_alive(self, alive: np.ndarray) -> np.ndarray:
        """The characters' alive flags as int32, in a buffer kept from step to step (the pool's launches stay bound)."""
        if self._alive_chars is None or self._alive_chars.shape != alive.shape:
            self._alive_chars = np.zeros(alive.shape, np.int32)
        np.copyto(self._alive_chars, alive)
        return self._alive_chars

    def player_hits(self, shooters):
        """The player's live bullets against the standing shooters (module docstring), after `advance`.

        Returns (down (H,) shooter indices, impact points (H, 3), the winning bullets' velocities (H, 3)),
        or None. Free when the player has no live bullet (one `any` over the flags).
        """
        mine = self.players
        if not mine.any():
            return None
        mine &= self.alive  # flags of bullets that died (a character hit, lifetime, far) are dropped
        if not mine.any() or not shooters.alive.any():
            return None
        hb = shooters.body
        slots = np.flatnonzero(mine)  # (K,) ascending
        standing = np.flatnonzero(shooters.alive)  # (S',)
        SJ = shooters.joints[standing]  # (S', J, 3) end-of-step pose
        a = SJ[:, hb.bone_parent].reshape(-1, 3)  # (C, 3), C = S' * B, capsule c is bone c % B of standing[c // B]
        b = SJ[:, 1:].reshape(-1, 3)
        r = np.tile(hb.bone_radius, len(standing)) + np.float32(self.settings.radius)
        p0, p1 = self.pos_prev[slots], self.pos[slots]
        toi = sweep_toi(p0[:, None], p1[:, None], a[None], b[None], r[None])  # (K, C), -1: no hit
        toi = np.where(toi >= 0.0, toi, np.inf)
        first = np.argmin(toi, axis=1)  # the lowest capsule id among equal times
        t = toi[np.arange(len(slots)), first]
        hit = np.isfinite(t)
        if not hit.any():
            return None
        slots, first, t = slots[hit], first[hit], t[hit]
        shooter = standing[first // hb.n_bones]
        self.pool.kill(slots)
        self.alive[slots] = False
        self._alive_i32[slots] = 0
        mine[slots] = False
        order = np.lexsort((slots, t))  # per shooter the earliest (toi, slot) bullet shatters it
        down, firsts = np.unique(shooter[order], return_index=True)
        win = order[firsts]
        impact = (p0[hit][win] + (p1[hit][win] - p0[hit][win]) * t[win, None]).astype(np.float32)
        return down, impact, self.vel[slots[win]]

    def live(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (K, 3), velocities (K, 3)) copies of the live bullets."""
        return self.pos[self.alive].copy(), self.vel[self.alive].copy()
