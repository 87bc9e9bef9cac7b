"""Autopilot: the player when nobody holds the controls (headless renders), so that the video has action.

It walks `player.path` at the player's speed, in a loop when the path is closed (its last point is
its first) and turning back at its ends otherwise (one waypoint: a small square around it), and
stops STOP_TIME seconds at every waypoint, so that it never stands still for more than half a
second and time moves in bursts. Meanwhile it aims at the nearest standing shooter whose line of
fire no standing bystander blocks (else at the nearest one) and, once it has held that aim for
AIM_HOLD seconds with the line clear, fires, at most every FIRE_INTERVAL seconds (with jitter from
the counter hash). Its output each video frame is what a hand on the controls would give:
(move (x, z) in [-1, 1], aim point or None, fire), applied through World.set_player_input's path
(Player.steer, then the same shot), so that the player's pose comes from IK as in live play.
Real (video) time, like the player's walk.
"""

from __future__ import annotations


import numpy as np

from crowd_ik.game import streams

STOP_TIME = 0.35  # s: the player stops this long at every waypoint (time slows, never below ~0.3x)
LONE_SQUARE = 1.0  # m: side of the square walked around a path of one point
AIM_HOLD = 0.3  # s: the aim is held this long on the same shooter before a shot
FIRE_INTERVAL = (2.4, 3.4)  # s between shots (uniform): the shooters keep up the fire for most of the video
FIRST_SHOT = 1.5  # s: no shot before this
CLEAR_WIDTH = 0.45  # m: a bystander whose root is this close to the line of fire blocks it
CLEAR_MARGIN = 0.01  # m: _pick tests exactly only the bystanders within CLEAR_WIDTH + this of a line


class Autopilot:
    """Steering of the player along the scene's path, with aims and shots (module docstring)."""

    def __init__(self, scene, body):
        pts = np.asarray(scene.player.path, np.float64).reshape(-1, 2)
        keep = [pts[0]]
        for p in pts[1:]:
            if np.linalg.norm(p - keep[-1]) > 1e-6:
                keep.append(p)
        self.closed = len(keep) > 2 and np.linalg.norm(keep[-1] - keep[0]) < 1e-3
        if self.closed:
            keep = keep[:-1]
        if len(keep) == 1:
            c, a = keep[0], LONE_SQUARE * body.scale
            keep = [c, c + (a, 0.0), c + (a, a), c + (0.0, a)]
            self.closed = True
        self.route = np.asarray(keep)
        self.body = body
        self.seed = scene.seed
        self.speed = scene.player.speed
        self.next = 1
        self.direction = 1
        self.stop_left = 0.0
        self.clock = 0.0
        self.next_shot = FIRST_SHOT
        self.target = -1
        self.held = 0.0
        self.shots = 0

    def _advance(self) -> None:
        n = len(self.route)
        if self.closed:
            self.next = (self.next + 1) % n
            return
        if not 0 <= self.next + self.direction < n:
            self.direction = -self.direction
        self.next += self.direction

    def _move(self, dt: float, here: np.ndarray) -> np.ndarray:
        if self.stop_left > 0.0:
            self.stop_left -= dt
            return np.zeros(2)
        to = self.route[self.next] - here
        dist = float(np.hypot(*to))
        step = self.speed * dt
        if dist <= step:
            self.stop_left = STOP_TIME
            self._advance()
            return to / max(step, 1e-12)
        return to / dist

    def _pick(self, here: np.ndarray, shooters, characters) -> tuple[int, bool]:
        """(shooter, line clear) to aim at: the nearest standing shooter with a clear line, else the nearest."""
        up = np.flatnonzero(shooters.alive)
        if up.size == 0:
            return -1, False
        ends = shooters.ground[up][:, [0, 2]].astype(np.float64)  # (S', 2)
        seg = ends - here
        length2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-12)
        alive = np.flatnonzero(characters.alive)
        clear = np.ones(up.size, bool)
        if alive.size:
            p = characters.ground[alive][:, [0, 2]].astype(np.float64) - here  # (N', 2)
            t = (p @ seg.T) / length2  # (N', S')
            width = CLEAR_WIDTH * self.body.scale
            # candidates: pairs whose distance to the line (|p x seg| / |seg|, the distance to the segment where
            # 0 < t < 1) is below the width plus a margin far above rounding; only they can be near, and for them
            # `near` is computed exactly as over every pair
            cross = p[:, :1] * seg[:, 1] - p[:, 1:] * seg[:, 0]
            n, s = np.nonzero((cross * cross < (width + CLEAR_MARGIN) ** 2 * length2) & (t > 0.0) & (t < 1.0))
            closest = t[n, s][:, None] * seg[s] - p[n]
            near = np.linalg.norm(closest, axis=1) < width
            clear[s[near]] = False
        order = np.argsort(length2, kind="stable")
        best = order[clear[order]]
        k = best[0] if best.size else order[0]
        return int(up[k]), bool(clear[k])

    def update(self, dt: float, player, shooters, characters):
        """(move (2,), aim (3,) or None, fire) for the next dt s of real time."""
        self.clock += dt
        here = player.position()[[0, 2]]
        move = self._move(dt, here)
        k, clear = self._pick(here, shooters, characters)
        if k < 0:
            self.target = -1
            return move, None, False
        self.held = self.held + dt if k == self.target else 0.0
        self.target = k
        aim = shooters.joints[k, shooters.body.chest].astype(np.float64)
        fire = clear and self.held >= AIM_HOLD and self.clock >= self.next_shot
        if fire:
            u = float(streams.rand(self.seed, streams.AUTOPILOT, 0, self.shots))
            self.next_shot = self.clock + FIRE_INTERVAL[0] + (FIRE_INTERVAL[1] - FIRE_INTERVAL[0]) * u
            self.shots += 1
        n = float(np.hypot(*move))
        return (move / n if n > 1.0 else move), aim, fire


__all__ = ["Autopilot", "STOP_TIME"]
