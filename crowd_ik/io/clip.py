"""Motion clips: every body's root transform and joint angles per video frame (.npz), and BVH.

A clip (`crowd-ik play SCENE --clip F.npz`) holds one entry per rendered video frame f, taken
after the frame's simulation: the poses of the last world step (the video draws poses
interpolated between the last two steps; a clip keeps the steps' exact poses, so FK of its angles
gives its joint positions). Three groups of bodies, each with its own rig: `characters` (the
crowd), `shooters` and `player`. Keys of the .npz (F frames; n bodies, J joints, D angles per group):

    format          "crowd_ik.clip/1"
    scene, scene_toml   the scene's name and every effective value (TOML)
    fps             video frames per second (the clip's frame rate)
    frame (F,)      video frame index;  world_time (F,) s;  time_scale (F,)
    camera_position (F, 3), camera_look_at (F, 3) float64 metres; camera_fov_deg (F,) vertical
                    degrees: the camera of each frame (it follows the player in camera.mode "follow")
    groups          ("characters", "shooters", "player")
    <g>_index (n,)  which bodies of the group were recorded (characters: all, or a selection)
    <g>_root (F, n, 3) float32   world position of the root joint (metres, y up)
    <g>_yaw (F, n) float32       heading about +y, radians (+z turns toward +x)
    <g>_angles (F, n, D) float32 joint angles, radians (rig.py: ball joints intrinsic XYZ Euler,
                                 hinge and universal angles about their axes); the root joint's
                                 rotation applies after the yaw
    <g>_joints (F, n, J, 3) float32  world joint positions (FK of the above)
    <g>_alive (F, n) bool        False once a character is hit or a shooter downed (its pose is then
                                 the last one solved); the player is always True
    <g>_rig                      rig name;  <g>_joint_names (J,);  <g>_parents (J,) int32 (-1: root)
    <g>_offsets (J, 3) float32   rest offset of each joint from its parent, in the parent's frame, metres
    <g>_kinds (J,)               "ball" | "universal" | "hinge" | "fixed"
    <g>_axes (J, 2, 3) float32   hinge/universal axes;  <g>_dof_start (J,) int32: first angle of each joint

FK (clip_joint_positions): p_0 = root, R_0 = Ry(yaw) R(angles of joint 0); for j > 0,
p_j = p_parent + R_parent offset_j and R_j = R_parent R(angles of j).

BVH (`crowd-ik export SCENE --bvh OUT.bvh --character K`): one body's motion, in metres (Blender:
import with scale 1), y up, Frame Time = 1 / fps; `--characters K,L,...` writes one ROOT per
character, in that order, its joint names prefixed c<K>_. ROOT is the rig's root joint at OFFSET 0 with
channels Xposition Yposition Zposition Yrotation Xrotation Zrotation (its world position, and yaw
times its own rotation as intrinsic Y-X-Z Euler angles); every other joint has Xrotation Yrotation
Zrotation, intrinsic X-Y-Z, so a ball joint's channels are its angles in degrees. A fixed joint
with no children that is its parent's only child becomes the parent's End Site; other fixed joints
keep three zero rotation channels. Channel values are degrees, intrinsic in the listed order
(R = R_first R_second R_third), as Blender and most tools read them.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from crowd_ik.geometry import fk as ref_fk
from crowd_ik.geometry.quat import qmul, qrot
from crowd_ik.io.skeleton import axis_matrix, matrix_to_euler
from crowd_ik.rig import Joint, Rig

FORMAT = "crowd_ik.clip/1"
GROUPS = ("characters", "shooters", "player")
MAX_CLIP_BYTES = 2 * 2**30  # a clip is held in memory while it is recorded
ROOT_ORDER = "YXZ"  # BVH root rotation channels: heading first
JOINT_ORDER = "XYZ"  # the rig's ball-joint Euler order
_PER_FRAME = ("root", "yaw", "angles", "joints", "alive")
_RIG_KEYS = ("rig", "joint_names", "parents", "offsets", "kinds", "axes", "dof_start")


# ------------------------------------------------------------------------------------------------
# rigs as arrays


def rig_arrays(rig: Rig) -> dict[str, np.ndarray]:
    """The rig's joint data as arrays (the <g>_ keys of a clip, without the prefix)."""
    axes = np.zeros((rig.n_joints, 2, 3), np.float32)
    for j, joint in enumerate(rig.joints):
        for a, ax in enumerate(joint.axes):
            axes[j, a] = ax
    return {
        "rig": np.array(rig.name),
        "joint_names": np.array(rig.joint_names),
        "parents": np.array([j.parent for j in rig.joints], np.int32),
        "offsets": np.array([j.offset for j in rig.joints], np.float32),
        "kinds": np.array([j.kind for j in rig.joints]),
        "axes": axes,
        "dof_start": rig.dof_start.astype(np.int32),
    }


def rig_from_arrays(data, group: str, source: str = "clip") -> Rig:
    """The Rig of a clip's group (joint tree, kinds and axes; no limits, one effector at the end)."""
    names = [str(n) for n in data[f"{group}_joint_names"]]
    parents = np.asarray(data[f"{group}_parents"])
    offsets = np.asarray(data[f"{group}_offsets"], np.float64)
    kinds = [str(k) for k in data[f"{group}_kinds"]]
    axes = np.asarray(data[f"{group}_axes"], np.float64)
    joints = []
    for j, name in enumerate(names):
        n_axes = {"hinge": 1, "universal": 2}.get(kinds[j], 0)
        joints.append(Joint(name, int(parents[j]), tuple(offsets[j]), kinds[j],
                            tuple(tuple(a) for a in axes[j, :n_axes])))
    try:
        return Rig(tuple(joints), name=str(data[f"{group}_rig"]))
    except ValueError as exc:
        raise ValueError(f"{source}: {group}: bad rig ({exc})") from None


# ------------------------------------------------------------------------------------------------
# recording


def _group_crowds(world) -> list:
    return [("characters", world.characters.crowd), ("shooters", world.shooters.crowd), ("player", world.player.crowd)]


def clip_bytes(world, frames: int, characters=None) -> int:
    """Bytes a clip of `frames` frames of `world` takes (characters: count recorded, or all)."""
    total = 0
    for group, crowd in _group_crowds(world):
        n = crowd.n if group != "characters" or characters is None else len(characters)
        rig = crowd.rig
        total += n * (4 * (3 + 1 + rig.n_dof + 3 * rig.n_joints) + 1)
    return int(frames) * total + (24 + 56) * int(frames)


class ClipRecorder:
    """Records a World frame by frame into preallocated arrays; `save` writes the .npz.

    frames: how many frames will be added (the arrays' length); characters: indices of the
    characters to record (default all). Refuses (ValueError) a clip over MAX_CLIP_BYTES.
    """

    def __init__(self, world, frames: int, characters=None, what: str = "--clip"):
        n_chars = world.n
        if characters is not None:
            characters = np.asarray(characters, np.int64).reshape(-1)
            if characters.size == 0 or characters.min() < 0 or characters.max() >= n_chars:
                raise ValueError(f"{what}: character indices must be in [0, {n_chars - 1}] "
                                 f"(got {characters.tolist()[:8]})")
        need = clip_bytes(world, frames, characters)
        if need > MAX_CLIP_BYTES:
            raise ValueError(f"{what}: {frames} frames of {n_chars} characters take {need / 2**30:.1f} GiB "
                             f"(limit {MAX_CLIP_BYTES / 2**30:.0f} GiB); record fewer frames (--frames)")
        self.capacity = int(frames)
        self.count = 0
        self.scene = world.scene
        self.fps = float(world.scene.video.fps)
        F = self.capacity
        self.frame = np.zeros(F, np.int32)
        self.world_time = np.zeros(F, np.float64)
        self.time_scale = np.zeros(F, np.float64)
        self.camera_position = np.zeros((F, 3), np.float64)
        self.camera_look_at = np.zeros((F, 3), np.float64)
        self.camera_fov_deg = np.zeros(F, np.float64)
        self.groups = {}
        for group, crowd in _group_crowds(world):
            index = np.arange(crowd.n) if group != "characters" or characters is None else characters
            rig = crowd.rig
            n, J, D = len(index), rig.n_joints, rig.n_dof
            self.groups[group] = {
                "crowd": crowd,
                "index": index,
                "rig": rig,
                "root": np.zeros((F, n, 3), np.float32),
                "yaw": np.zeros((F, n), np.float32),
                "angles": np.zeros((F, n, D), np.float32),
                "joints": np.zeros((F, n, J, 3), np.float32),
                "alive": np.ones((F, n), bool),
            }

    def add(self, world) -> None:
        """Record the world's current poses as the next frame."""
        k = self.count
        if k >= self.capacity:
            raise ValueError(f"clip: already holds the {self.capacity} frames it was made for")
        self.frame[k] = world.frame
        self.world_time[k] = world.world_time
        self.time_scale[k] = world.time_scale
        cam = world.camera
        self.camera_position[k] = cam.position
        self.camera_look_at[k] = cam.look_at
        self.camera_fov_deg[k] = cam.fov_deg
        for group, g in self.groups.items():
            crowd, idx = g["crowd"], g["index"]
            joints = crowd.joint_positions()[idx]
            g["joints"][k] = joints
            g["root"][k] = joints[:, 0]
            g["yaw"][k] = crowd.roots()[1][idx]
            g["angles"][k] = crowd.angles()[idx]
            if group == "characters":
                g["alive"][k] = world.characters.alive[idx]
            elif group == "shooters":
                g["alive"][k] = world.shooters.alive[idx]
        self.count += 1

    def arrays(self) -> dict[str, np.ndarray]:
        """The clip's arrays (the frames added so far), keyed as in the module docstring."""
        k = self.count
        out = {
            "format": np.array(FORMAT),
            "scene": np.array(self.scene.name),
            "scene_toml": np.array(self.scene.to_toml()),
            "fps": np.array(self.fps),
            "frame": self.frame[:k].copy(),
            "world_time": self.world_time[:k].copy(),
            "time_scale": self.time_scale[:k].copy(),
            "camera_position": self.camera_position[:k].copy(),
            "camera_look_at": self.camera_look_at[:k].copy(),
            "camera_fov_deg": self.camera_fov_deg[:k].copy(),
            "groups": np.array(GROUPS),
        }
        for group, g in self.groups.items():
            out[f"{group}_index"] = np.asarray(g["index"], np.int64)
            for key in _PER_FRAME:
                out[f"{group}_{key}"] = g[key][:k]
            for key, value in rig_arrays(g["rig"]).items():
                out[f"{group}_{key}"] = value
        return out

    def save(self, path, force: bool = False) -> Path:
        """Write the clip (.npz, uncompressed) atomically, never clobbering without force."""
        return save_clip(path, self.arrays(), force)


def save_clip(path, arrays: dict, force: bool = False) -> Path:
    from crowd_ik.io.output import atomic_path

    with atomic_path(path, force) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    return Path(path)


def record_clip(scene, frames: int | None = None, characters=None, what: str = "--bvh") -> dict:
    """Play `scene` as `crowd-ik play` does (frame 0 before any step) for `frames` frames (default
    the scene's) without rendering, and return the clip's arrays."""
    from crowd_ik.game.world import World
    from crowd_ik.session import frames as world_frames

    n = scene.n_frames if frames is None else int(frames)
    world = World(scene)
    rec = ClipRecorder(world, n, characters, what=what)
    for _ in world_frames(world, n):
        rec.add(world)
    return rec.arrays()


def load_clip(path) -> dict[str, np.ndarray]:
    """Read a clip .npz fully; ValueError naming the file when it is not a crowd-ik clip."""
    path = os.fspath(path)
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable .npz clip ({exc})") from None
    if str(data.get("format", "")) != FORMAT:
        raise ValueError(f"{path}: not a crowd-ik clip (format {str(data.get('format', 'missing'))!r}, "
                         f"expected {FORMAT!r})")
    F = len(data["frame"])
    for group in GROUPS:
        for key in (*_PER_FRAME, *_RIG_KEYS, "index"):
            if f"{group}_{key}" not in data:
                raise ValueError(f"{path}: not a crowd-ik clip (missing {group}_{key})")
        n, J = len(data[f"{group}_index"]), len(data[f"{group}_joint_names"])
        D = int(sum({"ball": 3, "universal": 2, "hinge": 1}.get(str(k), 0) for k in data[f"{group}_kinds"]))
        want = {"root": (F, n, 3), "yaw": (F, n), "angles": (F, n, D), "joints": (F, n, J, 3), "alive": (F, n)}
        for key, shape in want.items():
            if data[f"{group}_{key}"].shape != shape:
                raise ValueError(f"{path}: {group}_{key}: expected shape {shape} (got {data[f'{group}_{key}'].shape})")
    return data


def clip_joint_positions(clip: dict, group: str = "characters") -> np.ndarray:
    """(F, n, J, 3) float64 world joint positions by FK of the clip's roots, yaws and angles."""
    rig = rig_from_arrays(clip, group)
    root = np.asarray(clip[f"{group}_root"], np.float64)
    yaw = np.asarray(clip[f"{group}_yaw"], np.float64)
    angles = np.asarray(clip[f"{group}_angles"], np.float64)
    F, n = yaw.shape
    q = ref_fk.angles_to_rotations(rig, angles.reshape(F * n, -1))
    y = yaw.reshape(-1)
    base = root.reshape(-1, 3) - qrot(ref_fk.yaw_quat(y), np.broadcast_to(np.asarray(rig.joints[0].offset), (F * n, 3)))
    pos, _ = ref_fk.forward_kinematics(rig, base, y, q)
    return pos.reshape(F, n, rig.n_joints, 3)


# ------------------------------------------------------------------------------------------------
# rotations and Euler angles


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (x, y, z, w) -> (..., 3, 3) rotation matrices."""
    x, y, z, w = np.moveaxis(np.asarray(q, np.float64), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def euler_to_matrix(angles: np.ndarray, order: str) -> np.ndarray:
    """(..., 3) radians, intrinsic in `order` (R = R_order[0] R_order[1] R_order[2]) -> (..., 3, 3)."""
    a = np.asarray(angles, np.float64)
    return axis_matrix(order[0], a[..., 0]) @ axis_matrix(order[1], a[..., 1]) @ axis_matrix(order[2], a[..., 2])


# ------------------------------------------------------------------------------------------------
# BVH


def _end_site(rig: Rig, j: int) -> int | None:
    """The child of joint j written as its End Site: its only child, when that is a fixed leaf."""
    kids = rig.children[j]
    if len(kids) == 1 and not rig.children[kids[0]] and rig.joints[kids[0]].kind == "fixed":
        return kids[0]
    return None


def bvh_joints(rig: Rig) -> list[int]:
    """The rig's joints that are ROOT/JOINT entries, in file (and channel) order: depth first."""
    out, todo = [], [0]
    while todo:
        j = todo.pop()
        out.append(j)
        if _end_site(rig, j) is None:
            todo.extend(reversed(rig.children[j]))
    return out


def bvh_text(rig: Rig, root, yaw, angles, fps: float, prefixes=None) -> str:
    """A BVH file of one body: root (F, 3) world position of the root joint, yaw (F,) radians,
    angles (F, D) radians, at `fps` frames per second (see the module docstring). Several bodies:
    root (F, n, 3), yaw (F, n), angles (F, n, D) and prefixes (n,) put before each body's joint
    names; each body is a ROOT of its own, its channels after the previous body's."""
    if prefixes is None:
        root, yaw, angles, prefixes = (np.asarray(root)[:, None], np.asarray(yaw)[:, None],
                                       np.asarray(angles)[:, None], [""])
    root = np.asarray(root, np.float64)
    yaw = np.asarray(yaw, np.float64)
    angles = np.asarray(angles, np.float64)
    F, n = yaw.shape if yaw.ndim == 2 else (0, -1)
    if F == 0 or len(prefixes) != n or root.shape != (F, n, 3) or angles.shape != (F, n, rig.n_dof):
        raise ValueError(f"bvh: expected one root, yaw and angle row per frame and body (got {root.shape}, "
                         f"{yaw.shape}, {angles.shape} for {len(prefixes)} bodies)")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"bvh: fps must be positive (got {fps!r})")
    lines, columns = ["HIERARCHY"], []
    for b, prefix in enumerate(prefixes):
        _bvh_body(rig, root[:, b], yaw[:, b], angles[:, b], str(prefix), lines, columns)
    motion = np.concatenate(columns, axis=1)
    motion[np.abs(motion) < 5e-7] = 0.0  # no "-0.000000"
    buf = io.StringIO()
    np.savetxt(buf, motion, fmt="%.6f", delimiter=" ")
    lines += ["MOTION", f"Frames: {F}", f"Frame Time: {1.0 / float(fps):.8f}"]
    return "\n".join(lines) + "\n" + buf.getvalue()


def _bvh_body(rig: Rig, root, yaw, angles, prefix: str, lines: list, columns: list) -> None:
    """Append one body's ROOT block to lines and its channel columns (F, k) to columns."""
    q = ref_fk.angles_to_rotations(rig, angles)  # (F, J, 4)
    q[:, 0] = qmul(ref_fk.yaw_quat(yaw), q[:, 0])

    def vec(v) -> str:
        return " ".join(f"{float(c):.6f}" for c in v)

    columns.append(root)
    todo: list[tuple[int, int]] = [(0, 0)]  # (joint, depth); joint -1 closes the block at that depth
    while todo:
        j, depth = todo.pop()
        pad = "\t" * depth
        if j < 0:
            lines.append(pad + "}")
            continue
        joint = rig.joints[j]
        if j == 0:
            lines += [f"ROOT {prefix}{joint.name}", "{", "\tOFFSET 0.000000 0.000000 0.000000",
                      "\tCHANNELS 6 Xposition Yposition Zposition " + " ".join(f"{a}rotation" for a in ROOT_ORDER)]
        else:
            lines += [f"{pad}JOINT {prefix}{joint.name}", pad + "{", f"{pad}\tOFFSET {vec(joint.offset)}",
                      f"{pad}\tCHANNELS 3 " + " ".join(f"{a}rotation" for a in JOINT_ORDER)]
        columns.append(np.degrees(matrix_to_euler(quat_to_matrix(q[:, j]), ROOT_ORDER if j == 0 else JOINT_ORDER)))
        end = _end_site(rig, j)
        kids = rig.children[j]
        if end is not None or not kids:  # a moving leaf still needs an End Site: zero length
            offset = rig.joints[end].offset if end is not None else (0.0, 0.0, 0.0)
            lines += [f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {vec(offset)}", f"{pad}\t}}"]
            kids = ()
        todo.append((-1, depth))
        todo.extend((c, depth + 1) for c in reversed(kids))


def bvh_from_clip(clip: dict, character, source: str = "clip") -> tuple[Rig, str]:
    """(rig, BVH text) of the clip's character with original index `character`; a list of indices
    gives one ROOT per character, its joint names prefixed "c<K>_" (K the character's index)."""
    index = np.asarray(clip["characters_index"])
    many = not isinstance(character, (int, np.integer))
    wanted = [int(k) for k in character] if many else [int(character)]
    picked = []
    for k in wanted:
        hit = np.flatnonzero(index == k)
        if hit.size == 0:
            shown = f"0..{len(index) - 1}" if np.array_equal(index, np.arange(len(index))) else str(index.tolist()[:10])
            raise ValueError(f"--character{'s' if many else ''}: {source} holds characters {shown} (got {k})")
        picked.append(int(hit[0]))
    rig = rig_from_arrays(clip, "characters", source)
    root, yaw, angles = (clip[f"characters_{key}"][:, picked] for key in ("root", "yaw", "angles"))
    if many:
        return rig, bvh_text(rig, root, yaw, angles, float(clip["fps"]), [f"c{k}_" for k in wanted])
    return rig, bvh_text(rig, root[:, 0], yaw[:, 0], angles[:, 0], float(clip["fps"]))


__all__ = ["ClipRecorder", "record_clip", "save_clip", "load_clip", "clip_joint_positions", "clip_bytes",
           "rig_arrays", "rig_from_arrays", "bvh_joints", "bvh_text", "bvh_from_clip", "quat_to_matrix",
           "euler_to_matrix", "matrix_to_euler", "GROUPS", "FORMAT"]
