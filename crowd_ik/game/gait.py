"""Gait: procedural footsteps of N humanoids at once, and the legs planted on them by analytic IK.

The pelvis moves (crowd_motion.py, or a shooter turning in place); the feet follow it in steps.
Each character has at most one foot in the air. When no foot swings and the character walks (or
a foot stands farther than STAND_TOLERANCE from where it would stand under the body), a step
starts: the other foot than the last one while walking, else the one that lags most. Its new
footprint is chosen ahead: where the foot stands under the body predicted at the landing
(ground + velocity * T) plus half a step's lead (velocity * T / 2), T the step's duration. The
step length grows with the speed (STEP_LENGTH + STEP_PER_SPEED * speed, at most STEP_MAX) and the
cadence is speed / step length, T clamped to STEP_TIME. The swing is an arc: the foot first lifts
straight up, moves along a smoothstep and sets down straight (LIFT_SHARE of the swing at each end),
peaking at STEP_LIFT in the middle. The stance foot does not move at all: `plant` (after the
solve) sets both legs analytically (kernels/gait_kernels.plant_legs) onto the footprints.

Everything is vectorised over characters (NumPy, one plant_legs launch); no Python loop over them.
`pose()` also gives the gait's pelvis bob and arm swing for the IK targets.
"""

from __future__ import annotations

import math
import weakref

import numpy as np

from crowd_ik.game.body import Body
from crowd_ik.geometry.vectors import yaw_rotate
from crowd_ik.kernels.serial_loops import POSE, serial_for
from crowd_ik.prepared import prepared

_PLANT_INPUTS = weakref.WeakKeyDictionary()  # crowd -> plant_legs' input buffers (feet, yaw, active)

STEP_LENGTH = 0.30  # m: step length (one foot's advance over the body) at zero speed, times the body's scale
STEP_PER_SPEED = 0.30  # s: extra step length per m/s of speed (m per m/s)
STEP_MAX = 0.75  # m: longest step, times the scale
STEP_TIME = (0.28, 0.55)  # s: shortest and longest step (swing) duration
STEP_LIFT = 0.08  # m: swing height at mid-step, times the scale
LIFT_SHARE = 0.12  # fraction of the swing at each end during which the foot moves only vertically
WALKING = 0.12  # m/s: above this speed a character steps continuously
STAND_TOLERANCE = 0.06  # m: a standing character steps when a foot is this far from its place under the body
BOB = 0.025  # m: pelvis rise at mid-step at full speed, times the scale
BOB_SPEED = 1.2  # m/s: speed of the full bob and arm swing
ARM_SWING = 0.40  # m of hand travel forward per m of the feet's forward split (hands counter-swing the legs)
ARM_MAX = 0.20  # m: largest forward/back hand offset, times the scale
HEAD_LEAN = 0.05  # m: the head leans this far forward at full speed, times the scale


def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class Gait:
    """Footprints and swings of N bodies of `body` (a humanoid) standing at ground (N, 3), yaw (N,).

    feet (N, 2, 3): the planted footprints (ankle positions, world metres); swing (N,) int8: the
    foot in the air (-1 none); progress (N,) in [0, 1) of that swing; steps: footsteps started so far.
    """

    def __init__(self, body: Body, ground: np.ndarray, yaw: np.ndarray):
        self.body = body
        self.n = len(ground)
        self.scale = body.scale
        self.foot_local = body.rest_local[body.planted].astype(np.float32)  # (2, 3) ankles under the root, yaw 0
        self.feet = self.homes(ground, yaw)
        self.swing = np.full(self.n, -1, np.int8)
        self.progress = np.zeros(self.n, np.float32)
        self.period = np.full(self.n, STEP_TIME[1], np.float32)
        self.start = np.zeros((self.n, 3), np.float32)
        self.goal = np.zeros((self.n, 3), np.float32)
        self.last = (np.arange(self.n) % 2).astype(np.int8)  # who stepped last: neighbours start on opposite feet
        self.steps = 0
        self.legs = leg_joints(body.rig)

    def homes(self, ground: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(N, 2, 3) where the ankles stand under bodies at ground (N, 3) (y = 0), yaw (N,)."""
        g = np.asarray(ground, np.float32) * np.float32([1.0, 0.0, 1.0])
        return (g[:, None, :] + yaw_rotate(self.foot_local[None], np.asarray(yaw, np.float32)[:, None])).astype(np.float32)

    def step(self, ground: np.ndarray, yaw: np.ndarray, velocity: np.ndarray, dt: float, active: np.ndarray) -> None:
        """Advance the swings by dt s and start new steps for bodies at ground (N, 3), yaw (N,), moving at
        velocity (N, 3) m/s (y ignored); only `active` (N,) bool bodies start steps."""
        s = self.scale
        up = self.swing >= 0
        self.progress[up] += np.float32(dt) / self.period[up]
        done = np.flatnonzero(up & (self.progress >= 1.0))
        if done.size:
            self.feet[done, self.swing[done]] = self.goal[done]
            self.last[done] = self.swing[done]
            self.swing[done] = -1
            self.progress[done] = 0.0
        vel = np.asarray(velocity, np.float32) * np.float32([1.0, 0.0, 1.0])
        speed = np.linalg.norm(vel, axis=1)
        self._retarget(np.flatnonzero(self.swing >= 0), ground, yaw, vel, speed)
        lag = np.linalg.norm((self.feet - self.homes(ground, yaw))[..., [0, 2]], axis=2)  # (N, 2)
        walking = speed > WALKING * s
        start = np.flatnonzero((self.swing < 0) & active & (walking | (lag.max(axis=1) > STAND_TOLERANCE * s)))
        if start.size == 0:
            return
        foot = np.where(walking[start], 1 - self.last[start], np.argmax(lag[start], axis=1)).astype(np.int8)
        self.start[start] = self.feet[start, foot]
        self.swing[start] = foot
        self.progress[start] = 0.0
        self.period[start] = self._period(speed[start])
        self._retarget(start, ground, yaw, vel, speed)
        self.steps += int(start.size)

    def _period(self, speed: np.ndarray) -> np.ndarray:
        """(K,) s: a step's duration at speed (K,) m/s (step length / speed, clamped to STEP_TIME)."""
        s = self.scale
        length = np.minimum(STEP_LENGTH * s + STEP_PER_SPEED * speed, STEP_MAX * s)
        return np.clip(length / np.maximum(speed, 1e-6), *STEP_TIME).astype(np.float32)

    def _retarget(self, i: np.ndarray, ground, yaw, vel: np.ndarray, speed: np.ndarray) -> None:
        """Footprints of the swings i (K,) from the body now: a swing shortens when the body speeds up, and
        until its set-down (the last LIFT_SHARE) its goal follows the body predicted at the landing."""
        if i.size == 0:
            return
        self.period[i] = np.minimum(self.period[i], self._period(speed[i]))
        i = i[self.progress[i] < 1.0 - LIFT_SHARE]
        left = ((1.0 - self.progress[i]) * self.period[i])[:, None]
        v = vel[i]
        landing = np.asarray(ground, np.float32)[i] + v * left
        homes = self.homes(landing, np.asarray(yaw, np.float32)[i])
        self.goal[i] = homes[np.arange(i.size), self.swing[i]] + v * (0.5 * self.period[i])[:, None]

    def targets(self) -> np.ndarray:
        """(N, 2, 3) the ankles' targets now: the planted footprints, the swinging foot on its arc."""
        feet = self.feet.copy()
        i = np.flatnonzero(self.swing >= 0)
        if i.size:
            t = self.progress[i]
            h = smoothstep((t - LIFT_SHARE) / (1.0 - 2.0 * LIFT_SHARE))[:, None]
            p = self.start[i] + (self.goal[i] - self.start[i]) * h
            reach = np.linalg.norm((self.goal[i] - self.start[i])[:, [0, 2]], axis=1)
            lift = STEP_LIFT * self.scale * np.minimum(1.0, reach / (0.15 * self.scale))  # small steps lift less
            p[:, 1] += lift * np.sin(math.pi * t)
            feet[i, self.swing[i]] = p
        return feet

    def pose(self, yaw: np.ndarray, speed: np.ndarray, feet: np.ndarray | None = None):
        """(bob (N,) m of pelvis rise, hand offsets (N, 2, 3) m for hand_l and hand_r, head offset (N, 3) m)
        of bodies heading yaw (N,) at speed (N,) m/s: the pelvis rises mid-swing, the hands swing
        against the feet, the head leans into the walk. feet: targets() of the state now, when the caller
        has it (else computed)."""
        s = self.scale
        gain = np.minimum(1.0, np.asarray(speed, np.float32) / (BOB_SPEED * s))
        mid = np.where(self.swing >= 0, np.sin(math.pi * self.progress), 0.0)
        bob = (BOB * s * gain * (mid - 0.5)).astype(np.float32)
        if feet is None:
            feet = self.targets()
        fwd = np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], axis=1).astype(np.float32)
        split = np.einsum("ij,ij->i", feet[:, 1] - feet[:, 0], fwd)  # right foot ahead of the left, m
        arm = np.clip(ARM_SWING * split, -ARM_MAX * s, ARM_MAX * s) * gain
        hands = np.stack([fwd * arm[:, None], -fwd * arm[:, None]], axis=1)
        return bob, hands.astype(np.float32), (fwd * (HEAD_LEAN * s * gain)[:, None]).astype(np.float32)

    def plant(self, crowd, feet: np.ndarray, yaw: np.ndarray, active: np.ndarray) -> None:
        """Set both legs of the crowd's active (N,) bodies analytically onto feet (N, 2, 3) (plant_legs)."""
        plant_legs(crowd, self.legs, feet, yaw, active)


def leg_joints(rig) -> np.ndarray:
    """(2, 4) int32: the joints hip, knee, ankle, toe of a humanoid's left and right leg."""
    names = rig.joint_names
    return np.array([[names.index(f"{j}_{side}") for j in ("hip", "knee", "ankle", "toe")] for side in "lr"], np.int32)


def plant_legs(crowd, legs: np.ndarray, feet: np.ndarray, yaw: np.ndarray, active: np.ndarray) -> None:
    """Set both legs (leg_joints) of the crowd's active (N,) humanoids analytically onto feet (N, 2, 3) m,
    knees bending toward yaw (N,): one kernels/gait_kernels.plant_legs launch, after the crowd's solve."""
    from crowd_ik.kernels import gait_kernels as gk

    ra = crowd.rig_arrays
    staged = _PLANT_INPUTS.get(crowd)
    if staged is None or staged[0].shape != np.shape(feet):  # kept per crowd, so that the launch stays bound
        staged = _PLANT_INPUTS[crowd] = (np.zeros(np.shape(feet), np.float32), np.zeros(crowd.n, np.float32),
                                         np.zeros(crowd.n, np.int32))
    feet_in, yaw_in, active_in = staged
    np.copyto(feet_in, feet, casting="same_kind")
    np.copyto(yaw_in, yaw, casting="same_kind")
    np.copyto(active_in, active, casting="unsafe")
    prepared(gk.plant_legs)(crowd.world_pos, crowd.world_rot, crowd.local_rot, ra["offset"],
                            np.ascontiguousarray(legs, np.int32), feet_in, yaw_in, active_in, serial_for(crowd.n, POSE))
