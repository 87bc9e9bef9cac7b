"""Shooters: humanoids in a ring or a line that aim at characters and fire (DESIGN "Game rules").

Each picks a standing character (a hash pick) and its head or chest, aims ballistically with a
low-passed aim, turns toward it and holds its right hand on the line of fire by IK; it fires when
due, in a cone of spread, at 1 / fire_rate intervals with jitter (all from the counter hash). A
shooter the player's bullet hits is down: it neither aims nor fires and keeps its last pose.
A shooter turning in place steps its feet around (game.gait), planted exactly by the analytic legs.
"""

from __future__ import annotations

import math
import time

import numpy as np

from crowd_ik.game import streams
from crowd_ik.game.aim import ballistic_direction, cone_sample
from crowd_ik.game.arm_poles import ArmPoles
from crowd_ik.game.body import Body
from crowd_ik.game.gait import Gait
from crowd_ik.game.layout import shooter_layout
from crowd_ik.game.player import ARM_REACH, MUZZLE, export_joints
from crowd_ik.game.solving import StepSolve
from crowd_ik.geometry.vectors import normalize

TAU_AIM = 0.12  # s: the aim follows a new target with this time constant
TAU_TURN = 0.25  # s: the body turns toward the aim with this time constant
FIRST_SHOT = (0.3, 1.0)  # first shot after this fraction of 1 / fire_rate (uniform)
INTERVAL_JITTER = (0.8, 1.2)  # later shots every 1 / fire_rate times a factor in this range
LEAD = 0.8  # fraction of the flight time by which the aim leads a walking target
COLOR = (0.16, 0.14, 0.82)  # BGR: the shooters (and their shards) are red


class Shooters:
    """S humanoid shooters: places, Crowd, joints, aim, fire schedule and who is still up."""

    def __init__(self, body: Body, scene):
        from crowd_ik.crowd import Crowd

        hb = self.body = body
        self.scene = scene
        self.seed = scene.seed
        S = self.n = scene.shooters.count
        self.ground, self.yaw = shooter_layout(scene)
        self.roots = self.ground + np.float32([0.0, hb.rest_root_y, 0.0])
        self.crowd = Crowd(hb.rig, n=S, seed=scene.seed)
        self.crowd.set_angles(hb.stance)
        self.crowd.set_roots(self.roots, self.yaw)
        self._joints_out = np.zeros((S, hb.rig.n_joints, 3), np.float32)  # export_joints' kept host buffer
        self.joints = export_joints(self.crowd, self._joints_out)  # (S, J, 3) after the last step
        self.joints_prev = self.joints.copy()
        self._orient = np.ascontiguousarray(np.broadcast_to(hb.orient, (S, hb.rig.n_effectors, 3)), np.float32)
        self.shots_fired = np.zeros(S, np.int64)
        self.alive = np.ones(S, bool)  # False once a player's bullet has downed the shooter
        self._weights = np.ones((S, hb.rig.n_effectors), np.float32)  # zero rows for downed shooters
        self._solve = StepSolve(self.crowd, scene.solver, self._orient)
        self.k = np.arange(S)
        period = 1.0 / scene.shooters.fire_rate
        self.next_fire = (period * (FIRST_SHOT[0] + (FIRST_SHOT[1] - FIRST_SHOT[0])
                                    * streams.rand(self.seed, streams.FIRE, self.k, 0))).astype(np.float64)
        self.target = np.zeros(S, np.int32)
        self.aim_joint = np.zeros(S, np.intp)
        self.aim = np.zeros((S, 3), np.float32)
        self.gait = Gait(hb, self.ground, self.yaw)
        self.arm_poles = ArmPoles(hb, S)  # elbows out and down; downed shooters get none (they keep their pose)

    @property
    def down(self) -> int:
        """How many shooters the player's bullets have downed."""
        return int(self.n - np.count_nonzero(self.alive))

    def start(self, characters) -> None:
        """First targets and an aim already on them."""
        self._pick_targets(self.k, characters)
        self.aim = self._aim_directions(self.k, self.joints[:, self.body.hand_r], characters)

    def _pick_targets(self, k: np.ndarray, characters) -> None:
        """New targets for shooters k: a standing character (hash pick) and head or chest."""
        living = np.flatnonzero(characters.alive)
        if living.size == 0 or k.size == 0:
            return
        shot = self.shots_fired[k]
        u = streams.rand(self.seed, streams.FIRE, k, 8 * shot + 1)
        self.target[k] = living[np.minimum((u * living.size).astype(np.int64), living.size - 1)]
        head = streams.rand(self.seed, streams.FIRE, k, 8 * shot + 2) < 0.5
        self.aim_joint[k] = np.where(head, characters.body.head, characters.body.chest)

    def _aim_directions(self, k: np.ndarray, muzzle: np.ndarray, characters) -> np.ndarray:
        """Ballistic unit directions (K, 3) from muzzle (K, 3) to shooters k's aim points, led by the target's
        walking velocity times the flight time (LEAD of it: the shooters are good but not perfect)."""
        b = self.scene.bullets
        point = characters.joints[self.target[k], self.aim_joint[k]]
        flight = np.linalg.norm(point - muzzle, axis=1, keepdims=True) / b.speed
        point = point + characters.velocity[self.target[k]] * (LEAD * flight)
        return ballistic_direction(muzzle, point, b.speed, b.gravity, b.drag)

    def aim_and_fire(self, characters, world_time: float, dt: float, autofire: bool):
        """Follow the targets with the aim; the bullets due now as (origins, velocities), or None."""
        hb = self.body
        k = self.k
        up = self.alive  # downed shooters neither aim nor fire
        dead_target = ~characters.alive[self.target] & up
        if dead_target.any():
            self._pick_targets(k[dead_target], characters)
        muzzle = self.joints[:, hb.hand_r]
        want = self._aim_directions(k, muzzle, characters)
        aim = normalize(self.aim + (want - self.aim) * (1.0 - math.exp(-dt / TAU_AIM)))
        self.aim = aim if up.all() else np.where(up[:, None], aim, self.aim)
        if not (autofire and characters.alive.any()):
            return None
        due = np.flatnonzero((world_time >= self.next_fire) & up)
        if due.size == 0:
            return None
        shot = self.shots_fired[due]
        sc = self.scene.shooters
        u1 = streams.rand(self.seed, streams.FIRE, due, 8 * shot + 3)
        u2 = streams.rand(self.seed, streams.FIRE, due, 8 * shot + 4)
        dirs = cone_sample(want[due], math.radians(sc.spread_deg), u1, u2)
        origins = muzzle[due] + dirs * MUZZLE * hb.scale
        velocities = dirs * self.scene.bullets.speed
        jitter = INTERVAL_JITTER[0] + (INTERVAL_JITTER[1] - INTERVAL_JITTER[0]) * streams.rand(
            self.seed, streams.FIRE, due, 8 * shot + 5)
        self.next_fire[due] = world_time + jitter / sc.fire_rate
        self.shots_fired[due] += 1
        self._pick_targets(due, characters)
        return origins, velocities

    def solve(self, dt: float) -> float:
        """Turn toward the aim and put the right hand on the line of fire (downed shooters keep their
        last pose: zero weights; none standing, no solve); returns the solve's milliseconds."""
        hb = self.body
        up = self.alive
        if not up.any():
            return 0.0
        fwd = self.aim * [1.0, 0.0, 1.0]
        want_yaw = np.arctan2(fwd[:, 0], fwd[:, 2])
        turn = (want_yaw - self.yaw + math.pi) % (2.0 * math.pi) - math.pi
        turn = np.where(up, turn, 0.0)
        self.yaw = (self.yaw + turn * (1.0 - math.exp(-dt / TAU_TURN))).astype(np.float32)
        self.gait.step(self.ground, self.yaw, np.zeros((self.n, 3), np.float32), dt, up)
        feet = self.gait.targets()
        targets = hb.rest_targets(self.ground, self.yaw)
        targets[:, hb.planted] = feet
        shoulder = hb.point(hb.shoulder_r, self.ground, self.yaw)
        targets[:, 2] = shoulder + self.aim * ARM_REACH * hb.scale
        t0 = time.perf_counter()
        self.crowd.set_roots(self.roots, self.yaw)
        # the report is not used: skipped (its rotation errors would read the pose back)
        self._solve(targets, self._weights, self.arm_poles.update(self.roots, self.yaw, up), report=False)
        self.gait.plant(self.crowd, feet, self.yaw, up)
        self.joints = export_joints(self.crowd, self._joints_out)
        return 1e3 * (time.perf_counter() - t0)

    def struck(self, down: np.ndarray) -> None:
        """Shooters `down` were hit by the player's bullets."""
        self.alive[down] = False
        self._weights[down] = 0.0
