"""Body: a rig with the stance it stands in and the part each effector plays in a dodge and a walk."""

from __future__ import annotations

import math

import numpy as np

from crowd_ik.geometry import fk
from crowd_ik.geometry.vectors import UP, yaw_rotate
from crowd_ik.rig import Rig

PELVIS_SHARE = 0.35  # fraction of the lean done by moving the pelvis
LEG_SLACK = 0.985  # the pelvis never asks a leg for more than this fraction of its length
CHAIN_BONES = 8
HUMANOID_STANCE = {  # joint -> angles in degrees: knees slightly bent so the legs are never straight
    "hip_l": (-15.0, 0.0, 0.0), "hip_r": (-15.0, 0.0, 0.0), "knee_l": (30.0,), "knee_r": (30.0,),
    "ankle_l": (-15.0, 0.0), "ankle_r": (-15.0, 0.0), "elbow_l": (20.0,), "elbow_r": (20.0,),
}


def make_rig(kind: str, scale: float) -> Rig:
    """The characters' rig of a scene: "humanoid" (1.75 m times scale) or an 8-bone chain."""
    if kind == "humanoid":
        return Rig.humanoid(1.75 * scale)
    return Rig.chain(CHAIN_BONES, bone_length=0.2 * scale, dim=3)


class Body:
    """A rig with its stance and how its effectors take part in a dodge.

    stance: (DOF,) radians; rest_root_y: root height that puts the stance's feet on the ground;
    rest_local: (E, 3) effectors relative to the root at yaw 0; lean/duck gains (E,) say how much
    of the dodge's lean vector and duck each effector follows; planted (E,) marks the feet (and
    orient (E, 3) their local axis target: up, so soles stay flat); pelvis_share: fraction of the
    lean done by the root; hands: effector indices that raise a guard (may be empty).
    """

    def __init__(self, rig: Rig, scale: float = 1.0):
        self.rig = rig
        self.scale = float(scale)
        J, E = rig.n_joints, rig.n_effectors
        names = rig.joint_names
        self.parent = rig.arrays["parent"]
        self.bone_parent = self.parent[1:].astype(np.intp)
        self.bone_radius = rig.arrays["radius"][1:].astype(np.float32)
        self.n_bones = J - 1
        self.eff_joint = rig.arrays["eff_joint"].astype(np.intp)
        stance = np.zeros(rig.n_dof, np.float32)
        self.humanoid = rig.name == "humanoid"
        if self.humanoid:
            for name, angles in HUMANOID_STANCE.items():
                j = names.index(name)
                s = rig.dof_start[j]
                stance[s : s + len(angles)] = np.radians(angles)
        else:  # a chain stands up: its first joint turns the +x rest pose to +y
            stance[2] = math.pi / 2.0
        self.stance = stance
        pos = stance_positions(rig, stance)
        if self.humanoid:
            ankle = names.index("ankle_l")
            self.rest_root_y = float(0.06 * self.scale - pos[ankle, 1])
            self.chest = names.index("chest")
            self.head = names.index("head")
            self.hand_r = names.index("hand_r")
            self.shoulder_r = names.index("shoulder_r")
            self.hips = np.array([names.index("hip_l"), names.index("hip_r")])
            self.leg_length = float(rig.bone_lengths[names.index("knee_l")] + rig.bone_lengths[ankle])
            self.hip_offset = pos[self.hips]  # (2, 3) hips relative to the root, yaw 0
            self.lean = np.array([1.0, 0.85, 0.85, 0.0, 0.0], np.float32)
            self.duck = np.array([1.0, 1.0, 1.0, 0.0, 0.0], np.float32)
            self.planted = np.array([False, False, False, True, True])
            self.hands = np.array([1, 2])
            self.pelvis_share = PELVIS_SHARE
        else:
            self.rest_root_y = 0.0
            self.chest = J // 2
            self.head = J - 1
            self.hand_r = J - 1
            self.shoulder_r = J - 2
            self.lean = np.ones(E, np.float32)
            self.duck = np.ones(E, np.float32)
            self.planted = np.zeros(E, bool)
            self.hands = np.zeros(0, np.intp)
            self.pelvis_share = 0.0
        self.rest_pos = (pos + [0.0, self.rest_root_y, 0.0]).astype(np.float32)  # (J, 3) at the origin
        self.rest_local = self.rest_pos[self.eff_joint]
        self.orient = np.zeros((E, 3), np.float32)
        self.orient[self.planted] = UP
        self.weights = np.ones(E, np.float32)

    def rest_targets(self, ground: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(N, E, 3) world effector positions of the stance standing at ground (N, 3) (y = 0), yaw (N,)."""
        return ground[:, None, :] + yaw_rotate(self.rest_local[None, :, :], yaw[:, None])

    def point(self, joint: int, ground: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(N, 3) world position of `joint` in the stance standing at ground (N, 3), yaw (N,)."""
        return ground + yaw_rotate(self.rest_pos[joint][None], yaw)

    def max_root_y(self, roots: np.ndarray, yaw: np.ndarray, feet: np.ndarray) -> np.ndarray:
        """(N,) highest root height at which both hips of roots (N, 3), yaw (N,) reach feet (N, 2, 3)."""
        if not self.humanoid:
            return np.full(len(roots), np.inf)
        hips = roots[:, None, :] * [1.0, 0.0, 1.0] + yaw_rotate(self.hip_offset[None].astype(np.float32), yaw[:, None])
        reach = LEG_SLACK * self.leg_length
        dh = np.linalg.norm((hips - feet)[..., [0, 2]], axis=-1)
        up = np.sqrt(np.maximum(reach * reach - dh * dh, (0.2 * reach) ** 2))
        return np.min(feet[..., 1] + up - self.hip_offset[:, 1][None, :], axis=1)


def stance_positions(rig: Rig, angles: np.ndarray) -> np.ndarray:
    """(J, 3) joint positions of one character in pose `angles`, root at the origin, yaw 0 (host NumPy)."""
    q = fk.angles_to_rotations(rig, angles[None])
    pos, _ = fk.forward_kinematics(rig, np.zeros((1, 3)), np.zeros(1), q)
    return np.asarray(pos[0], np.float64)
