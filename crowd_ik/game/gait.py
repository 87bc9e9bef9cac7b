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

A world step is one kernels/gait_kernels.gait_step launch over every body (the steps, the ankles' targets, and
the walk's pelvis bob, arm swing and head lean for the IK targets; twin: crowd_ik/reference/gait.py) and, after
the solve, one plant_legs launch; no Python loop over bodies (at 10,000 bodies the NumPy version it replaced
took 4.2 ms a step).
"""

from __future__ import annotations

import weakref

import numpy as np

from crowd_ik.game.body import Body
from crowd_ik.geometry.vectors import yaw_rotate
from crowd_ik.kernels.serial_loops import BOX, POSE, serial_for
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
SMALL_STEP = 0.15  # m: a step shorter than this lifts the foot less (in proportion), times the scale


def foot_homes(foot_local: np.ndarray, ground: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, 2, 3) float32: where ankles at foot_local (2, 3) under the root at yaw 0 stand under bodies at ground
    (N, 3) (its y ignored), yaw (N,)."""
    g = np.asarray(ground, np.float32) * np.float32([1.0, 0.0, 1.0])
    turned = yaw_rotate(foot_local[None], np.asarray(yaw, np.float32)[:, None])
    return (g[:, None, :] + turned).astype(np.float32)


class Gait:
    """Footprints and swings of N bodies of `body` (a humanoid) standing at ground (N, 3), yaw (N,).

    feet (N, 2, 3): the planted footprints (ankle positions, world metres); swing (N,) int32: the
    foot in the air (-1 none); progress (N,) in [0, 1) of that swing; steps: footsteps started so far.
    step() runs kernels/gait_kernels.gait_step (one launch), which also leaves the targets and the pose.
    """

    def __init__(self, body: Body, ground: np.ndarray, yaw: np.ndarray):
        from crowd_ik.kernels.gait_kernels import GAIT_PARAMS

        self.body = body
        self.n = n = len(ground)
        self.scale = s = body.scale
        self.foot_local = body.rest_local[body.planted].astype(np.float32)  # (2, 3) ankles under the root, yaw 0
        self.feet = self.homes(ground, yaw)
        self.swing = np.full(n, -1, np.int32)
        self.progress = np.zeros(n, np.float32)
        self.period = np.full(n, STEP_TIME[1], np.float32)
        self.start = np.zeros((n, 3), np.float32)
        self.goal = np.zeros((n, 3), np.float32)
        self.last = (np.arange(n) % 2).astype(np.int32)  # who stepped last: neighbours start on opposite feet
        self.legs = leg_joints(body.rig)
        values = dict(step_length=STEP_LENGTH * s, step_per_speed=STEP_PER_SPEED, step_max=STEP_MAX * s,
                      step_time_min=STEP_TIME[0], step_time_max=STEP_TIME[1], walking=WALKING * s,
                      stand_tolerance=STAND_TOLERANCE * s, lift_share=LIFT_SHARE, step_lift=STEP_LIFT * s,
                      bob=BOB * s, bob_speed=BOB_SPEED * s, arm_swing=ARM_SWING, arm_max=ARM_MAX * s,
                      head_lean=HEAD_LEAN * s, small_step=SMALL_STEP * s)
        self._params = np.array([values[k] for k in GAIT_PARAMS], np.float32)
        # the launch's inputs and outputs, kept (a prepared launch binds them once)
        self._ground, self._yaw = np.zeros((n, 3), np.float32), np.zeros(n, np.float32)
        self._velocity, self._active = np.zeros((n, 3), np.float32), np.zeros(n, np.int32)
        self._started = np.zeros(1, np.int32)
        self._targets = self.feet.copy()
        self._bob, self._hands = np.zeros(n, np.float32), np.zeros((n, 2, 3), np.float32)
        self._head = np.zeros((n, 3), np.float32)

    @property
    def steps(self) -> int:
        """Footsteps started so far."""
        return int(self._started[0])

    def homes(self, ground: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(N, 2, 3) where the ankles stand under bodies at ground (N, 3) (y = 0), yaw (N,)."""
        return foot_homes(self.foot_local, ground, yaw)

    def step(self, ground: np.ndarray, yaw: np.ndarray, velocity: np.ndarray, dt: float, active: np.ndarray) -> None:
        """Advance the swings by dt s and start new steps for bodies at ground (N, 3), yaw (N,), moving at
        velocity (N, 3) m/s (y ignored); only `active` (N,) bool bodies start steps. Then targets() and pose()
        give this step's foot targets and walk pose."""
        from crowd_ik.kernels import gait_kernels as gk

        np.copyto(self._ground, ground, casting="same_kind")
        np.copyto(self._yaw, yaw, casting="same_kind")
        np.copyto(self._velocity, velocity, casting="same_kind")
        np.copyto(self._active, active, casting="unsafe")
        prepared(gk.gait_step)(self._ground, self._yaw, self._velocity, self._active, self.foot_local, self._params,
                               float(dt), self.feet, self.swing, self.progress, self.period, self.start, self.goal,
                               self.last, self._started, self._targets, self._bob, self._hands, self._head,
                               serial_for(self.n, BOX))

    def targets(self) -> np.ndarray:
        """(N, 2, 3) the ankles' targets after the last step: the planted footprints, the swinging foot on its
        arc (the feet themselves before any step)."""
        return self._targets.copy()

    def pose(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bob (N,) m of pelvis rise, hand offsets (N, 2, 3) m for hand_l and hand_r, head offset (N, 3) m) of
        the last step: the pelvis rises mid-swing, the hands swing against the feet, the head leans into the walk,
        all in proportion to the speed up to BOB_SPEED."""
        return self._bob.copy(), self._hands.copy(), self._head.copy()

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
