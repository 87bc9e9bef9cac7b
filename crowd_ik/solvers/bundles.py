"""Kernel argument bundles: the groups of arrays every solver kernel takes, named once.

Taichi 1.7 kernels take ndarrays one by one (an argpack of ndarrays is not supported on every
backend), so a bundle is a tuple spread into the call: `kernel(*limited_rig(c), *pose(c), ...)`.
The order inside each bundle is the order of the kernels' parameters.
"""

from __future__ import annotations

import numpy as np


class SolveBuffers:
    """A Crowd's solver inputs and outputs, reused by every solve: host arrays the kernels take as they
    are (on the CPU without a copy; on a GPU Taichi copies them around the launch, as from_numpy
    would; a copy into a ti.ndarray cost 0.8 ms per (10,000, 5, 3) array)."""

    def __init__(self, n: int, n_effectors: int):
        N, E = n, n_effectors
        self.targets = np.zeros((N, E, 3), np.float32)
        self.orient = np.zeros((N, E, 3), np.float32)
        self.orient_zero = True  # True while orient holds zeros
        self.weights = np.zeros((N, E), np.float32)
        self.poles = np.zeros((N, E, 3), np.float32)  # pole points (world), pole_on (N, E) 1 where given
        self.pole_on = np.zeros((N, E), np.int32)
        self.poles_zero = True  # True while pole_on holds zeros
        self.rotations = np.zeros((N, E, 4), np.float32)  # rotation targets (x y z w), rot_w (N, E) 0 where none
        self.rot_w = np.zeros((N, E), np.float32)
        self.rot_zero = True  # True while rot_w holds zeros
        self.error = np.zeros(N, np.float32)
        self.iterations = np.zeros(N, np.int32)
        self.stalled = np.zeros(N, np.int32)

    def load(self, req) -> None:
        """Copy a SolveRequest's targets, weights and orientations in (zeros only once for None)."""
        dim = req.targets.shape[-1]
        self.targets[..., :dim] = req.targets
        np.copyto(self.weights, req.weights)
        if req.orientations is not None:
            np.copyto(self.orient, req.orientations)
        elif not self.orient_zero:
            self.orient.fill(0.0)
        self.orient_zero = req.orientations is None
        if req.poles is not None:
            has = ~np.isnan(req.poles[..., 0])
            self.poles[..., :dim] = np.where(has[..., None], req.poles, 0.0)
            np.copyto(self.pole_on, has)
        elif not self.poles_zero:
            self.pole_on.fill(0)
        self.poles_zero = req.poles is None
        if req.rotations is not None:
            np.copyto(self.rotations, req.rotations)
            np.copyto(self.rot_w, req.rotation_weights)
        elif not self.rot_zero:
            self.rot_w.fill(0.0)
        self.rot_zero = req.rotations is None


def limited_rig(crowd) -> tuple:
    """The rig with its joint limits: parent, offset, kind, axes, lo, hi, lim_p, cone, dof_start,
    child_start, child_list, eff_joint, eff_axis (kernels/fabrik.py, kernels/ccd.py)."""
    ra = crowd.rig_arrays
    return tuple(ra[k] for k in ("parent", "offset", "kind", "axes", "lo", "hi", "lim_p", "cone", "dof_start",
                                 "child_start", "child_list", "eff_joint", "eff_axis"))


def pose(crowd) -> tuple:
    """The characters' pose: root_pos, root_yaw, local_rot, world_pos, world_rot."""
    return crowd.root_pos, crowd.root_yaw, crowd.local_rot, crowd.world_pos, crowd.world_rot


def goal(crowd, orientations: bool = True) -> tuple:
    """What the solve aims at: targets, weights and (by default) the orientation targets."""
    b = crowd.buffers
    return (b.targets, b.weights, b.orient) if orientations else (b.targets, b.weights)


def rotation_goal(crowd) -> tuple:
    """Full rotation targets: rotations (N, E, 4) x y z w, rot_w (N, E) (0 where none)."""
    b = crowd.buffers
    return b.rotations, b.rot_w


def result(crowd) -> tuple:
    """Per character out: error, iterations, stalled."""
    b = crowd.buffers
    return b.error, b.iterations, b.stalled
