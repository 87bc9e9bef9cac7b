"""The player: one humanoid that walks its scene path (Walker) or is steered by hand (SteeredWalker).

The walk is scalar code (one character, real time): the root follows the path at the player's
speed with a pause at every corner; a foot steps when it lags too far behind where it should
stand (a smooth arc of SWING_TIME), the arms swing and the pelvis bobs. `Player` owns the walker,
the player's Crowd and its solved joints.
"""

from __future__ import annotations

import math

import numpy as np

from crowd_ik.game.aim import ballistic_direction
from crowd_ik.game.arm_poles import ArmPoles
from crowd_ik.game.body import Body
from crowd_ik.game.gait import leg_joints, plant_legs
from crowd_ik.game.solving import StepSolve
from crowd_ik.geometry.vectors import yaw_rotate
from crowd_ik.kernels.serial_loops import BOX, serial_for
from crowd_ik.prepared import prepared

CORNER_PAUSE = 0.6  # s: the scripted walker stops at every corner of its path (time slows down)
STEP_TRIGGER = 0.17  # m: a foot steps when it is this far from where it should stand
SWING_TIME = 0.22  # s per step
STEP_LIFT = 0.09  # m
ARM_SWING = 0.16  # m
TURN_RATE = 8.0  # 1/s: heading follows the path with this rate
ARM_REACH = 0.52  # m: right hand held this far from the shoulder along the line of fire
FACE_MIN = 0.3  # m: an aim point closer than this (horizontally) does not turn the player
MAX_AIM = 1e6  # metres: aim points farther out than this are refused
MUZZLE = 0.08  # m (times the body's scale): a bullet starts this far ahead of the hand


class Walker:
    """The player: walks `path` [(x, z), ...] at `speed` m/s with a pause at every corner, stepping
    its feet procedurally (a foot steps when it lags too far behind where it should stand).

    update(dt) advances real time and returns (root (3,), yaw, targets (E, 3), speed m/s).
    """

    def __init__(self, body: Body, path, speed: float):
        self.body = body
        pts = np.asarray(path, np.float64).reshape(-1, 2)
        self.speed = float(speed)
        # schedule: rows of (t0, t1, x0, z0, x1, z1); pauses have equal ends
        rows, t = [], 0.0
        keep = [pts[0]]
        for p in pts[1:]:
            if np.linalg.norm(p - keep[-1]) > 1e-6:
                keep.append(p)
        for i in range(len(keep) - 1):
            if i > 0:
                rows.append((t, t + CORNER_PAUSE, *keep[i], *keep[i]))
                t += CORNER_PAUSE
            dur = float(np.linalg.norm(keep[i + 1] - keep[i])) / self.speed
            rows.append((t, t + dur, *keep[i], *keep[i + 1]))
            t += dur
        self.schedule = np.array(rows, np.float64).reshape(-1, 6)
        self.headings = [math.atan2(r[4] - r[2], r[5] - r[3]) for r in self.schedule if r[1] > r[0] and
                         (r[4], r[5]) != (r[2], r[3])]
        self.end = keep[-1]
        self.t = 0.0
        x, z = self._position(0.0)
        self.yaw = self._heading(0.0)
        self.root = np.array([x, body.rest_root_y, z])
        self.plants = self._homes(self.root, self.yaw).copy()
        self.swing = -1
        self.swing_t = 0.0
        self.swing_from = np.zeros(3)
        self.swing_to = np.zeros(3)
        self.arm = 0.0

    def _position(self, t: float) -> tuple[float, float]:
        if len(self.schedule) == 0 or t >= self.schedule[-1, 1]:
            return float(self.end[0]), float(self.end[1])
        i = int(np.searchsorted(self.schedule[:, 1], t, side="right"))
        t0, t1, x0, z0, x1, z1 = self.schedule[i]
        f = 0.0 if t1 <= t0 else min(max((t - t0) / (t1 - t0), 0.0), 1.0)
        return x0 + (x1 - x0) * f, z0 + (z1 - z0) * f

    def _heading(self, t: float) -> float:
        """Heading of the segment walked at time t, or of the next one during a pause."""
        if not self.headings:
            return 0.0
        walks = [r for r in self.schedule if (r[4], r[5]) != (r[2], r[3])]
        for r in walks:
            if t < r[1]:
                return math.atan2(r[4] - r[2], r[5] - r[3])
        return self.headings[-1]

    def _homes(self, root: np.ndarray, yaw: float) -> np.ndarray:
        """(2, 3) where the two feet stand under a standing body at root, yaw."""
        b = self.body
        feet = b.rest_local[b.planted]
        return np.asarray(root, np.float64) * [1.0, 0.0, 1.0] + yaw_rotate(feet, np.float32(yaw)).astype(np.float64)

    def update(self, dt: float):
        b = self.body
        self.t += dt
        x, z = self._position(self.t)
        moved = math.hypot(x - self.root[0], z - self.root[2])
        speed = moved / dt
        vel = np.array([x - self.root[0], 0.0, z - self.root[2]]) / dt
        want = self._heading(self.t)
        turn = (want - self.yaw + math.pi) % (2.0 * math.pi) - math.pi
        self.yaw += turn * (1.0 - math.exp(-TURN_RATE * dt))
        root = np.array([x, b.rest_root_y, z])
        homes = self._homes(root, self.yaw)
        if self.swing >= 0:
            self.swing_t += dt / SWING_TIME
            if self.swing_t >= 1.0:
                self.plants[self.swing] = self.swing_to
                self.swing = -1
        if self.swing < 0:
            lag = np.linalg.norm(self.plants - homes, axis=1)
            k = int(np.argmax(lag))
            if lag[k] > STEP_TRIGGER * b.scale:
                self.swing, self.swing_t = k, 0.0
                self.swing_from = self.plants[k].copy()
                self.swing_to = homes[k] + vel * SWING_TIME * 1.5
        feet = self.plants.copy()
        lift = 0.0
        if self.swing >= 0:
            f = self.swing_t * self.swing_t * (3.0 - 2.0 * self.swing_t)
            lift = math.sin(math.pi * self.swing_t)
            feet[self.swing] = self.swing_from + (self.swing_to - self.swing_from) * f
            feet[self.swing, 1] += STEP_LIFT * b.scale * lift
        # the pelvis bobs up mid-step and never asks a leg for more than its length
        root[1] += 0.015 * b.scale * lift
        root[1] = min(root[1], b.max_root_y(root[None], np.array([self.yaw]), feet[None])[0])
        arm_goal = 0.0 if self.swing < 0 else (1.0 if self.swing == 1 else -1.0) * min(1.0, speed / self.speed)
        self.arm += (arm_goal - self.arm) * (1.0 - math.exp(-dt / 0.12))
        ground = (root * [1.0, 0.0, 1.0])[None].astype(np.float32)
        targets = b.rest_targets(ground, np.array([self.yaw], np.float32))[0].astype(np.float64)
        targets[:, 1] += root[1] - b.rest_root_y  # the upper body follows the pelvis bob and drop
        fwd = np.array([math.sin(self.yaw), 0.0, math.cos(self.yaw)])
        targets[0] += fwd * 0.04 * b.scale * min(1.0, speed / max(self.speed, 1e-9))
        if b.humanoid:
            targets[1] += fwd * ARM_SWING * b.scale * self.arm
            targets[2] -= fwd * ARM_SWING * b.scale * self.arm
        targets[b.planted] = feet
        self.root = root
        return root, self.yaw, targets.astype(np.float32), speed


class SteeredWalker(Walker):
    """The player's Walker steered by hand: each update moves the root by velocity * dt (instead of
    along the path) and keeps the procedural stepping, arm swing and pelvis bob of the walk.

    It takes over the state of the walker it replaces (position, heading, planted feet, clock).
    The player faces the aim point when one is set (else the way it walks, else it keeps its
    heading), and IK holds the right hand ARM_REACH from the shoulder on the line to the aim.
    """

    def __init__(self, walker: Walker):  # not super().__init__: that would restart the path walk
        self.__dict__.update(vars(walker))
        self.velocity = np.zeros(2)  # m/s in x, z
        self.aim: np.ndarray | None = None
        self._goal = (float(self.root[0]), float(self.root[2]))
        names = self.body.rig.effector_names
        self._hand_effector = names.index("hand_r") if "hand_r" in names else None

    def steer(self, move, aim=None) -> None:
        """move (x, z), each in [-1, 1] (cut to length 1): velocity = move * speed; aim (3,) or None."""
        m = np.asarray(move, np.float64).reshape(-1)
        if m.shape != (2,) or not np.all(np.isfinite(m)) or np.any(np.abs(m) > 1.0):
            raise ValueError(f"set_player_input: move: expected (x, z) with each in [-1, 1] (got {move!r})")
        n = float(np.hypot(*m))
        self.velocity = (m / n if n > 1.0 else m) * self.speed
        if aim is None:
            self.aim = None
            return
        a = np.asarray(aim, np.float64).reshape(-1)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(np.abs(a) > MAX_AIM):
            raise ValueError(f"set_player_input: aim: expected a finite world point (x, y, z) (got {aim!r})")
        self.aim = a.astype(np.float32)

    def _position(self, t: float) -> tuple[float, float]:
        return self._goal

    def _heading(self, t: float) -> float:
        if self.aim is not None:
            dx, dz = float(self.aim[0] - self.root[0]), float(self.aim[2] - self.root[2])
            if math.hypot(dx, dz) > FACE_MIN * self.body.scale:
                return math.atan2(dx, dz)
        vx, vz = self.velocity
        if math.hypot(vx, vz) > 1e-9:
            return math.atan2(vx, vz)
        return self.yaw

    def update(self, dt: float):
        self._goal = (float(self.root[0] + self.velocity[0] * dt), float(self.root[2] + self.velocity[1] * dt))
        root, yaw, targets, speed = super().update(dt)
        b = self.body
        if self.aim is not None and self._hand_effector is not None and b.humanoid:
            ground = (np.asarray(root) * [1.0, 0.0, 1.0])[None].astype(np.float32)
            shoulder = b.point(b.shoulder_r, ground, np.array([yaw], np.float32))[0]
            shoulder[1] += root[1] - b.rest_root_y
            d = self.aim - shoulder
            n = float(np.linalg.norm(d))
            if n > 1e-6:
                targets[self._hand_effector] = shoulder + d * (ARM_REACH * b.scale / n)
        return root, yaw, targets, speed


def export_joints(crowd, out: np.ndarray) -> np.ndarray:
    """A new (N, J, 3) float32 copy of the crowd's joint positions, through `out`, a host buffer kept by the caller
    (game_kernels.export_joints as a prepared launch: a to_numpy costs a launch's full set-up)."""
    from crowd_ik.kernels import game_kernels as gk

    prepared(gk.export_joints)(crowd.world_pos, out, serial_for(crowd.n, BOX))
    return out.copy()


class Player:
    """The player's walker, Crowd (one humanoid) and solved joints; `shots` counts the bullets it fired."""

    def __init__(self, body: Body, scene):
        from crowd_ik.crowd import Crowd

        self.body = body
        self.solver = scene.solver
        self.walker = Walker(body, scene.player.path, scene.player.speed)
        self.crowd = Crowd(body.rig, n=1, seed=scene.seed)
        self.crowd.set_angles(body.stance)
        self.speed = 0.0  # m/s walked in the last update
        self.shots = 0
        self._orient = body.orient[None].copy()
        self.joints = np.zeros((body.rig.n_joints, 3), np.float32)  # (J, 3) after the last update
        self._joints_out = np.zeros((1, body.rig.n_joints, 3), np.float32)  # export_joints' kept host buffer
        self._legs = leg_joints(body.rig)
        self._arm_poles = ArmPoles(body, 1)  # elbows out and down (knees: plant_legs)
        self._solve = StepSolve(self.crowd, self.solver, self._orient)  # the walking solve, checked once
        self._weights = np.ones((1, body.rig.n_effectors), np.float32)

    def update(self, dt: float) -> None:
        """Walk dt seconds of real time (dt = 0: stand where the walker is) and solve the pose."""
        b = self.body
        if dt > 0.0:
            root, yaw, targets, speed = self.walker.update(dt)
        else:
            w = self.walker
            root, yaw = w.root.astype(np.float32), w.yaw
            targets = b.rest_targets((root * [1.0, 0.0, 1.0])[None].astype(np.float32), np.array([yaw], np.float32))[0]
            speed = 0.0
        self.speed = speed
        root1, yaw1 = np.asarray(root, np.float32)[None], np.array([yaw], np.float32)
        self.crowd.set_roots(root1, yaw1)
        sv = self.solver
        poles = self._arm_poles.update(root1, yaw1)
        if dt > 0.0:  # the report is not used: skipped
            self._solve(np.asarray(targets, np.float32)[None], self._weights, poles, report=False)
        else:  # standing (the first pose): more iterations
            self.crowd.solve(targets[None], method=sv.method, max_iterations=max(sv.iterations, 50),
                             tolerance=sv.tolerance, orientations=self._orient, poles=poles)
        # the feet exactly on the walker's footprints (game.gait): planted feet do not slide
        plant_legs(self.crowd, self._legs, targets[None, b.planted], yaw1, np.ones(1, np.int32))
        self.joints = export_joints(self.crowd, self._joints_out)[0]

    def steer(self, move, aim=None) -> None:
        """Hand steering from now on (see SteeredWalker.steer); the scripted path is not resumed."""
        if not isinstance(self.walker, SteeredWalker):
            self.walker = SteeredWalker(self.walker)
        self.walker.steer(move, aim)

    def shot(self, bullets) -> tuple[np.ndarray, np.ndarray]:
        """(origin (1, 3), velocity (1, 3)) of a bullet fired from the right hand toward the aim point
        under the scene's `bullets` settings (needs a steered walker with an aim)."""
        b = self.body
        hand = self.joints[b.hand_r][None].astype(np.float32)
        d = ballistic_direction(hand, self.walker.aim[None], bullets.speed, bullets.gravity, bullets.drag)
        return hand + d * np.float32(MUZZLE * b.scale), d * np.float32(bullets.speed)

    def position(self) -> np.ndarray:
        """(3,) float64 world position of the player's root on the ground (y = 0)."""
        return np.asarray(self.walker.root, np.float64) * [1.0, 0.0, 1.0]
