"""Characters: the crowd that dodges - its Crowd, who is standing, and each one's dodge.

Each world step (DESIGN "Game rules"): every standing character asks the bullets for the first
one that will pass within THREAT_REACH of its chest within THREAT_HORIZON seconds and, once that
is within its own reflex time, dodges it: a lean away from the bullet's line, a duck under
head-high bullets (for those who prefer it) and a hand guard. The dodge is low-passed (fast while
it grows, slow while it relaxes), moves the pelvis and becomes IK targets for head and hands while
the feet stay planted (one kernel, `game_kernels.dodge_targets`), then one batched solve. A dodge
is counted when a tracked bullet goes past the chest (or stops past it) without hitting.

Characters walk (`walk`, before the solve): humanoid bystanders wander, keep apart and flee the
bullets that threaten them (game.crowd_motion), and their feet step along (game.gait): the stance
targets follow the walking pelvis, the dodge is added on top, and after the solve both legs are
set analytically onto the footprints, so that planted feet do not move at all. With
characters.walk_speed = 0 (or a chain rig) they stand where the layout put them and only dodge.
"""

from __future__ import annotations

import time

import numpy as np

from crowd_ik.game import streams
from crowd_ik.game.arm_poles import ArmPoles
from crowd_ik.game.body import Body
from crowd_ik.game.cross import cross
from crowd_ik.game.crowd_motion import CrowdMotion
from crowd_ik.game.gait import Gait
from crowd_ik.game.layout import character_layout
from crowd_ik.game.limbs import Limbs
from crowd_ik.game.solving import StepSolve
from crowd_ik.geometry.vectors import UP, normalize
from crowd_ik.kernels.serial_loops import BOX, serial_for
from crowd_ik.prepared import prepared

THREAT_HORIZON = 0.7  # s: how far ahead bullets are predicted
THREAT_REACH = 0.7  # m: a bullet passing this close to the chest is a threat (and, if it misses, a dodge)
REFLEX_RANGE = (0.12, 0.65)  # s: each character starts dodging this long before the closest approach
OBLIVIOUS = 0.25  # fraction of the walking bystanders who never see a bullet coming (no dodge, no flight): the
# crowd is hit now and then (with characters.walk_speed = 0 everybody dodges)
CLEAR_HALF_WIDTH = 0.42  # m: lateral distance from the bullet line that clears the shoulders
MAX_LEAN = 0.42  # m: largest lean of the head away from a bullet line
MAX_DUCK = 0.32  # m: deepest duck
MAX_PELVIS_SHIFT = 0.16  # m
HEAD_LEVEL = 1.42  # m: bullets above this height are ducked under (by characters that prefer it)
TAU_ATTACK = 0.06  # s: low-pass time constant while a dodge builds up
TAU_RELEASE = 0.35  # s: ... and while it relaxes back to the stance
WALK_SLACK = 0.95  # the pelvis never asks a leg for more than this fraction of its length (a walking pelvis
# also tilts: the analytic legs then still reach their footprints)
GREY = (0.80, 0.95)  # the characters' shades of grey


def lowpass_gain(magnitude_now, magnitude_desired, dt: float) -> np.ndarray:
    """The gain of one step of `lowpass`: fast (TAU_ATTACK) while the magnitude grows, slow while it shrinks."""
    tau = np.where(magnitude_desired > magnitude_now, TAU_ATTACK, TAU_RELEASE)
    return 1.0 - np.exp(-dt / tau)


def lowpass(current: np.ndarray, desired: np.ndarray, magnitude_now, magnitude_desired, dt: float,
            gain: np.ndarray | None = None) -> np.ndarray:
    """One step of a first-order filter, fast while the magnitude grows and slow while it shrinks (gain: the
    step's lowpass_gain, when the caller filters several values with the same magnitudes)."""
    k = lowpass_gain(magnitude_now, magnitude_desired, dt) if gain is None else gain
    if current.ndim > k.ndim:
        k = k[..., None]
    return (current + (desired - current) * k).astype(np.float32)


def as_slice(rows):
    """slice(first, last + 1) when rows (K,) are consecutive ascending indices (K >= 1), else rows as an array."""
    rows = np.asarray(rows, np.intp)
    if rows.size and np.array_equal(rows, np.arange(rows[0], rows[0] + rows.size)):
        return slice(int(rows[0]), int(rows[0]) + rows.size)
    return rows


class Characters:
    """N characters of `body`'s rig: layout, Crowd, limbs, standing flags and dodge state."""

    def __init__(self, body: Body, scene):
        from crowd_ik.crowd import Crowd

        b = self.body = body
        self.scene = scene
        self.seed = scene.seed
        N, E = scene.characters.count, b.rig.n_effectors
        self.n = N
        self.ground, self.yaw = character_layout(scene)  # (N, 3) y = 0, (N,)
        self.roots = self.ground + np.float32([0.0, b.rest_root_y, 0.0])
        self.crowd = Crowd(b.rig, n=N, seed=scene.seed)
        self.crowd.set_angles(b.stance)
        self.crowd.set_roots(self.roots, self.yaw)
        self.rest_targets = b.rest_targets(self.ground, self.yaw)  # (N, E, 3)
        self.planted = self.rest_targets[:, b.planted].copy()  # (N, 2, 3) ankles, world
        # the point threats are measured from: the chest (a chain's middle joint)
        self.ref_points = np.ascontiguousarray(b.point(b.chest, self.ground, self.yaw), np.float32)
        self.alive = np.ones(N, bool)
        idx = np.arange(N)
        self.reflex = (REFLEX_RANGE[0] + (REFLEX_RANGE[1] - REFLEX_RANGE[0])
                       * streams.rand(self.seed, streams.CHARACTER, idx, 0)).astype(np.float32)
        self.prefers_duck = streams.rand(self.seed, streams.CHARACTER, idx, 1) < 0.5
        walking = scene.characters.walk_speed > 0.0 and b.humanoid
        self.sees = ~walking | (streams.rand(self.seed, streams.CHARACTER, idx, 3) >= OBLIVIOUS)  # (N,) bool
        lo, hi = GREY
        grey = lo + (hi - lo) * streams.rand(self.seed, streams.CHARACTER, idx, 2)
        self.colors = np.repeat(grey[:, None], 3, axis=1).astype(np.float32)  # (N, 3) BGR
        self.lean = np.zeros((N, 3), np.float32)  # low-passed dodge state
        self.duck = np.zeros(N, np.float32)
        self.guard = np.zeros(N, np.float32)
        self.threat = None  # the last step's Threats, for inspection
        self.dodges = 0
        self.hits = 0
        self.last_iterations = np.zeros(N, np.int32)  # each character's iterations in the last world step's solve
        self._tracked = np.full(N, -1, np.int32)  # bullet slot that threatens each character
        self._tracked_serial = np.full(N, -1, np.int64)
        self._orient = np.ascontiguousarray(np.broadcast_to(b.orient, (N, E, 3)), np.float32)
        self._weights = np.ascontiguousarray(np.broadcast_to(b.weights, (N, E)), np.float32)
        # dodge_targets' per-rig arguments (placeholders where a chain has no hips or hands) and outputs
        slot = np.full(E, -1, np.int32)
        slot[b.planted] = np.arange(int(b.planted.sum()), dtype=np.int32)
        self._dodge_consts = (
            b.lean.astype(np.float32), b.duck.astype(np.float32), slot,
            (b.hands if len(b.hands) else np.full(1, -1)).astype(np.int32),
            (b.hip_offset if b.humanoid else np.zeros((1, 3))).astype(np.float32),
            int(b.humanoid), b.pelvis_share, MAX_PELVIS_SHIFT, WALK_SLACK * b.leg_length if b.humanoid else 1.0, b.scale,
        )
        self._planted_arg = self.planted if b.humanoid else np.zeros((N, 1, 3), np.float32)
        self._targets_buf = np.zeros((N, E, 3), np.float32)
        self._roots_buf = np.zeros((N, 3), np.float32)
        # dodge_targets' inputs, copied into buffers kept from step to step so that its launch stays bound
        # (crowd_ik.prepared): rest targets, lean, duck, guard, roots, yaw, chest points
        self._dodge_in = (np.zeros((N, E, 3), np.float32), np.zeros((N, 3), np.float32), np.zeros(N, np.float32),
                          np.zeros(N, np.float32), np.zeros((N, 3), np.float32), np.zeros(N, np.float32),
                          np.zeros((N, 3), np.float32))
        self.limbs = Limbs(b, N, self.crowd)
        self.motion = CrowdMotion(self.ground, self.yaw, scene)
        self.motion.enabled &= b.humanoid
        self.gait = Gait(b, self.ground, self.yaw) if b.humanoid else None
        names = b.rig.effector_names
        self._hand_eff = [names.index("hand_l"), names.index("hand_r")] if b.humanoid else []
        # the same rows as slices where they are consecutive (a view: no gather and scatter each step)
        self._hand_rows = as_slice(self._hand_eff)
        self._planted_rows = as_slice(np.flatnonzero(b.planted))
        self.arm_poles = ArmPoles(b, N) if b.humanoid else None  # elbows out and down (no knee poles: gait.plant)
        self._solve = StepSolve(self.crowd, scene.solver, self._orient)  # the crowd's solve, checked once

    def walk(self, dt: float, obstacles: np.ndarray) -> None:
        """Move the standing bystanders' pelvises (obstacles (K, 2): the player's and the standing shooters'
        (x, z), kept clear of), step their feet, and set this step's stance targets, roots and chest points."""
        if self.gait is None:
            return
        m, b = self.motion, self.body
        if m.enabled:
            m.step(dt, self.alive, obstacles)
            self.ground = np.zeros((self.n, 3), np.float32)
            self.ground[:, [0, 2]] = m.pos
            self.yaw = m.yaw.astype(np.float32)
        self.gait.step(self.ground, self.yaw, self.velocity, dt, self.alive)
        feet = self.gait.targets()
        bob, hands, head = self.gait.pose()
        targets = b.rest_targets(self.ground, self.yaw)
        targets[:, self._hand_rows] += hands
        targets[:, 0] += head
        targets[:, self._planted_rows] = feet
        self.rest_targets = targets
        np.copyto(self.planted, feet)
        self.roots = (self.ground + np.float32([0.0, b.rest_root_y, 0.0])).astype(np.float32)
        self.roots[:, 1] += bob
        self.ref_points = np.ascontiguousarray(b.point(b.chest, self.ground, self.yaw), np.float32)

    @property
    def velocity(self) -> np.ndarray:
        """(N, 3) float32 m/s: the pelvises' walking velocities (y = 0)."""
        v = np.zeros((self.n, 3), np.float32)
        v[:, [0, 2]] = self.motion.vel
        return v

    @property
    def joints(self) -> np.ndarray:
        """(N, J, 3) float32 world joints after the last world step (the limbs' host copy)."""
        return self.limbs.joints

    def dodge(self, bullets, dt: float) -> None:
        """Threats from `bullets` (game.bullets.Bullets) -> dodge bookkeeping -> the low-passed dodge."""
        b = self.body
        scale = b.scale
        alive_i = self.alive.astype(np.int32)
        thr = bullets.pool.threats(self.ref_points, alive_i, THREAT_HORIZON, THREAT_REACH * scale)
        self.threat = thr
        # 1. tracked bullets that went past their character are dodges; ones that stopped short are dropped
        tr = self._tracked
        idx = np.flatnonzero((tr >= 0) & self.alive)
        if idx.size:
            p = tr[idx]
            same = bullets.serial[p] == self._tracked_serial[idx]
            rel = self.ref_points[idx] - bullets.pos[p]
            past = np.einsum("ij,ij->i", rel, bullets.vel[p]) <= 0.0
            dodged = same & past
            self.dodges += int(dodged.sum())
            done = dodged | ~same | (~bullets.alive[p] & ~past)
            tr[idx[done]] = -1
        # 2. new close passes are tracked
        close = (tr < 0) & self.alive & (thr.bullet >= 0) & (thr.time < THREAT_HORIZON)
        tr[close] = thr.bullet[close]
        self._tracked_serial[close] = bullets.serial[thr.bullet[close]]
        # 3. the dodge each character wants now
        react = self.alive & self.sees & (thr.bullet >= 0) & (thr.time <= self.reflex)
        lean_goal = np.zeros_like(self.lean)
        duck_goal = np.zeros_like(self.duck)
        guard_goal = np.zeros_like(self.guard)
        i = np.flatnonzero(react)
        if i.size:
            d = thr.direction[i]
            m = self.ref_points[i] - thr.point[i]  # from the bullet's closest point to the chest
            side = normalize(cross(UP, d) * [1.0, 0.0, 1.0], fallback=(1.0, 0.0, 0.0))
            along = np.einsum("ij,ij->i", m, side)
            coin = streams.rand(self.seed, streams.SIDE, i, bullets.serial[thr.bullet[i]]) < 0.5
            sign = np.where(np.abs(along) > 0.02 * scale, np.sign(along), np.where(coin, 1.0, -1.0))
            height = thr.point[i, 1] - self.ground[i, 1]
            head_high = height > HEAD_LEVEL * scale
            ducks = head_high & self.prefers_duck[i] & b.humanoid
            clear = (CLEAR_HALF_WIDTH * scale + self.scene.bullets.radius) - np.abs(along)
            lean = np.clip(clear, 0.0, MAX_LEAN * scale) * np.where(ducks, 0.4, 1.0)
            head_top = (b.rest_pos[b.head, 1] + 0.12 * scale) if b.humanoid else b.rest_pos[:, 1].max() + 0.05
            duck = np.where(ducks, np.clip(head_top + 0.05 * scale - height, 0.0, MAX_DUCK * scale), 0.0)
            if not b.humanoid:  # a chain dodges by bending: duck for anything above its middle
                duck = np.where(height > 0.5 * head_top, np.clip(head_top - height + 0.3, 0.0, MAX_DUCK * scale), 0.0)
            lean_goal[i] = side * (sign * lean)[:, None]
            self.motion.flee(i, side * sign[:, None], d)
            duck_goal[i] = duck
            guard_goal[i] = np.where(head_high, 1.0, 0.0)
        mag_now = np.linalg.norm(self.lean, axis=1) + self.duck
        mag_goal = np.linalg.norm(lean_goal, axis=1) + duck_goal
        gain = lowpass_gain(mag_now, mag_goal, dt)  # one gain for the three filters (the same magnitudes)
        self.lean = lowpass(self.lean, lean_goal, mag_now, mag_goal, dt, gain)
        self.duck = lowpass(self.duck, duck_goal, mag_now, mag_goal, dt, gain)
        self.guard = lowpass(self.guard, guard_goal, mag_now, mag_goal, dt, gain)

    def solve(self) -> float:
        """The dodge -> roots and IK targets (one kernel), one batched solve, the limbs; returns the
        solve's milliseconds (0 when nobody is standing: no solve)."""
        if not self.alive.any():
            return 0.0
        from crowd_ik.kernels import game_kernels as gk

        targets, roots = self._targets_buf, self._roots_buf
        staged = self._dodge_in
        for buf, value in zip(staged, (self.rest_targets, self.lean, self.duck, self.guard, self.roots, self.yaw,
                                       self.ref_points)):
            np.copyto(buf, value, casting="same_kind")
        rest, lean, duck, guard, roots_in, yaw, chest = staged
        prepared(gk.dodge_targets)(rest, lean, duck, guard, roots_in, yaw, self._planted_arg, chest,
                                   *self._dodge_consts, targets, roots, serial_for(self.n, BOX))
        weights = self._weights * self.alive[:, None]
        t0 = time.perf_counter()
        self.crowd.set_roots(roots, self.yaw)
        poles = None if self.arm_poles is None else self.arm_poles.update(roots, self.yaw, self.alive)
        # no SolveReport: nothing in the game reads its statuses or rotation errors (at 10,000 humanoids they cost
        # 2.3 ms a step); the iterations are kept for the bench and the tests
        self._solve(targets, weights, poles, report=False)
        np.copyto(self.last_iterations, self.crowd.buffers.iterations)
        if self.gait is not None:
            self.gait.plant(self.crowd, self.planted, self.yaw, self.alive)
        ms = 1e3 * (time.perf_counter() - t0)
        self.limbs.update()
        return ms

    def struck(self, chars: np.ndarray) -> None:
        """Characters `chars` were hit: they fall (stop dodging and being drawn)."""
        self.alive[chars] = False
        self._tracked[chars] = -1
        self.hits += len(chars)
