"""Joint trees read from files (BVH, glTF) as plain data for ``Rig.from_tree``, and the host rotation maths
their readers and writers share: effectors found by name, zero-length bones, joint angles <-> rotation
matrices, FK. (No import of crowd_ik.rig: Rig.from_gltf imports the glTF reader, which imports this.)

Effectors: head, hand_l, hand_r, foot_l, foot_r (in that order, as Rig.humanoid) when every one of them
matches a joint name (case-insensitive words: "LeftHand", "hand_l", "l_wrist", "mixamorig:RightFoot",
"lfoot"; hand may be a wrist, foot an ankle); otherwise one effector per leaf joint, named as the leaf;
or the joints a caller names.

A Rig's bones need a positive length, but files often put a joint on its parent (CMU's hip joints, an
End Site at OFFSET 0): such an offset becomes ZERO_BONE metres along +y, which moves the joints below
it by at most that much.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # annotations only: rig.py builds rigs from these modules' trees
    from crowd_ik.rig import Rig


ZERO_BONE = 1e-6  # metres: the length a zero offset is given
HUMANOID_EFFECTORS = ("head", "hand_l", "hand_r", "foot_l", "foot_r")
_PARTS = {"head": ("head", None), "hand": ("hand", "wrist"), "foot": ("foot", "ankle")}
_SIDES = {"l": "l", "left": "l", "r": "r", "right": "r"}


def _words(name: str) -> list[str]:
    """Lower-case words of a joint name: split at non-letters and at camelCase steps ("LHand" -> l, hand)."""
    return [w.lower() for w in re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+", name)]


def _match(name: str, part: str, side: str | None) -> tuple[int, int] | None:
    """(rank, word count) when the name names this body part (rank 0 its main word, 1 the other), else None."""
    words = _words(name)
    if "end" in words or "site" in words:
        return None
    found_side, rank = None, None
    for w in words:
        if w in _SIDES:
            found_side = found_side or _SIDES[w]
        for r, word in enumerate(_PARTS[part]):
            if word is None:
                continue
            if w == word or (len(w) == len(word) + 1 and w[1:] == word and w[0] in "lr"):
                rank = r if rank is None else min(rank, r)
                if w != word:
                    found_side = found_side or w[0]
    if rank is None or found_side != side:
        return None
    return rank, len(words)


def find_effectors(names: list[str], leaves: list[int], given, source: str) -> tuple[tuple[str, int], ...]:
    """The rig's effectors (see the module docstring). given: None, a list of joint names, or a mapping
    {effector name: joint name}. Returns (effector name, joint index) pairs."""
    index = {n: j for j, n in reversed(list(enumerate(names)))}
    if given is not None:
        pairs = list(given.items()) if isinstance(given, dict) else [(n, n) for n in given]
        if not pairs:
            raise ValueError(f"{source}: effectors: expected at least one joint name (got {given!r})")
        out = []
        for eff, joint in pairs:
            if not isinstance(joint, str) or joint not in index:
                shown = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")
                raise ValueError(f"{source}: effectors: no joint named {joint!r} (joints: {shown})")
            out.append((str(eff), index[joint]))
        return tuple(out)
    found = []
    for eff in HUMANOID_EFFECTORS:
        part, _, side = eff.partition("_")
        scored = [(m, j) for j, n in enumerate(names) if (m := _match(n, part, side or None)) is not None]
        if not scored:
            break
        found.append((eff, min(scored)[1]))
    if len(found) == len(HUMANOID_EFFECTORS) and len({j for _, j in found}) == len(found):
        return tuple(found)
    return tuple((names[j], j) for j in leaves)


@dataclass(frozen=True)
class Tree:
    """A joint tree read from a file: joints (name, parent, offset metres, kind, axes, radius) in topological
    order, effectors (name, joint index), the rig's name and the file it came from (for error messages)."""

    name: str
    source: str
    joints: tuple
    effectors: tuple


def make_tree(names, parents, offsets, kinds, axes, effectors, name: str, source: str) -> Tree:
    """A Tree from joint data in topological order (offsets in metres; zero ones become ZERO_BONE). Each
    joint's radius (its limb's, from the parent) is a fifth of its bone, within 1.5-6 cm."""
    joints = []
    for j, joint_name in enumerate(names):
        off = tuple(float(v) for v in offsets[j])
        if j > 0 and math.hypot(*off) == 0.0:
            off = (0.0, ZERO_BONE, 0.0)
        radius = 0.06 if j == 0 else min(max(0.2 * math.hypot(*off), 0.015), 0.06)
        joints.append((joint_name, int(parents[j]), off, kinds[j], tuple(axes[j]), radius))
    leaves = [j for j in range(len(names)) if j not in set(int(p) for p in parents)]
    return Tree(name, source, tuple(joints), find_effectors(list(names), leaves, effectors, source))


# ------------------------------------------------------------------------------------------------
# rotations


def axis_matrix(axis: str, angle: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation about the world axis 'X', 'Y' or 'Z' by angle (...) radians."""
    angle = np.asarray(angle, np.float64)
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(angle), np.zeros_like(angle)
    rows = {
        "X": [[o, z, z], [z, c, -s], [z, s, c]],
        "Y": [[c, z, s], [z, o, z], [-s, z, c]],
        "Z": [[c, -s, z], [s, c, z], [z, z, o]],
    }[axis]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def axis_angle_matrix(axis, angle) -> np.ndarray:
    """(..., 3, 3) rotation about the unit axis (3,) by angle (...) radians (Rodrigues)."""
    k = np.asarray(axis, np.float64)
    angle = np.asarray(angle, np.float64)[..., None, None]
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def joint_matrices(rig: Rig, angles) -> np.ndarray:
    """(F, D) radians in the rig's convention -> (F, J, 3, 3) local joint rotations."""
    a = np.asarray(angles, np.float64).reshape(-1, rig.n_dof)
    out = np.broadcast_to(np.eye(3), (len(a), rig.n_joints, 3, 3)).copy()
    for j, joint in enumerate(rig.joints):
        s = int(rig.dof_start[j])
        if joint.kind == "ball":
            out[:, j] = axis_matrix("X", a[:, s]) @ axis_matrix("Y", a[:, s + 1]) @ axis_matrix("Z", a[:, s + 2])
        elif joint.kind in ("hinge", "universal"):
            for d, ax in enumerate(joint.axes):
                out[:, j] = out[:, j] @ axis_angle_matrix(ax, a[:, s + d])
    return out


def matrix_to_euler(R: np.ndarray, order: str) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 3) radians, intrinsic in `order` (three different axes).

    The middle angle is in [-pi/2, pi/2]; at gimbal lock (middle angle +-pi/2) the third is 0.
    """
    i, j, k = ("XYZ".index(c) for c in order)
    if len({i, j, k}) != 3:
        raise ValueError(f"matrix_to_euler: order must name three different axes (got {order!r})")
    s = 1.0 if (i, j, k) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    R = np.asarray(R, np.float64)
    cos_b = np.hypot(R[..., i, i], R[..., i, j])
    b = np.arctan2(s * R[..., i, k], cos_b)
    lock = cos_b < 1e-9
    a = np.where(lock, np.arctan2(s * R[..., k, j], R[..., j, j]), np.arctan2(-s * R[..., j, k], R[..., k, k]))
    c = np.where(lock, 0.0, np.arctan2(-s * R[..., i, j], R[..., i, i]))
    return np.stack([a, b, c], -1)


def matrix_to_quat(R) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (x, y, z, w), w >= 0."""
    R = np.asarray(R, np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # each of the four squared magnitudes from the trace; divide by the largest (Shepperd's method)
    q2 = np.stack([1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22, 1 + m00 + m11 + m22], -1)
    k = np.argmax(q2, axis=-1)
    d = {
        0: (q2[..., 0], R[..., 1, 0] + R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] - R[..., 1, 2]),
        1: (R[..., 1, 0] + R[..., 0, 1], q2[..., 1], R[..., 2, 1] + R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0]),
        2: (R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] + R[..., 1, 2], q2[..., 2], R[..., 1, 0] - R[..., 0, 1]),
        3: (R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1], q2[..., 3]),
    }
    q = np.zeros(R.shape[:-2] + (4,))
    for case, parts in d.items():
        sel = k == case
        q[sel] = np.stack(parts, -1)[sel] / (2.0 * np.sqrt(q2[..., case][sel]))[..., None]
    q *= np.where(q[..., 3:] < 0, -1.0, 1.0)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def yaw_matrix(yaw) -> np.ndarray:
    """(..., 3, 3) rotation about +y by yaw (...) radians (+z turns toward +x)."""
    return axis_matrix("Y", yaw)


def forward(rig: Rig, base, yaw, local) -> tuple[np.ndarray, np.ndarray]:
    """(world positions (F, J, 3), world rotations (F, J, 3, 3)) of a body whose root is at base (F, 3)
    turned by yaw (F,), from local rotations (F, J, 3, 3): the Crowd's FK, in float64 on the host."""
    local = np.asarray(local, np.float64)
    F, J = local.shape[:2]
    pos = np.zeros((F, J, 3))
    rot = np.zeros((F, J, 3, 3))
    top = yaw_matrix(np.asarray(yaw, np.float64).reshape(F))
    base = np.asarray(base, np.float64).reshape(F, 3)
    for j, joint in enumerate(rig.joints):
        p_pos, p_rot = (base, top) if joint.parent < 0 else (pos[:, joint.parent], rot[:, joint.parent])
        pos[:, j] = p_pos + p_rot @ np.asarray(joint.offset)
        rot[:, j] = p_rot @ local[:, j]
    return pos, rot


__all__ = ["ZERO_BONE", "HUMANOID_EFFECTORS", "Tree", "find_effectors", "make_tree", "axis_matrix", "matrix_to_euler",
           "axis_angle_matrix",
           "joint_matrices", "matrix_to_quat", "yaw_matrix", "forward"]
