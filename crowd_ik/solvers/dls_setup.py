"""The constants of one DLS solve of a rig (damping, reach and error clamp per effector, joint modes, the
limits the solver applies, balance weights): host code shared by Crowd and the NumPy twin.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from crowd_ik.solvers.settings import (
    DLS_DAMPING as DAMPING, DLS_DAMPING_MIN as DAMPING_MIN, DLS_ERROR_CLAMP as ERROR_CLAMP,
    DLS_EULER_B_MAX as EULER_B_MAX,
)

if TYPE_CHECKING:
    from crowd_ik.rig import Rig


def balance_weights(rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """(com_w (J,), support_w (J,)) float64: c - s = sum_j com_w[j] midpoint_j - support_w[j] p_j.

    com_w[j] is the mass fraction of the bone ending at joint j (0 for the root), mass proportional to
    bone length x radius^2 (rig.joints[j].radius); support_w[j] is 1 / (number of foot effectors) at a
    foot effector's joint (effector names starting with "foot"), else 0. Both sum to 1 (support_w to 0
    for a rig without feet).
    """
    radius = np.array([j.radius for j in rig.joints], np.float64)
    mass = rig.bone_lengths * radius**2
    mass[0] = 0.0
    com_w = mass / mass.sum()
    support_w = np.zeros(rig.n_joints)
    feet = [e.joint for e in rig.effectors if e.name.startswith("foot")]
    for j in feet:
        support_w[j] += 1.0 / len(feet)
    return com_w, support_w


def dls_settings(rig: Rig, damping: float | None = None, joint_weights=None) -> dict:
    """Constants of a DLS solve of ``rig``: L, the damping (metres), the per-effector reach and d_max, joint modes.

    L (``length``, metres) is the mean reach of the effectors (root to effector along the bones): it
    converts orientation errors (radians) into metres and sets the default damping 0.05 * L. d_max =
    0.4 * mean bone length * sqrt(number of bones) of each effector's path = 0.4 * reach / sqrt(bones).
    jmode (J,): 0 fixed; 1 solved in its angles (hinge, universal, and a ball joint with box limits
    or unequal joint weights, in Euler angles); 2 any other ball joint, solved by world-axis rotation
    vectors on its quaternion (no gimbal lock), its joint weight scaling all three axes alike.
    lo, hi (D,) float64: the limits the solver applies: the rig's, with the middle Euler angle of an
    angle-mode ball joint kept 0.01 rad inside +-pi/2 (off gimbal lock, its angles are then exactly
    the ones Crowd.angles() reports);
    lo32, hi32 (D+1,) float32 the same for the kernel (+-1e30 for none, one padding entry).
    com_w, support_w (J,) float64: :func:`balance_weights`; has_feet: whether the rig has foot effectors.
    """
    reach = np.asarray(rig.reach, np.float64)
    bones = np.array([len(rig.path_to_root(e.joint)) - 1 for e in rig.effectors], np.float64)
    length = float(reach.mean()) if reach.mean() > 0 else float(rig.bone_lengths.max())
    d_max = ERROR_CLAMP * reach / np.sqrt(np.maximum(bones, 1.0))
    lam = DAMPING * length if damping is None else float(damping)
    lam = max(lam, DAMPING_MIN * length)
    eff_lim = np.stack([reach, d_max], axis=1).astype(np.float32)
    lo, hi = rig.angle_limits()
    jw = np.ones(rig.n_dof) if joint_weights is None else np.asarray(joint_weights, np.float64)
    jmode = np.zeros(rig.n_joints, np.int32)
    for j, joint in enumerate(rig.joints):
        s, k = int(rig.dof_start[j]), joint.dof
        limited = bool(np.any(np.isfinite(lo[s : s + k])) or np.any(np.isfinite(hi[s : s + k])))
        uneven = k == 3 and not np.all(jw[s : s + k] == jw[s])
        jmode[j] = 0 if k == 0 else 1 if (k < 3 or limited or uneven) else 2
        if k == 3 and jmode[j] == 1:
            lo[s + 1], hi[s + 1] = max(lo[s + 1], -EULER_B_MAX), min(hi[s + 1], EULER_B_MAX)
    big = 1e30
    lo32 = np.concatenate([np.clip(lo, -big, big), [0.0]]).astype(np.float32)
    hi32 = np.concatenate([np.clip(hi, -big, big), [0.0]]).astype(np.float32)
    com_w, support_w = balance_weights(rig)
    return dict(length=length, damping=lam, eff_lim=np.ascontiguousarray(eff_lim), jmode=jmode, lo=lo, hi=hi,
                lo32=lo32, hi32=hi32, com_w=com_w, support_w=support_w, has_feet=bool(support_w.any()))
