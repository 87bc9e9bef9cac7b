"""CrowdMotion: where the bystanders' pelvises go - wandering, keeping apart, fleeing bullets.

Each standing bystander walks toward a goal at its own preferred speed (characters.walk_speed times
a factor in WALK_FACTOR, from the counter hash), slows down near it, pauses there (PAUSE seconds)
and draws the next goal within WANDER_RADIUS of where it stands, inside the region (the layout's
box grown by one spacing). A bystander a bullet threatens flees for FLEE_TIME seconds at FLEE_SPEED:
sideways out of the line of fire and away from the shooter (`flee`), then wanders on.

Keeping apart (nobody walks through anybody): every step one `separate` launch
(kernels/gait_kernels.py) over the walkers and the obstacles (the player and the standing
shooters, who are never moved) on a uniform ground grid gives (1) a steering push away from
everybody within SEPARATION_REACH, added to the next step's desired velocity, and (2) the
displacement that resolves overlaps of the bodies' discs (BODY_RADIUS, PLAYER_RADIUS), applied at
once. The velocity follows the desired one with the time constant TAU_VELOCITY. Vectorised NumPy
plus one launch a step; no Python loop over characters. Deterministic: the grid's order is a
stable sort and each walker sums its neighbours in that order on one thread.
"""

from __future__ import annotations

import math

import numpy as np

from crowd_ik.game import streams
from crowd_ik.kernels.serial_loops import serial_for
from crowd_ik.prepared import prepared

WALK_FACTOR = (0.7, 1.3)  # each bystander's preferred speed is walk_speed times a factor in this range
WANDER_RADIUS = 3.0  # m (times the scale): the next goal lies within this distance
ARRIVE = 0.25  # m (times the scale): a goal this close is reached
SLOW_RADIUS = 0.8  # m (times the scale): bystanders slow down within this distance of their goal
PAUSE = (0.4, 2.5)  # s: how long a bystander stands at a goal (uniform)
FIRST_PAUSE = 1.2  # s: bystanders start walking within this time (uniform)
FLEE_TIME = 1.2  # s: a threatened bystander flees this long
FLEE_SPEED = 1.8  # m/s (times the scale)
FLEE_AWAY = 0.5  # weight of "away from the shooter" against "out of the line of fire"
BODY_RADIUS = 0.28  # m (times the scale): two bystanders' roots stay 2 x this apart
PLAYER_RADIUS = 0.36  # m (times the scale): the player's and the shooters' disc
SEPARATION_REACH = 1.1  # m (times the scale): neighbours closer than this steer a walker away
SEPARATION_GAIN = 0.9  # m/s of steering per unit of separation push
TAU_VELOCITY = 0.3  # s: the velocity follows the desired velocity with this time constant
MAX_SPEED = 2.5  # m/s (times the scale)
TURN_RATE = 6.0  # 1/s: heading follows the walking direction with this rate
TURN_SPEED = 0.15  # m/s: below this speed the heading is kept


class CrowdMotion:
    """Pelvis positions (N, 2) (x, z), velocities (N, 2) and headings (N,) of N wandering bystanders."""

    def __init__(self, ground: np.ndarray, yaw: np.ndarray, scene):
        c = scene.characters
        self.n = n = len(ground)
        self.seed = scene.seed
        self.scale = s = c.scale
        self.enabled = c.walk_speed > 0.0
        self.pos = np.asarray(ground, np.float64)[:, [0, 2]].copy()
        self.vel = np.zeros((n, 2))
        self.yaw = np.asarray(yaw, np.float64).copy()
        lo, hi = self.pos.min(axis=0) - c.spacing, self.pos.max(axis=0) + c.spacing
        self.region = (lo, hi)
        idx = self.idx = np.arange(n)
        u = streams.rand(self.seed, streams.WANDER, idx, 0)
        self.speed = c.walk_speed * (WALK_FACTOR[0] + (WALK_FACTOR[1] - WALK_FACTOR[0]) * u)
        self.goals_drawn = np.zeros(n, np.int64)
        self.goal = self.pos.copy()
        self.paused = np.ones(n, bool)
        self.wait = FIRST_PAUSE * streams.rand(self.seed, streams.WANDER, idx, 1).astype(np.float64)
        self.flee_dir = np.zeros((n, 2))
        self.flee_time = np.zeros(n)
        self.steer = np.zeros((n, 2))
        self.radius = np.full(n, BODY_RADIUS * s, np.float32)
        self._sep_sizes = None  # separate's kept input and output buffers, for these (bodies, grid cells + 1)
        self._sep_bufs = ()

    @property
    def walking_speed(self) -> np.ndarray:
        return np.linalg.norm(self.vel, axis=1)

    def _new_goals(self, i: np.ndarray) -> None:
        k = self.goals_drawn[i]
        a = 2.0 * math.pi * streams.rand(self.seed, streams.WANDER, i, 2 * k + 2)
        r = WANDER_RADIUS * self.scale * np.sqrt(streams.rand(self.seed, streams.WANDER, i, 2 * k + 3))
        goal = self.pos[i] + np.stack([np.cos(a) * r, np.sin(a) * r], axis=1)
        self.goal[i] = np.clip(goal, *self.region)
        self.goals_drawn[i] += 1

    def flee(self, i: np.ndarray, side: np.ndarray, bullet_dir: np.ndarray) -> None:
        """Bystanders i flee: side (K, 3) out of the line of fire, bullet_dir (K, 3) the bullet's way."""
        if not self.enabled or i.size == 0:
            return
        d = side[:, [0, 2]] + FLEE_AWAY * bullet_dir[:, [0, 2]]
        n = np.linalg.norm(d, axis=1, keepdims=True)
        self.flee_dir[i] = np.where(n > 1e-9, d / np.maximum(n, 1e-9), 0.0)
        self.flee_time[i] = FLEE_TIME

    def step(self, dt: float, alive: np.ndarray, obstacles: np.ndarray) -> None:
        """Advance dt s: alive (N,) bool; obstacles (K, 2) (x, z) of the player and the standing shooters."""
        if not self.enabled:
            return
        s = self.scale
        # wander: arrive, pause, draw the next goal
        self.wait -= dt
        to_goal = self.goal - self.pos
        dist = np.linalg.norm(to_goal, axis=1)
        arrived = alive & ~self.paused & (dist < ARRIVE * s)
        if arrived.any():
            i = np.flatnonzero(arrived)
            self.paused[i] = True
            u = streams.rand(self.seed, streams.WANDER, i, 2 * self.goals_drawn[i] + 1)
            self.wait[i] = PAUSE[0] + (PAUSE[1] - PAUSE[0]) * u
        resume = alive & self.paused & (self.wait <= 0.0)
        if resume.any():
            i = np.flatnonzero(resume)
            self.paused[i] = False
            self._new_goals(i)
            to_goal[i] = self.goal[i] - self.pos[i]
            dist[i] = np.linalg.norm(to_goal[i], axis=1)
        want = to_goal / np.maximum(dist, 1e-9)[:, None] * (self.speed * np.minimum(1.0, dist / (SLOW_RADIUS * s)))[:, None]
        want[self.paused] = 0.0
        fleeing = self.flee_time > 0.0
        want[fleeing] = self.flee_dir[fleeing] * FLEE_SPEED * s
        self.flee_time -= dt
        want += SEPARATION_GAIN * self.steer
        speed = np.linalg.norm(want, axis=1, keepdims=True)
        want *= np.minimum(1.0, MAX_SPEED * s / np.maximum(speed, 1e-9))
        want[~alive] = 0.0
        self.vel += (want - self.vel) * (1.0 - math.exp(-dt / TAU_VELOCITY))
        self.vel[~alive] = 0.0
        self.pos += self.vel * dt
        self._separate(alive, obstacles)
        np.clip(self.pos, *self.region, out=self.pos)
        # heading follows the walking direction
        sp = np.linalg.norm(self.vel, axis=1)
        turn = (np.arctan2(self.vel[:, 0], self.vel[:, 1]) - self.yaw + math.pi) % (2.0 * math.pi) - math.pi
        self.yaw += np.where(sp > TURN_SPEED * s, turn, 0.0) * (1.0 - math.exp(-TURN_RATE * dt))

    def _separate(self, alive: np.ndarray, obstacles: np.ndarray) -> None:
        """One `separate` launch on a ground grid over walkers and obstacles (module docstring)."""
        from crowd_ik.kernels import gait_kernels as gk

        s = self.scale
        obstacles = np.asarray(obstacles, np.float64).reshape(-1, 2)
        pts = np.ascontiguousarray(np.concatenate([self.pos, obstacles]), np.float32)
        radius = np.concatenate([self.radius, np.full(len(obstacles), PLAYER_RADIUS * s, np.float32)])
        kind = np.concatenate([alive.astype(np.int32), np.full(len(obstacles), 2, np.int32)])
        reach = SEPARATION_REACH * s
        cell = max(reach, 2.0 * PLAYER_RADIUS * s)
        lo = pts.min(axis=0)
        span = float((pts.max(axis=0) - lo).max())
        cell = max(cell, span / math.sqrt(4.0 * len(pts) + 64.0))  # at most ~4 cells per body (a sparse, wide world)
        cells = np.maximum(np.floor((pts.max(axis=0) - lo) / cell).astype(np.int64) + 1, 1)
        cx = np.clip(np.floor((pts[:, 0] - lo[0]) / cell).astype(np.int64), 0, cells[0] - 1)
        cz = np.clip(np.floor((pts[:, 1] - lo[1]) / cell).astype(np.int64), 0, cells[1] - 1)
        key = cx * cells[1] + cz
        order = np.argsort(key, kind="stable").astype(np.int32)
        start = np.zeros(int(cells[0] * cells[1]) + 1, np.int32)
        np.cumsum(np.bincount(key, minlength=int(cells[0] * cells[1])), out=start[1:])
        # into buffers kept while the sizes stay (they change when a shooter falls or the grid grows), so that
        # the launch stays bound (crowd_ik.prepared)
        sizes = (len(pts), len(start))
        if self._sep_sizes != sizes:
            self._sep_sizes = sizes
            self._sep_bufs = (np.zeros_like(pts), np.zeros_like(radius), np.zeros_like(kind), np.zeros_like(order),
                              np.zeros_like(start), np.zeros_like(pts), np.zeros_like(pts))
        args = self._sep_bufs
        for buf, value in zip(args, (pts, radius, kind, order, start)):
            np.copyto(buf, value)
        steer, push = args[5:]
        prepared(gk.separate)(*args[:5], float(lo[0]), float(lo[1]), float(cell), int(cells[0]), int(cells[1]),
                              float(reach), steer, push, serial_for(len(pts)))
        n = self.n
        self.steer = steer[:n].astype(np.float64)
        self.pos += push[:n]
