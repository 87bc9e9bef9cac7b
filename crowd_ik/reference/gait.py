"""NumPy twin of kernels/gait_kernels.gait_step: game.gait.Gait's footsteps, foot targets and walk pose, vectorised
over characters in float32 as the game ran them before the kernel (the tests' oracle)."""

from __future__ import annotations

import math

import numpy as np

from crowd_ik.game.gait import (ARM_MAX, ARM_SWING, BOB, BOB_SPEED, HEAD_LEAN, LIFT_SHARE, SMALL_STEP,
                                STAND_TOLERANCE, STEP_LENGTH, STEP_LIFT, STEP_MAX, STEP_PER_SPEED, STEP_TIME, WALKING,
                                foot_homes)


def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class GaitTwin:
    """The state of game.gait.Gait (feet (N, 2, 3), swing (N,) -1 or the foot in the air, progress, period, start,
    goal, last, steps) for bodies whose ankles stand at foot_local (2, 3) under the root at yaw 0, `scale` the
    bodies' scale; step() advances it as kernels/gait_kernels.gait_step does."""

    def __init__(self, foot_local: np.ndarray, scale: float, state: dict):
        self.foot_local = np.asarray(foot_local, np.float32)
        self.scale = float(scale)
        for name in ("feet", "swing", "progress", "period", "start", "goal", "last"):
            setattr(self, name, np.array(state[name]))
        self.steps = int(state.get("steps", 0))
        self.n = len(self.feet)

    def homes(self, ground: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(N, 2, 3) where the ankles stand under bodies at ground (N, 3) (y ignored), yaw (N,)."""
        return foot_homes(self.foot_local, ground, yaw)

    def step(self, ground: np.ndarray, yaw: np.ndarray, velocity: np.ndarray, dt: float, active: np.ndarray):
        """Advance dt s; returns (targets (N, 2, 3), bob (N,), hands (N, 2, 3), head (N, 3)) after the step."""
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
        if start.size:
            foot = np.where(walking[start], 1 - self.last[start], np.argmax(lag[start], axis=1))
            self.start[start] = self.feet[start, foot]
            self.swing[start] = foot
            self.progress[start] = 0.0
            self.period[start] = self._period(speed[start])
            self._retarget(start, ground, yaw, vel, speed)
            self.steps += int(start.size)
        targets = self.targets()
        return (targets, *self.pose(yaw, speed, targets))

    def _period(self, speed: np.ndarray) -> np.ndarray:
        s = self.scale
        length = np.minimum(STEP_LENGTH * s + STEP_PER_SPEED * speed, STEP_MAX * s)
        return np.clip(length / np.maximum(speed, 1e-6), *STEP_TIME).astype(np.float32)

    def _retarget(self, i: np.ndarray, ground, yaw, vel: np.ndarray, speed: np.ndarray) -> None:
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
        feet = self.feet.copy()
        i = np.flatnonzero(self.swing >= 0)
        if i.size:
            t = self.progress[i]
            h = smoothstep((t - LIFT_SHARE) / (1.0 - 2.0 * LIFT_SHARE))[:, None]
            p = self.start[i] + (self.goal[i] - self.start[i]) * h
            reach = np.linalg.norm((self.goal[i] - self.start[i])[:, [0, 2]], axis=1)
            lift = STEP_LIFT * self.scale * np.minimum(1.0, reach / (SMALL_STEP * self.scale))
            p[:, 1] += lift * np.sin(math.pi * t)
            feet[i, self.swing[i]] = p
        return feet

    def pose(self, yaw: np.ndarray, speed: np.ndarray, feet: np.ndarray):
        s = self.scale
        gain = np.minimum(1.0, np.asarray(speed, np.float32) / (BOB_SPEED * s))
        mid = np.where(self.swing >= 0, np.sin(math.pi * self.progress), 0.0)
        bob = (BOB * s * gain * (mid - 0.5)).astype(np.float32)
        yaw = np.asarray(yaw, np.float32)
        fwd = np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], axis=1).astype(np.float32)
        split = np.einsum("ij,ij->i", feet[:, 1] - feet[:, 0], fwd)
        arm = np.clip(ARM_SWING * split, -ARM_MAX * s, ARM_MAX * s) * gain
        hands = np.stack([fwd * arm[:, None], -fwd * arm[:, None]], axis=1)
        return bob, hands.astype(np.float32), (fwd * (HEAD_LEAN * s * gain)[:, None]).astype(np.float32)
