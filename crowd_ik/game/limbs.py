"""Limbs: the characters' bones as capsules in Taichi ndarrays, for the bullet pool's hit tests.

Capsule n * B + k is character n's bone k (B bones each). Two capsule sets alternate (this step's
and the previous step's pose: the pool sub-steps between them), with each character's (x, z) box
over both, and the host copy of the joints the game reads (`joints`, `joints_prev`).
"""

from __future__ import annotations

import numpy as np

from crowd_ik.game.body import Body
from crowd_ik.kernels.serial_loops import BOX, serial_for
from crowd_ik.prepared import prepared


def ti_ndarray(value: np.ndarray):
    """A Taichi ndarray holding a copy of `value`: (n, 3) float32 as n vec3, other arrays element-wise."""
    import taichi as ti

    if value.dtype == np.float32 and value.ndim == 2 and value.shape[1] == 3:
        arr = ti.ndarray(ti.math.vec3, shape=value.shape[:1])
    else:
        arr = ti.ndarray(ti.i32 if value.dtype == np.int32 else ti.f32, shape=value.shape)
    arr.from_numpy(np.ascontiguousarray(value))
    return arr


class Limbs:
    """The capsules of N bodies of `body`'s rig, updated from a Crowd's solved pose in one launch."""

    def __init__(self, body: Body, n: int, crowd):
        B, J = body.n_bones, body.rig.n_joints
        self.crowd = crowd
        self.owner = ti_ndarray(np.repeat(np.arange(n, dtype=np.int32), B))  # capsule c is character c // B
        self.radius = ti_ndarray(np.tile(body.bone_radius, n))
        self._bone_parent = ti_ndarray(body.bone_parent.astype(np.int32))
        self._bone_radius = ti_ndarray(body.bone_radius)
        self.caps = [(ti_ndarray(np.zeros((n * B, 3), np.float32)), ti_ndarray(np.zeros((n * B, 3), np.float32)))
                     for _ in range(2)]  # this step's and the previous step's capsule ends, alternating
        self.pose_box = [ti_ndarray(np.zeros((n, 4), np.float32)) for _ in range(2)]  # (x, z) box of each set
        self.now = 0
        self.owner_box = ti_ndarray(np.zeros((n, 4), np.float32))
        self._joint_bufs = (np.zeros((n, J, 3), np.float32), np.zeros((n, J, 3), np.float32))
        self.joints = self._joint_bufs[0]
        for _ in range(2):  # both capsule sets hold the starting pose
            self.update()
        self.joints_prev = self.joints  # (N, J, 3) now and at the previous step (host)

    def begin_step(self) -> None:
        """The pose now becomes the previous step's (for drawing between the two)."""
        self.joints_prev = self.joints

    def update(self) -> None:
        """From the crowd's solved pose, in one launch: the capsules into the next set, the host
        joints (N, J, 3) into the buffer that `joints` does not hold, and each character's box over
        this and the previous step's capsules."""
        from crowd_ik.kernels import game_kernels as gk

        prev_box = self.pose_box[self.now]
        self.now = 1 - self.now
        a, b = self.caps[self.now]
        joints = self._joint_bufs[1] if self.joints is self._joint_bufs[0] else self._joint_bufs[0]
        prepared(gk.limb_capsules)(self.crowd.world_pos, self._bone_parent, self._bone_radius, prev_box, a, b, joints,
                                   self.pose_box[self.now], self.owner_box, serial_for(self.crowd.n, BOX))
        self.joints = joints

    @property
    def current(self):
        """(a, b) ndarrays of this step's capsule ends."""
        return self.caps[self.now]

    @property
    def previous(self):
        """(a, b) ndarrays of the previous step's capsule ends."""
        return self.caps[1 - self.now]
