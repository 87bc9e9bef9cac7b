"""Arm poles of the game's humanoids: each elbow turns out to the side and down/back (Crowd.solve's poles).

The pole of a hand is a point fixed to the character's root and heading: its stance elbow moved ELBOW_OUT to
the side (away from the body), ELBOW_DOWN down and ELBOW_BACK back (against the facing direction), times the
body's scale. The pole swivel (kernels/poles.py) only uses its direction off the shoulder-hand line, so a
hanging arm gets its elbow back and a little out, an arm held forward (a shooter's) gets it down and a
little out, a guard raised before the face gets it down and out.

Knees get no pole: every standing humanoid of the game has its legs set analytically after the solve
(game.gait.plant_legs, knees bending toward the facing direction), which would overwrite what a knee pole did.
The head and the feet rows stay NaN (no pole), as do the rows of characters that are down.
"""

from __future__ import annotations

import numpy as np

from crowd_ik.game.body import Body

ELBOW_OUT = 0.15  # m (times the scale): the pole's offset from the stance elbow, away from the body
ELBOW_DOWN = 0.10  # m
ELBOW_BACK = 0.30  # m


class ArmPoles:
    """The poles (N, E, 3) float32 of N humanoids of `body`: one host array, refilled in place each step."""

    def __init__(self, body: Body, n: int):
        names = body.rig.effector_names
        self.hands = np.array([names.index("hand_l"), names.index("hand_r")], np.intp)
        joints = body.rig.joint_names
        s = body.scale
        local = []
        for side, sx in (("l", 1.0), ("r", -1.0)):
            elbow = body.rest_pos[joints.index(f"elbow_{side}")] - [0.0, body.rest_root_y, 0.0]  # from the root
            local.append(elbow + s * np.array([sx * ELBOW_OUT, -ELBOW_DOWN, -ELBOW_BACK]))  # its left is +x
        self.local = np.array(local, np.float32)  # (2, 3) each hand's pole from the root at yaw 0
        self.poles = np.full((n, body.rig.n_effectors, 3), np.nan, np.float32)
        self._cos = np.empty(n, np.float32)
        self._sin = np.empty(n, np.float32)

    def update(self, roots: np.ndarray, yaw: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """The poles of characters with roots (N, 3) and headings yaw (N,) (+z turned toward +x, as
        geometry.vectors.yaw_rotate); rows of characters not `active` (N,) bool are NaN. Returns the array."""
        c, s, p = self._cos, self._sin, self.poles
        np.cos(yaw, out=c)
        np.sin(yaw, out=s)
        for k, e in enumerate(self.hands):
            lx, ly, lz = (float(v) for v in self.local[k])
            p[:, e, 0] = roots[:, 0] + c * lx + s * lz
            p[:, e, 1] = roots[:, 1] + ly
            p[:, e, 2] = roots[:, 2] - s * lx + c * lz
        if active is not None and not active.all():
            p[np.flatnonzero(~active)[:, None], self.hands] = np.nan
        return p
