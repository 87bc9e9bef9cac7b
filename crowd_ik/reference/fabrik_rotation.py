"""NumPy twin of kernels/fabrik_rotation.py: FABRIK's steps for full rotation targets, over all characters."""

from __future__ import annotations

import numpy as np

from crowd_ik.geometry.quat import axis_angle, qconj, qmul, qnormalize, qrot, twist_angle


def extended_toward(rig, j, length, toward, rot, rot_t, rot_w):
    """Twin of fabrik_rotation.extended_toward for joint j: (N, 3) directions from its proposal to its parent's."""
    if rig.joints[j].kind != "fixed":
        return toward
    off = rig.arrays["offset"][j].astype(np.float64)
    for e, eff in enumerate(rig.effectors):
        if eff.joint == j:
            d = -qrot(qmul(rot_t[:, e], qconj(rot[:, j])), np.broadcast_to(off, toward.shape)) / length
            toward = np.where((rot_w[:, e] > 0)[:, None], d, toward)
    return toward


def turn_onto_targets(rig, j, q, inv_base, pos_j, pos, wrot, rot_t, rot_w, move):
    """Twin of fabrik_rotation.turn_onto_targets for joint j over all characters."""
    out = q
    for e, eff in enumerate(rig.effectors):
        has = rot_w[:, e] > 0
        k = eff.joint
        if move[e, 0] == j:
            turn = qmul(qconj(wrot[:, j]), wrot[:, k])
            out = np.where(has[:, None], qnormalize(qmul(inv_base, qmul(rot_t[:, e], qconj(turn)))), out)
        elif move[e, 1] == j:
            a = pos[:, move[e, 0]] - pos_j
            n2 = np.sum(a * a, -1)
            a = a / np.sqrt(np.maximum(n2, 1e-30))[:, None]
            ang = twist_angle(qmul(rot_t[:, e], qconj(wrot[:, k])), a)
            swivelled = qnormalize(qmul(axis_angle(qrot(inv_base, a), ang), out))
            out = np.where((has & (n2 > 1e-12))[:, None], swivelled, out)
    return out


def rotation_error(rig, wrot, rot_t, rot_w):
    """(N,) max over effectors with rot_w > 0 of 2 acos |<q, q_target>|."""
    q = wrot[:, rig.arrays["eff_joint"]]
    ang = 2.0 * np.arccos(np.clip(np.abs(np.sum(q * rot_t, -1)), 0.0, 1.0))
    return np.max(np.where(rot_w > 0, ang, 0.0), axis=1)
