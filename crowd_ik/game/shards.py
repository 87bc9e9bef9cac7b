"""Shards: what is left of a character (or shooter) a bullet hits - pieces that fly, fall, bounce and fade.

Each bone breaks into SHARD_PIECES capsules, pushed by the bullet (more near the impact) and
bursting outward from it, spinning; they fall under gravity, bounce on the ground with
restitution and friction, and shrink away over the last SHARD_FADE seconds of SHARD_LIFE. The
pieces live in a ring of slots sized for MAX_SHATTERED bodies of each kind; the oldest are reused.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.game import streams
from crowd_ik.game.cross import cross
from crowd_ik.geometry.vectors import UP, normalize

SHARD_PIECES = 2
SHARD_LIFE = 3.0  # s of world time
SHARD_FADE = 1.0  # s: shards shrink away over the last second of their life
SHARD_RESTITUTION = 0.35
SHARD_FRICTION = 0.7  # horizontal speed kept at a bounce
SHARD_IMPULSE = 0.1  # fraction of the bullet's velocity given to the pieces next to the impact
SHARD_BURST = 1.6  # m/s: outward speed from the impact point
SHARD_TINT = np.array([0.55, 0.62, 1.0], np.float32)  # multiplies the body's colour
MAX_SHATTERED = 256  # the ring holds this many characters' (and shooters') pieces, oldest reused first


class Shards:
    """A ring of `capacity` shard capsules (centre, half-axis, radius, velocity, spin, age, colour)."""

    def __init__(self, capacity: int, seed: int, gravity: float):
        M = self.capacity = capacity
        self.seed = seed
        self.gravity = gravity
        self.c = np.zeros((M, 3), np.float32)
        self.c_prev = np.zeros((M, 3), np.float32)
        self.h = np.zeros((M, 3), np.float32)
        self.v = np.zeros((M, 3), np.float32)
        self.w = np.zeros((M, 3), np.float32)
        self.r = np.zeros(M, np.float32)
        self.age = np.zeros(M, np.float32)
        self.live = np.zeros(M, bool)
        self.color = np.zeros((M, 3), np.float32)
        self._next = 0
        self._serial = 0

    @staticmethod
    def capacity_for(bodies) -> int:
        """Slots for MAX_SHATTERED bodies of each (body, count) pair."""
        return SHARD_PIECES * sum(body.n_bones * min(count, MAX_SHATTERED) for body, count in bodies)

    def begin_step(self) -> None:
        np.copyto(self.c_prev, self.c)

    def shatter(self, body, joints: np.ndarray, colors: np.ndarray, bullet_vel: np.ndarray,
                impact: np.ndarray) -> None:
        """Break H bodies of `body`'s rig, posed at joints (H, J, 3) and coloured colors (H, 3) BGR,
        into shards, pushed by their bullets' velocities (H, 3) and bursting from the impacts (H, 3)."""
        b = body
        P = joints  # (H, J, 3)
        a, e = P[:, b.bone_parent], P[:, 1:]  # (H, B, 3)
        f = np.linspace(0.0, 1.0, SHARD_PIECES + 1, dtype=np.float32)
        starts = a[:, :, None] + (e - a)[:, :, None] * f[None, None, :-1, None]
        ends = a[:, :, None] + (e - a)[:, :, None] * f[None, None, 1:, None]
        H, K = len(P), SHARD_PIECES * b.n_bones
        c = ((starts + ends) * 0.5).reshape(H, K, 3)
        h = ((ends - starts) * 0.5).reshape(H, K, 3)
        r = np.repeat(b.bone_radius * 0.9, SHARD_PIECES)[None].repeat(H, 0)
        serial = self._serial + np.arange(H * K).reshape(H, K)
        self._serial += H * K
        u = [streams.rand(self.seed, streams.SHARD, serial, j) for j in range(6)]
        off = c - impact[:, None, :]
        dist = np.linalg.norm(off, axis=-1)
        radial = normalize(off + 0.05 * (np.stack(u[3:6], -1) - 0.5))
        push = bullet_vel[:, None, :] * (SHARD_IMPULSE * np.exp(-dist / (0.4 * b.scale)))[..., None]
        v = push + radial * (SHARD_BURST * (0.4 + u[0]))[..., None] + UP * (0.8 + 1.5 * u[1])[..., None]
        w = (np.stack(u[2:5], -1) - 0.5) * 18.0
        M = self.capacity
        slots = (self._next + np.arange(H * K)) % M
        self._next = int((self._next + H * K) % M)
        self.c[slots] = c.reshape(-1, 3)
        self.c_prev[slots] = c.reshape(-1, 3)
        self.h[slots] = h.reshape(-1, 3)
        self.v[slots] = v.reshape(-1, 3)
        self.w[slots] = w.reshape(-1, 3)
        self.r[slots] = r.reshape(-1)
        self.age[slots] = 0.0
        self.live[slots] = True
        self.color[slots] = np.repeat(colors * SHARD_TINT, K, axis=0)

    def step(self, dt: float) -> None:
        live = self.live
        if not live.any():
            return
        i = np.flatnonzero(live)
        v, c, h, w = self.v[i], self.c[i], self.h[i], self.w[i]
        v[:, 1] -= self.gravity * dt
        c += v * dt
        # rotate the half-axis by w dt (Rodrigues)
        ang = np.linalg.norm(w, axis=1) * dt
        k = normalize(w)
        cos, sin = np.cos(ang)[:, None], np.sin(ang)[:, None]
        h = h * cos + cross(k, h) * sin + k * np.einsum("ij,ij->i", k, h)[:, None] * (1.0 - cos)
        low = c[:, 1] - np.abs(h[:, 1]) - self.r[i]
        ground = low < 0.0
        c[ground, 1] -= low[ground]
        bounce = ground & (v[:, 1] < 0.0)
        v[bounce, 1] *= -SHARD_RESTITUTION
        v[bounce, 0] *= SHARD_FRICTION
        v[bounce, 2] *= SHARD_FRICTION
        w[bounce] *= 0.6
        self.v[i], self.c[i], self.h[i], self.w[i] = v, c, h.astype(np.float32), w
        self.age[i] += dt
        self.live[i] = self.age[i] < SHARD_LIFE

    def capsules(self, alpha) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """(a, b, radius, color) of the live shards, centres interpolated by alpha between the last
        two steps, radii shrinking over the fade; None when there are none."""
        sh = np.flatnonzero(self.live)
        if not sh.size:
            return None
        c = self.c_prev[sh] + (self.c[sh] - self.c_prev[sh]) * alpha
        h = self.h[sh]
        fade = np.clip((SHARD_LIFE - self.age[sh]) / SHARD_FADE, 0.0, 1.0)
        return c - h, c + h, self.r[sh] * fade, self.color[sh]
