"""Rig: a joint tree as data (offsets, joint kinds, limits, effectors), and the arrays the kernels read.

A rig is a list of joints in topological order (parent index < child index). Joint j's rest offset
is the vector from its parent to it, in the parent's frame; joint j's rotation turns the bones to
its children. Kinds and their degrees of freedom (DOF), in the order they appear in the angle vector:

- ``ball`` (3): stored as a unit quaternion; reported as intrinsic XYZ Euler angles, R = Rx Ry Rz,
  the values its box limits apply to; optionally a cone limits the swing of its child bones.
- ``universal`` (2): R = R(axes[0], a0) R(axes[1], a1), intrinsic.
- ``hinge`` (1): R = R(axes[0], a0).
- ``fixed`` (0).

Rig topology is runtime data handed to the kernels as index arrays (see :meth:`Rig.arrays`), so a
rig of another shape never recompiles a kernel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from crowd_ik.checks import is_integer, is_number
from crowd_ik.solvers.limits import limit_half_turns, limit_pseudo_angles

# Joint kinds and their DOF counts; the DOF count doubles as the kind code the kernels read.
KINDS = {"fixed": 0, "hinge": 1, "universal": 2, "ball": 3}


@dataclass(frozen=True)
class Joint:
    """One joint: name, parent index (-1 for the root), rest offset from the parent (metres)."""

    name: str
    parent: int
    offset: tuple[float, float, float]
    kind: str = "ball"
    axes: tuple[tuple[float, float, float], ...] = ()
    lo: tuple[float, ...] | None = None
    hi: tuple[float, ...] | None = None
    cone: float | None = None
    radius: float = 0.04

    @property
    def dof(self) -> int:
        return KINDS[self.kind]


@dataclass(frozen=True)
class Effector:
    """An end effector: the world position (and optionally a local axis direction) of one joint."""

    name: str
    joint: int
    weight: float = 1.0
    axis: tuple[float, float, float] | None = None


MAX_EXTENT = 1e4  # metres: offsets, bone lengths, roots and targets beyond this are refused (float32 keeps
# sub-millimetre steps up to there; 1e39 is infinite in float32 and made a NaN pose look converged)


def _vec3(value, what: str, limit: float | None = None) -> tuple[float, float, float]:
    try:
        raw = np.asarray(value)
        if raw.dtype == object or not (np.issubdtype(raw.dtype, np.integer) or np.issubdtype(raw.dtype, np.floating)):
            raise TypeError
        arr = raw.astype(np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected 3 real numbers (got {value!r})") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: expected 3 finite numbers (got {value!r})")
    if limit is not None and np.any(np.abs(arr) > limit):
        raise ValueError(f"{what}: each coordinate must be within +-{limit:g} m (got {value!r})")
    return tuple(float(v) for v in arr)


def _index(value, what: str) -> int:
    """An integer index (Python or numpy integer; not a bool, a float or a string)."""
    if not is_integer(value):
        raise ValueError(f"{what}: expected an integer index (got {value!r})")
    return int(value)


@dataclass(frozen=True)
class Rig:
    """A joint tree with effectors. Build one with :meth:`chain`, :meth:`humanoid` or ``Rig(joints=...)``."""

    joints: tuple[Joint, ...]
    effectors: tuple[Effector, ...] = ()
    dim: int = 3
    name: str = "rig"

    def __post_init__(self):
        joints = tuple(self.joints)
        object.__setattr__(self, "joints", joints)
        if self.dim not in (2, 3):
            raise ValueError(f"rig dim: expected 2 or 3 (got {self.dim!r})")
        if len(joints) < 2:
            raise ValueError(f"rig needs at least one bone, i.e. 2 joints (got {len(joints)})")
        fixed = []
        for j, joint in enumerate(joints):
            where = f"joint {j} ({joint.name!r})"
            if joint.kind not in KINDS:
                raise ValueError(f"{where}: unknown joint kind {joint.kind!r} (expected one of {', '.join(KINDS)})")
            parent = _index(joint.parent, f"{where}: parent")
            if j == 0 and parent != -1:
                raise ValueError(f"{where}: the first joint is the root and needs parent -1 (got {joint.parent})")
            if j > 0 and not (0 <= parent < j):
                raise ValueError(
                    f"{where}: parent must come before its child (parent index in [0, {j - 1}]; got {joint.parent})"
                )
            offset = _vec3(joint.offset, f"{where}: offset", MAX_EXTENT)
            if j > 0 and math.hypot(*offset) <= 0.0:
                raise ValueError(f"{where}: bone length must be positive (got offset {offset})")
            dof = KINDS[joint.kind]
            axes = joint.axes
            if joint.kind in ("hinge", "universal"):
                if not axes:
                    axes = ((0.0, 0.0, 1.0),) if joint.kind == "hinge" else ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
                if len(axes) != dof:
                    raise ValueError(f"{where}: a {joint.kind} joint needs {dof} axes (got {len(axes)})")
                axes = tuple(_unit(_vec3(a, f"{where}: axis"), where) for a in axes)
                if dof == 2 and abs(sum(a * b for a, b in zip(*axes))) > 1e-6:
                    raise ValueError(f"{where}: a universal joint's two axes must be perpendicular (got {axes})")
            elif axes:
                raise ValueError(f"{where}: only hinge and universal joints take axes (kind {joint.kind!r})")
            lo = (-math.inf,) * dof if joint.lo is None else tuple(float(v) for v in joint.lo)
            hi = (math.inf,) * dof if joint.hi is None else tuple(float(v) for v in joint.hi)
            if len(lo) != dof or len(hi) != dof:
                raise ValueError(f"{where}: limits need {dof} values for a {joint.kind} joint (got lo {lo}, hi {hi})")
            for d, (a, b) in enumerate(zip(lo, hi)):
                if math.isnan(a) or math.isnan(b):
                    raise ValueError(f"{where}: limit {d} is NaN")
                if a > b:
                    raise ValueError(f"{where}: limit {d} has lo > hi (got lo={a:g}, hi={b:g})")
            if joint.cone is not None and not (joint.kind == "ball" and 0.0 < joint.cone <= math.pi):
                raise ValueError(f"{where}: cone must be in (0, pi] on a ball joint (got {joint.cone!r} on {joint.kind})")
            if not (math.isfinite(joint.radius) and joint.radius > 0):
                raise ValueError(f"{where}: radius must be positive (got {joint.radius!r})")
            fixed.append(Joint(joint.name, parent, offset, joint.kind, axes, lo, hi, joint.cone, joint.radius))
        object.__setattr__(self, "joints", tuple(fixed))
        effectors = tuple(self.effectors) or (Effector("tip", len(joints) - 1),)
        checked = []
        for e in effectors:
            joint = _index(e.joint, f"effector {e.name!r}: joint")
            if not (0 <= joint < len(joints)):
                raise ValueError(f"effector {e.name!r}: joint index out of range (got {e.joint})")
            if not is_number(e.weight) or not (math.isfinite(e.weight) and e.weight >= 0):
                raise ValueError(f"effector {e.name!r}: weight must be a number >= 0 (got {e.weight!r})")
            axis = e.axis
            if axis is not None:
                axis = _vec3(axis, f"effector {e.name!r}: axis")
                if math.hypot(*axis) < 1e-9:
                    raise ValueError(f"effector {e.name!r}: axis must be non-zero (got {e.axis!r})")
                axis = _unit(axis, f"effector {e.name!r}")
            checked.append(Effector(e.name, joint, float(e.weight), axis))
        object.__setattr__(self, "effectors", tuple(checked))

    # ---------------------------------------------------------------- constructors
    @classmethod
    def chain(cls, n_bones: int, bone_length: float = 1.0, dim: int = 3, lo=None, hi=None, cone=None) -> "Rig":
        """A serial chain of ``n_bones`` bones along +x, root at the origin, one effector at the tip.

        dim=2: hinges about z; the angles are the homework's (each relative to the previous bone,
        the first to the x axis). dim=3: ball joints, unlimited unless ``lo``/``hi`` (radians, per DOF
        of one joint, or a scalar) or ``cone`` (radians) are given.
        """
        if not is_integer(n_bones) or n_bones < 1:
            raise ValueError(f"n_bones: expected a positive integer (got {n_bones!r})")
        if not is_number(bone_length) or not (math.isfinite(bone_length) and 0 < bone_length <= MAX_EXTENT):
            raise ValueError(f"bone_length: expected a positive number up to {MAX_EXTENT:g} m (got {bone_length!r})")
        bone_length = float(bone_length)
        if dim not in (2, 3):
            raise ValueError(f"dim: expected 2 or 3 (got {dim!r})")
        kind, dof = ("hinge", 1) if dim == 2 else ("ball", 3)
        lo_t = None if lo is None else tuple(np.broadcast_to(np.asarray(lo, float), (dof,)))
        hi_t = None if hi is None else tuple(np.broadcast_to(np.asarray(hi, float), (dof,)))
        radius = min(0.04, 0.15 * bone_length) if bone_length < 0.5 else 0.06 * bone_length
        joints = [
            Joint(f"j{j}", j - 1, (0.0, 0.0, 0.0) if j == 0 else (float(bone_length), 0.0, 0.0), kind,
                  ((0.0, 0.0, 1.0),) if kind == "hinge" else (), lo_t, hi_t, cone if kind == "ball" else None, radius)
            for j in range(n_bones)
        ]
        joints.append(Joint("tip", n_bones - 1, (float(bone_length), 0.0, 0.0), "fixed", radius=radius))
        return cls(tuple(joints), (Effector("tip", n_bones),), dim=dim, name=f"chain{n_bones}")

    @classmethod
    def humanoid(cls, height: float = 1.75) -> "Rig":
        """A 21-joint humanoid standing on y=0, facing +z (its left is +x), arms hanging.

        Effectors in order: head, hand_l, hand_r, foot_l (ankle), foot_r. Limits are anatomical
        ranges in intrinsic XYZ Euler angles (x: flexion, y: twist, z: abduction).
        """
        if not (isinstance(height, (int, float)) and math.isfinite(height) and height > 0):
            raise ValueError(f"height: expected a positive number (got {height!r})")
        s = height / 1.75
        d = math.radians
        X, Z = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)

        def lim(*pairs):
            return tuple(d(a) for a, _ in pairs), tuple(d(b) for _, b in pairs)

        def J(name, parent, off, kind="ball", axes=(), limits=None, radius=0.05, cone=None):
            lo, hi = limits if limits else (None, None)
            return Joint(name, parent, tuple(s * v for v in off), kind, axes, lo, hi, cone, radius * s)

        joints = [
            J("pelvis", -1, (0, 0.95, 0), limits=lim((-25, 25), (-40, 40), (-20, 20)), radius=0.11),
            J("spine", 0, (0, 0.10, 0), limits=lim((-30, 40), (-30, 30), (-25, 25)), radius=0.10),
            J("chest", 1, (0, 0.25, 0), limits=lim((-20, 30), (-25, 25), (-20, 20)), radius=0.13),
            J("neck", 2, (0, 0.20, 0), limits=lim((-40, 50), (-60, 60), (-35, 35)), radius=0.05),
            J("head", 3, (0, 0.12, 0), "fixed", radius=0.10),
        ]
        for side, sx in (("l", 1.0), ("r", -1.0)):
            base = len(joints)
            abd = (-20, 170) if sx > 0 else (-170, 20)
            joints += [
                J(f"shoulder_{side}", 2, (0.17 * sx, 0.17, 0), limits=lim((-170, 50), (-80, 80), abd), radius=0.06),
                J(f"elbow_{side}", base, (0, -0.28, 0), "hinge", ((-1.0, 0.0, 0.0),), lim((0, 150)), radius=0.05),
                J(f"wrist_{side}", base + 1, (0, -0.26, 0), "universal", (X, Z), lim((-70, 70), (-30, 30)), radius=0.04),
                J(f"hand_{side}", base + 2, (0, -0.08, 0), "fixed", radius=0.04),
            ]
        for side, sx in (("l", 1.0), ("r", -1.0)):
            base = len(joints)
            abd = (-20, 60) if sx > 0 else (-60, 20)
            joints += [
                J(f"hip_{side}", 0, (0.10 * sx, -0.05, 0), limits=lim((-120, 30), (-40, 40), abd), radius=0.08),
                J(f"knee_{side}", base, (0, -0.42, 0), "hinge", (X,), lim((0, 150)), radius=0.065),
                J(f"ankle_{side}", base + 1, (0, -0.42, 0), "universal", (X, Z), lim((-40, 30), (-20, 20)), radius=0.05),
                J(f"toe_{side}", base + 2, (0, -0.05, 0.14), "fixed", radius=0.04),
            ]
        names = [j.name for j in joints]
        effectors = (
            Effector("head", names.index("head")),
            Effector("hand_l", names.index("hand_l")),
            Effector("hand_r", names.index("hand_r")),
            Effector("foot_l", names.index("ankle_l"), axis=(0.0, 1.0, 0.0)),
            Effector("foot_r", names.index("ankle_r"), axis=(0.0, 1.0, 0.0)),
        )
        return cls(tuple(joints), effectors, dim=3, name="humanoid")

    @classmethod
    def from_gltf(cls, path, effectors=None) -> "Rig":
        """The joint tree of a .glb/.gltf file's skin, at the file's rest pose (crowd_ik.io.gltf)."""
        from crowd_ik.io.gltf import read_gltf_tree

        return cls.from_tree(read_gltf_tree(path, effectors))

    @classmethod
    def from_tree(cls, tree) -> "Rig":
        """A rig from a joint tree read from a file (crowd_ik.io.skeleton.Tree); problems name the file."""
        try:
            joints = tuple(Joint(n, p, o, k, a, radius=r) for n, p, o, k, a, r in tree.joints)
            return cls(joints, tuple(Effector(n, j) for n, j in tree.effectors), name=tree.name)
        except ValueError as exc:
            raise ValueError(f"{tree.source}: {exc}") from None

    # ---------------------------------------------------------------- queries
    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @cached_property
    def dof_start(self) -> np.ndarray:
        """(J,) int32: index of each joint's first DOF in the angle vector."""
        counts = np.array([j.dof for j in self.joints], dtype=np.int32)
        return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)

    @property
    def n_dof(self) -> int:
        return int(sum(j.dof for j in self.joints))

    @property
    def n_effectors(self) -> int:
        return len(self.effectors)

    @property
    def effector_names(self) -> list[str]:
        return [e.name for e in self.effectors]

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    def angle_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi), each (DOF,) float64 radians; +-inf where a DOF is unlimited."""
        lo = np.array([v for j in self.joints for v in j.lo], dtype=np.float64)
        hi = np.array([v for j in self.joints for v in j.hi], dtype=np.float64)
        return lo, hi

    @cached_property
    def constraint_free(self) -> bool:
        """True when every joint is an unlimited ball (or fixed): nothing constrains a FABRIK pose."""
        return all(j.kind in ("ball", "fixed") and j.cone is None and all(math.isinf(v) for v in j.lo + j.hi)
                   for j in self.joints)

    @cached_property
    def bone_lengths(self) -> np.ndarray:
        """(J,) float64: |offset| of each joint (0 for the root)."""
        lengths = np.linalg.norm(np.array([j.offset for j in self.joints]), axis=1)
        lengths[0] = 0.0
        return lengths

    @cached_property
    def children(self) -> tuple[tuple[int, ...], ...]:
        kids: list[list[int]] = [[] for _ in self.joints]
        for j, joint in enumerate(self.joints[1:], start=1):
            kids[joint.parent].append(j)
        return tuple(tuple(k) for k in kids)

    def path_to_root(self, joint: int) -> list[int]:
        """Joint indices from ``joint`` up to the root, inclusive."""
        path = [joint]
        while self.joints[path[-1]].parent >= 0:
            path.append(self.joints[path[-1]].parent)
        return path

    @cached_property
    def reach(self) -> np.ndarray:
        """(E,) float64: length of the bone path from the root joint to each effector."""
        return np.array([self.bone_lengths[self.path_to_root(e.joint)[:-1]].sum() for e in self.effectors])

    @cached_property
    def reach_bound_sq(self) -> np.ndarray:
        """(E,) float64: the squared distance from the root joint beyond which a target is out of reach: the
        reach with a slack for rounding (relative 1e-6, absolute 1e-7 m)."""
        return np.square(self.reach * (1 + 1e-6) + 1e-7)

    def beyond_reach(self, targets: np.ndarray, base: np.ndarray) -> np.ndarray:
        """(N, E) bool: each target (N, E, 3) farther from its character's root joint base (N, 3) than its chain
        reaches (Crowd's UNREACHABLE rule, where the target's weight is positive): the squared length in float64 of
        the difference in the targets' precision, as kernels/report_rows.py statuses computes it."""
        d = (targets - base[:, None, :]).astype(np.float64)
        return np.einsum("nek,nek->ne", d, d) > self.reach_bound_sq

    def root_joints(self, roots: np.ndarray, yaw: np.ndarray) -> np.ndarray:
        """(N, 3) float64: the root joints' world positions of characters standing at roots (N, 3) turned by yaw
        (N,) radians about +y (the root joint sits at the rig's first offset from the root)."""
        off = self.arrays["offset"][0].astype(np.float64)
        c, s = np.cos(yaw), np.sin(yaw)
        return roots + np.stack([c * off[0] + s * off[2], np.full_like(c, off[1]), -s * off[0] + c * off[2]], -1)

    @cached_property
    def arrays(self) -> dict[str, np.ndarray]:
        """The rig as C-contiguous arrays for the kernels (float32 and int32).

        parent (J,), offset (J,3), kind (J,) 0 fixed/1 hinge/2 universal/3 ball, axes (J,2,3),
        dof_start (J,), lo/hi (DOF+1,) (one padding entry so a DOF-less rig still has an array), lim_p (DOF+1, 2)
        their pseudo-angles (solvers.limits.limit_pseudo_angles), lim_h (DOF+1, 4) their half-angles' cosines and
        sines (solvers.limits.limit_half_turns),
        cone (J,) (0 = none), eff_joint (E,), eff_axis (E,3), eff_has_axis (E,), radius (J,), bone (J, 4): the
        unit direction of each joint's offset and its length (the root's: 0), which FABRIK's passes use.
        """
        J, D = self.n_joints, self.n_dof
        axes = np.zeros((J, 2, 3), np.float32)
        for j, joint in enumerate(self.joints):
            for a, ax in enumerate(joint.axes):
                axes[j, a] = ax
        lo, hi = self.angle_limits()
        big = np.float32(1e30)
        out = dict(
            parent=np.array([j.parent for j in self.joints], np.int32),
            offset=np.array([j.offset for j in self.joints], np.float32),
            kind=np.array([KINDS[j.kind] for j in self.joints], np.int32),
            axes=axes,
            dof_start=self.dof_start.astype(np.int32),
            lo=np.concatenate([np.clip(lo, -big, big), [0.0]]).astype(np.float32),
            hi=np.concatenate([np.clip(hi, -big, big), [0.0]]).astype(np.float32),
            lim_p=limit_pseudo_angles(np.append(lo, 0.0), np.append(hi, 0.0)),
            lim_h=limit_half_turns(np.append(lo, 0.0), np.append(hi, 0.0)),
            cone=np.array([j.cone or 0.0 for j in self.joints], np.float32),
            eff_joint=np.array([e.joint for e in self.effectors], np.int32),
            eff_axis=np.array([e.axis or (0.0, 0.0, 0.0) for e in self.effectors], np.float32),
            eff_has_axis=np.array([e.axis is not None for e in self.effectors], np.int32),
            radius=np.array([j.radius for j in self.joints], np.float32),
            child_start=np.concatenate([[0], np.cumsum([len(c) for c in self.children])]).astype(np.int32),
            child_list=np.array([c for kids in self.children for c in kids] or [0], np.int32),
        )
        offset = out["offset"].astype(np.float32)
        length = np.sqrt(offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1] + offset[:, 2] * offset[:, 2])
        direction = offset / np.maximum(length, 1e-30)[:, None]  # (the root's zero offset stays zero)
        out["bone"] = np.concatenate([direction, length[:, None]], axis=1).astype(np.float32)
        assert D == len(lo)
        return {k: np.ascontiguousarray(v) for k, v in out.items()}


def _unit(v: tuple[float, float, float], where: str) -> tuple[float, float, float]:
    n = math.sqrt(sum(c * c for c in v))
    if n == 0:
        raise ValueError(f"{where}: axis must be non-zero")
    return tuple(c / n for c in v)


__all__ = ["Rig", "Joint", "Effector", "KINDS"]
