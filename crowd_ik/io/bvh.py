"""Reading BVH motion capture: ``rig, motion = load_bvh(path, units="auto", effectors=None, root=0)``.

What a file may hold: one or more ROOT hierarchies (``root=k`` picks the k-th); per joint an OFFSET and
CHANNELS naming any of X/Y/Z position and rotation, in any order (rotation channels compose intrinsic
in the listed order, R = R_first R_second R_third; translation applies before rotation); End Sites.
The rig (crowd_ik.rig) keeps the BVH joint names in file order; an End Site becomes a fixed leaf named
``<parent>_end``. A joint's rotation channels choose its kind: 3 -> ball, 2 -> universal about those
two axes, 1 -> hinge about that axis, 0 -> fixed. The root's position channels move the character
root (Crowd.set_roots; the root joint's OFFSET stays its rig offset); position channels on another
joint must hold one value over the clip (a rig's bones have fixed lengths): it is added to the offset.

Units: ``motion.scale`` is metres per file unit: 1 for "m", 0.01 for "cm"; "auto" takes "cm" when the
skeleton at rest is taller (its largest extent) than 10 units. The world is y up, as in BVH.
Effectors: crowd_ik.io.skeleton.find_effectors. Problems are ``ValueError("path:line: problem")``
(truncated files, channel counts that do not match, unknown keywords or channels, repeated joint
names, NaN or infinite numbers); the nesting of a BVH cannot express a cycle.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from crowd_ik.io.skeleton import axis_matrix, forward, make_tree, matrix_to_euler
from crowd_ik.rig import MAX_EXTENT, Rig

UNITS = {"m": 1.0, "cm": 0.01}
AUTO_CM_ABOVE = 10.0  # file units: a skeleton taller than this is taken to be in centimetres
_CHANNELS = {f"{a}{kind}": (kind, a) for a in "XYZ" for kind in ("position", "rotation")}
_CONSTANT = 1e-6  # relative spread under which a non-root joint's position channel counts as constant


@dataclass
class _Node:
    name: str
    parent: int
    line: int
    offset: np.ndarray | None = None
    channels: list[str] = field(default_factory=list)
    column: int = 0  # first column of its channels in a frame line
    end: bool = False  # an End Site


class Motion:
    """A BVH clip on its rig: n_frames, frame_time (s), fps, scale (metres per file unit), units, source.

    roots() -> (positions (F, 3), yaw (F,) zeros): the character root of each frame for Crowd.set_roots;
    angles() -> (F, DOF) radians for Crowd.set_angles; joint_positions() -> (F, J, 3) world metres.
    """

    def __init__(self, rig: Rig, frame_time: float, scale: float, units: str, base: np.ndarray,
                 local: np.ndarray, angles: np.ndarray, source: str):
        self.rig, self.frame_time, self.scale, self.units, self.source = rig, frame_time, scale, units, source
        self._base, self._local, self._angles = base, local, angles
        self._positions = None

    def __repr__(self) -> str:
        return (f"Motion({self.source!r}, {self.n_frames} frames at {self.fps:g} fps, {self.rig.n_joints} joints, "
                f"units {self.units})")

    @property
    def n_frames(self) -> int:
        return len(self._base)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return (self.n_frames - 1) * self.frame_time

    def roots(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (F, 3) float64 metres, yaw (F,) zeros): the root joint sits its rig offset above these."""
        return self._base.copy(), np.zeros(self.n_frames)

    def local_rotations(self) -> np.ndarray:
        """(F, J, 3, 3) float64: each joint's rotation in its parent's frame."""
        return self._local.copy()

    def angles(self) -> np.ndarray:
        """(F, DOF) float64 radians in the rig's convention (ball joints: intrinsic XYZ Euler)."""
        return self._angles.copy()

    def joint_positions(self) -> np.ndarray:
        """(F, J, 3) float64 world joint positions, metres, y up, joints in the rig's order."""
        if self._positions is None:
            self._positions = forward(self.rig, self._base, np.zeros(self.n_frames), self._local)[0]
        return self._positions.copy()


def _lines(text: str):
    """(line number, tokens) of the non-blank lines; a trailing '{' on a line is a line of its own."""
    for number, raw in enumerate(text.splitlines(), start=1):
        tokens = raw.split()
        if not tokens:
            continue
        if len(tokens) > 1 and tokens[-1] == "{":
            yield number, tokens[:-1]
            yield number, ["{"]
        else:
            yield number, tokens


def _floats(path: str, number: int, words: list[str], what: str, count: int) -> np.ndarray:
    if len(words) != count:
        raise ValueError(f"{path}:{number}: {what} needs {count} numbers (got {len(words)}: {' '.join(words)!r})")
    try:
        values = np.array([float(w) for w in words])
    except ValueError:
        raise ValueError(f"{path}:{number}: {what}: not a number in {' '.join(words)!r}") from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise ValueError(f"{path}:{number}: {what}: value {bad[0] + 1} is not a finite number (got {words[bad[0]]!r})")
    return values


def _hierarchy(path: str, lines) -> tuple[list[_Node], int]:
    """Parse HIERARCHY up to MOTION: (nodes in file order, the MOTION line's number)."""
    first = next(lines, None)
    if first is None:
        raise ValueError(f"{path}:1: empty file (expected HIERARCHY)")
    if first[1] != ["HIERARCHY"]:
        raise ValueError(f"{path}:{first[0]}: expected HIERARCHY (got {' '.join(first[1])!r})")
    nodes: list[_Node] = []
    stack: list[int] = []  # open blocks (node indices)
    pending: int | None = None  # a node whose '{' is due
    last = first[0]
    for number, tokens in lines:
        last = number
        key = tokens[0]
        if pending is not None:
            if tokens != ["{"]:
                raise ValueError(f"{path}:{number}: expected '{{' after line {nodes[pending].line} (got {' '.join(tokens)!r})")
            stack.append(pending)
            pending = None
            continue
        top = nodes[stack[-1]] if stack else None
        if key in ("ROOT", "JOINT"):
            if (key == "ROOT") != (top is None) or (top is not None and top.end):
                where = "inside a joint" if key == "ROOT" else ("inside an End Site" if top else "outside a ROOT")
                raise ValueError(f"{path}:{number}: {key} {where}")
            if len(tokens) < 2:
                raise ValueError(f"{path}:{number}: {key} needs a joint name")
            nodes.append(_Node(" ".join(tokens[1:]), stack[-1] if stack else -1, number))
            pending = len(nodes) - 1
        elif key == "End" and tokens[1:] == ["Site"]:
            if top is None or top.end:
                raise ValueError(f"{path}:{number}: End Site outside a joint")
            nodes.append(_Node(f"{top.name}_end", stack[-1], number, end=True))
            pending = len(nodes) - 1
        elif key == "OFFSET":
            if top is None or top.offset is not None:
                raise ValueError(f"{path}:{number}: OFFSET {'outside a joint' if top is None else 'given twice'}")
            top.offset = _floats(path, number, tokens[1:], "OFFSET", 3)
        elif key == "CHANNELS":
            if top is None or top.end or top.channels:
                what = "outside a joint" if top is None else ("in an End Site" if top.end else "given twice")
                raise ValueError(f"{path}:{number}: CHANNELS {what}")
            try:
                count = int(tokens[1])
            except (IndexError, ValueError):
                raise ValueError(f"{path}:{number}: CHANNELS needs a count (got {' '.join(tokens)!r})") from None
            names = tokens[2:]
            if count != len(names) or count > 6:
                raise ValueError(f"{path}:{number}: CHANNELS {count} lists {len(names)} channels "
                                 f"({' '.join(names) or 'none'})" + ("; at most 6" if count > 6 else ""))
            for name in names:
                if name.capitalize() not in _CHANNELS:
                    raise ValueError(f"{path}:{number}: unknown channel {name!r} (expected X/Y/Z position/rotation)")
            canon = [n.capitalize() for n in names]
            if len(set(canon)) != len(canon):
                raise ValueError(f"{path}:{number}: CHANNELS repeats a channel ({' '.join(names)})")
            top.channels = canon
        elif key == "}":
            if top is None:
                raise ValueError(f"{path}:{number}: '}}' closes nothing")
            if top.offset is None:
                raise ValueError(f"{path}:{number}: {'End Site' if top.end else 'joint ' + repr(top.name)} "
                                 f"(line {top.line}) has no OFFSET")
            stack.pop()
        elif key == "MOTION":
            if stack or pending is not None or not nodes:
                raise ValueError(f"{path}:{number}: MOTION before the hierarchy is complete"
                                 + (f" (joint {nodes[stack[-1]].name!r} of line {nodes[stack[-1]].line} is open)"
                                    if stack else ""))
            return nodes, number
        else:
            raise ValueError(f"{path}:{number}: unexpected {' '.join(tokens)!r} in the hierarchy")
    open_at = f" (joint {nodes[stack[-1]].name!r} of line {nodes[stack[-1]].line} is open)" if stack else ""
    raise ValueError(f"{path}:{last}: truncated: the file ends before MOTION{open_at}")


def _motion(path: str, lines, motion_line: int, n_columns: int) -> tuple[np.ndarray, float]:
    """Parse 'Frames: N', 'Frame Time: t' and the N frame lines: ((N, n_columns) values, t)."""
    header = {}
    last = motion_line
    for want in ("Frames:", "Frame Time:"):
        item = next(lines, None)
        if item is None:
            raise ValueError(f"{path}:{last}: truncated: expected '{want}'")
        last, tokens = item
        words = want.split()
        if tokens[: len(words)] != words or len(tokens) != len(words) + 1:
            raise ValueError(f"{path}:{last}: expected '{want} <number>' (got {' '.join(tokens)!r})")
        header[want] = (last, tokens[-1])
    line, text = header["Frames:"]
    try:
        n = int(text)
    except ValueError:
        raise ValueError(f"{path}:{line}: Frames: expected a whole number (got {text!r})") from None
    if n < 1:
        raise ValueError(f"{path}:{line}: Frames: a clip needs at least one frame (got {n})")
    line, text = header["Frame Time:"]
    try:
        frame_time = float(text)
    except ValueError:
        frame_time = math.nan
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise ValueError(f"{path}:{line}: Frame Time: expected a positive number of seconds (got {text!r})")
    values = np.empty((n, n_columns))
    k = 0
    for number, tokens in lines:
        if k == n:
            raise ValueError(f"{path}:{number}: more frame lines than 'Frames: {n}'")
        if len(tokens) != n_columns:
            raise ValueError(f"{path}:{number}: frame {k} has {len(tokens)} values; the channels need {n_columns}")
        values[k] = _floats(path, number, tokens, f"frame {k}", n_columns)
        k += 1
        last = number
    if k < n:
        raise ValueError(f"{path}:{last}: truncated: {k} frame lines of 'Frames: {n}'")
    return values, frame_time


def load_bvh(path, units: str = "auto", effectors=None, root: int = 0) -> tuple[Rig, Motion]:
    """(rig, motion) of a BVH file (see the module docstring)."""
    path = os.fspath(path)
    if units not in (*UNITS, "auto"):
        raise ValueError(f"units: expected 'm', 'cm' or 'auto' (got {units!r})")
    if isinstance(root, bool) or not isinstance(root, (int, np.integer)) or root < 0:
        raise ValueError(f"root: expected an index >= 0 (got {root!r})")
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        text = Path(path).read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a text file ({exc.reason} at byte {exc.start})") from None
    lines = _lines(text)
    nodes, motion_line = _hierarchy(path, lines)
    column = 0
    for node in nodes:
        node.column = column
        column += len(node.channels)
    values, frame_time = _motion(path, lines, motion_line, column)
    roots = [i for i, node in enumerate(nodes) if node.parent < 0]
    if root >= len(roots):
        raise ValueError(f"root: {path} has {len(roots)} ROOT hierarch{'y' if len(roots) == 1 else 'ies'} "
                         f"(got root={root})")
    start = roots[root]
    stop = roots[root + 1] if root + 1 < len(roots) else len(nodes)
    return _build(path, nodes[start:stop], start, values, frame_time, units, effectors)


def _build(path: str, nodes: list[_Node], start: int, values: np.ndarray, frame_time: float, units: str,
           effectors) -> tuple[Rig, Motion]:
    F, J = len(values), len(nodes)
    seen: dict[str, int] = {}
    for node in nodes:
        if node.end:
            base, k = node.name, 1
            while node.name in seen:
                node.name, k = f"{base}{k}", k + 1
        if node.name in seen:
            raise ValueError(f"{path}:{node.line}: joint name {node.name!r} repeats line {seen[node.name]}'s")
        seen[node.name] = node.line
    parents = [n.parent - start if n.parent >= 0 else -1 for n in nodes]
    offsets = np.array([n.offset for n in nodes])
    base = np.zeros((F, 3))
    local = np.broadcast_to(np.eye(3), (F, J, 3, 3)).copy()
    kinds, axes, rotation_columns = [], [], []
    for j, node in enumerate(nodes):
        rotation, columns = [], []
        for c, name in enumerate(node.channels):
            kind, axis = _CHANNELS[name]
            column = values[:, node.column + c]
            if kind == "rotation":
                rotation.append(axis)
                local[:, j] = local[:, j] @ axis_matrix(axis, np.radians(column))
                columns.append(np.radians(column))
            elif j == 0:
                base[:, "XYZ".index(axis)] = column
            else:
                spread = float(column.max() - column.min())
                if spread > _CONSTANT * max(1.0, float(np.abs(column).max())):
                    raise ValueError(f"{path}:{node.line}: joint {node.name!r}: its {name} channel moves "
                                     f"(by {spread:g}); only the root may translate, a rig's bones keep their lengths")
                offsets[j, "XYZ".index(axis)] += column[0]
        rotation_columns.append(columns)
        kinds.append({3: "ball", 2: "universal", 1: "hinge", 0: "fixed"}[len(rotation)])
        axes.append(tuple(tuple(float(v) for v in np.eye(3)["XYZ".index(a)]) for a in rotation)
                    if len(rotation) < 3 else ())
    scale, unit = _scale(units, parents, offsets)
    offsets = offsets * scale
    base = base * scale
    extent = max(float(np.abs(offsets).max()), float(np.abs(base).max()))
    if extent > MAX_EXTENT:
        raise ValueError(f"{path}:{nodes[0].line}: the skeleton or its motion reaches {extent:g} m "
                         f"(limit {MAX_EXTENT:g} m; wrong units?)")
    names = [n.name for n in nodes]
    rig = Rig.from_tree(make_tree(names, parents, offsets, kinds, axes, effectors, Path(path).stem, path))
    angles = np.zeros((F, rig.n_dof))
    for j, joint in enumerate(rig.joints):
        s = int(rig.dof_start[j])
        if joint.kind == "ball":
            angles[:, s : s + 3] = matrix_to_euler(local[:, j], "XYZ")
        elif joint.dof:
            angles[:, s : s + joint.dof] = np.stack(rotation_columns[j], axis=1)
    return rig, Motion(rig, frame_time, scale, unit, base, local, angles, path)


def _scale(units: str, parents: list[int], offsets: np.ndarray) -> tuple[float, str]:
    """(metres per file unit, "m" | "cm"): as given, or guessed from the rest pose's largest extent."""
    if units != "auto":
        return UNITS[units], units
    rest = np.zeros_like(offsets)
    for j, p in enumerate(parents):
        rest[j] = offsets[j] + (rest[p] if p >= 0 else 0.0)
    extent = float(np.ptp(rest, axis=0).max()) if len(rest) else 0.0
    return (UNITS["cm"], "cm") if extent > AUTO_CM_ABOVE else (UNITS["m"], "m")


__all__ = ["load_bvh", "Motion", "UNITS"]
