"""The general FABRIK kernel's launches in each character's root frame (kernels/root_frame.py): the crowd's world_pos
and the request's targets minus root_pos for the launch, the root at 0 in the kernel, and world_pos back after it
(also when the launch raises). kernels/fabrik_lanes.py and kernels/fabrik_limited_lanes.py do the same inside their
kernels; why, with numbers, in kernels/root_frame.py."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from crowd_ik.kernels.serial_loops import JOINT, serial_for
from crowd_ik.prepared import prepared


@contextmanager
def shifted(crowd):
    """Yields (origins (N, 3) zeros, the targets (N, E, 3) in the root frame) for the launch in the with-block, while
    crowd.world_pos holds the positions minus root_pos."""
    from crowd_ik.kernels import root_frame

    b = crowd.buffers
    held = crowd.__dict__.get("_root_frame")
    if held is None:  # buffers the launches keep bound
        held = crowd.__dict__["_root_frame"] = (np.zeros_like(crowd.root_pos), np.zeros_like(b.targets))
    origins, rel_targets = held
    serial = serial_for(crowd.n * crowd.rig.n_joints, JOINT)
    prepared(root_frame.to_root_frame)(crowd.root_pos, crowd.world_pos, b.targets, rel_targets, serial)
    try:
        yield origins, rel_targets
    finally:
        prepared(root_frame.to_world_frame)(crowd.root_pos, crowd.world_pos, serial)
