"""Which effectors a request switches on, when the lane kernels can take it: the same effectors positively weighted
for every character that weights any (the game's, the bench's and FABRIK's restart windows' requests), so that which
joints are active is a property of the rig, the same in every lane (kernels/fabrik_limited_lanes.py,
kernels/ccd_lanes.py)."""

from __future__ import annotations

import numpy as np


def weighted_effectors(weights: np.ndarray) -> tuple | None:
    """The (E,) on/off pattern of positive weights shared by every row of weights (N, E) that has any, or None when
    the rows differ or none has any."""
    on = weights > 0.0
    if on.all():  # the common case (every effector weighted), without the row comparison below
        return (True,) * on.shape[1]
    rows = on.any(axis=1)
    if not rows.any():
        return None
    first = on[int(np.argmax(rows))]
    if not np.array_equal(on[rows], np.broadcast_to(first, (int(rows.sum()), on.shape[1]))):
        return None
    return tuple(bool(x) for x in first)


def active_joints(crowd, weighted: tuple) -> np.ndarray:
    """(J,) int32: 1 for each joint at or above a positively weighted effector (kernels/fabrik.py's acc_w > 0,
    kernels/ccd_steps.joint_active), cached per crowd and pattern."""
    cache = crowd.__dict__.setdefault("_lane_active_joints", {})
    if weighted not in cache:
        parent, eff_joint = crowd.rig.arrays["parent"], crowd.rig.arrays["eff_joint"]
        active = np.zeros(len(parent), np.int32)
        for e, on in enumerate(weighted):
            j = int(eff_joint[e]) if on else -1
            while j >= 0 and not active[j]:
                active[j] = 1
                j = int(parent[j])
        cache[weighted] = active
    return cache[weighted]
