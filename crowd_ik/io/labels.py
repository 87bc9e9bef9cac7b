"""Per-frame pose labels for data sets: one JSON line per video frame (`play --labels F.jsonl`, and
render-many's `labels = true`), written atomically like every output (crowd_ik.io.output).

A line (keys in this order; numbers rounded to 0.01 px and 0.1 mm):

    {"frame": k,
     "camera": {"position": [x, y, z], "look_at": [x, y, z], "fov_deg": f, "size": [W, H]},
     "characters": [{"id": i, "group": "crowd" | "shooter" | "player",
                     "keypoints_2d": [[x, y, v], ...17],   # COCO order (COCO_KEYPOINTS), pixels
                     "joints_3d": [[x, y, z], ...J],       # the rig's joints in rig order, world metres
                     "bbox": [x0, y0, x1, y1]}, ...]}      # pixels showing the character, x1 y1 exclusive

- Which characters: every body the frame shows at least one pixel of in the renderer's z-buffer
  (crowd characters, shooters, the player; shattered ones are shards and are not listed). `id` is the
  body's index in World.primitives(): crowd 0..N-1, shooters N..N+S-1, the player N+S.
- Poses are the ones drawn: World.primitives() interpolates between the last two world steps, and the
  joints are read back from its limb capsules (a bone's capsule runs from its parent joint to it).
- keypoints_2d: pixel coordinates as Camera.project gives them (x right, y down, pixel (i, j)'s centre
  at (i, j)); v = 2 when the z-buffer at the keypoint's pixel is no nearer than the joint less the
  largest radius of the limbs meeting there (plus one pixel's footprint), v = 1 when something nearer
  covers it (another character, or the character's own limb), [0, 0, 0] when the rig has no such
  joint (the humanoid has no nose, eyes or ears: COCO's "not labelled"), the joint is behind the
  camera or outside the image. The HUD and bullet trails, drawn over the frame, hide nothing.
- bbox: the extent of the pixels whose z-buffer entry is the character's (what is visible of it).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from crowd_ik.io.output import check_writable, make_temp_path, publish

COCO_KEYPOINTS = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
)
VISIBLE, HIDDEN, UNLABELLED = 2, 1, 0
GROUPS = ("crowd", "shooter", "player")

__all__ = ["COCO_KEYPOINTS", "VISIBLE", "HIDDEN", "UNLABELLED", "coco_joints", "frame_labels", "LabelsWriter",
           "check_labels_path"]


def coco_joints(joint_names) -> np.ndarray:
    """(17,) int: the rig joint shown as each COCO keypoint, -1 where the rig has none.

    COCO's `left_X` is the rig's `X_l` (the humanoid's left is its own left, +x when it faces +z)."""
    index = {name: i for i, name in enumerate(joint_names)}
    out = []
    for name in COCO_KEYPOINTS:
        side, _, part = name.partition("_")
        out.append(index.get(f"{part}_{side[0]}", -1) if part else -1)
    return np.array(out, np.int64)


class _Rig:
    """What labelling needs of one Body: bones, the COCO map, each joint's largest limb radius."""

    def __init__(self, body):
        self.n_bones = int(body.n_bones)
        names = [j.name for j in body.rig.joints]
        self.coco = coco_joints(names)
        radius = np.zeros(len(names), np.float64)  # joint j: bones ending at j (bone j-1) and leaving it
        np.maximum.at(radius, np.arange(1, len(names)), body.bone_radius)
        np.maximum.at(radius, np.asarray(body.bone_parent), body.bone_radius)
        self.radius = radius


def _bone_capsules(order: np.ndarray, sorted_body: np.ndarray, ids: np.ndarray, n_bones: int) -> np.ndarray:
    """(len(ids), n_bones) capsule indices of each body's bones: its first n_bones capsules in drawing
    order (a shooter's gun comes after its bones)."""
    start = np.searchsorted(sorted_body, ids)
    return order[start[:, None] + np.arange(n_bones)[None, :]]


def frame_labels(world, frame: int) -> dict:
    """The labels of the frame `world` last rendered (call right after World.render())."""
    cam = world.camera
    w, h = cam.width, cam.height
    prim = world.primitives()
    caps = prim["capsules"]
    body = caps["body"]
    n_caps = len(body)
    ids, zdepth = world.renderer.id_buffer()  # ids: capsules first, then spheres (bullets)
    prim_body = np.concatenate([body, np.full(max(int(ids.max()) + 1 - n_caps, 0), -1, np.int32)])
    pixel_body = np.where(ids >= 0, prim_body[np.maximum(ids, 0)], -1).ravel()
    n, s = world.n, world.n_shooters
    shown = pixel_body[(pixel_body >= 0) & (pixel_body <= n + s)]  # no shards (n + s + 1)
    flat = np.flatnonzero((pixel_body >= 0) & (pixel_body <= n + s))
    by_body = np.argsort(shown, kind="stable")
    present, first = np.unique(shown[by_body], return_index=True)
    xs, ys = flat[by_body] % w, flat[by_body] // w
    boxes = np.stack([np.minimum.reduceat(xs, first), np.minimum.reduceat(ys, first),
                      np.maximum.reduceat(xs, first) + 1, np.maximum.reduceat(ys, first) + 1], axis=1) \
        if len(present) else np.zeros((0, 4), np.int64)
    order = np.argsort(body, kind="stable")
    sorted_body = body[order]
    crowd_rig, human_rig = _Rig(world.body), _Rig(world.hbody)  # the crowd's rig; shooters' and player's
    people = []
    for rig, sel in ((crowd_rig, present < n), (human_rig, present >= n)):
        who = present[sel]
        if not len(who):
            continue
        bones = _bone_capsules(order, sorted_body, who, rig.n_bones)  # (K, B)
        joints = np.concatenate([caps["a"][bones[:, :1]], caps["b"][bones]], axis=1).astype(np.float64)  # (K, J, 3)
        pix, depth = cam.project(joints.reshape(-1, 3))
        pix, depth = pix.reshape(len(who), -1, 2), depth.reshape(len(who), -1)
        kp = np.zeros((len(who), len(COCO_KEYPOINTS), 3))
        have = rig.coco >= 0
        jp, jd = pix[:, rig.coco[have]], depth[:, rig.coco[have]]  # (K, h, 2), (K, h)
        px, py = np.rint(np.nan_to_num(jp[..., 0], nan=-1.0)), np.rint(np.nan_to_num(jp[..., 1], nan=-1.0))
        inside = np.isfinite(jp[..., 0]) & (px >= 0) & (px < w) & (py >= 0) & (py < h)
        front = np.full(jd.shape, -np.inf)
        front[inside] = zdepth[py[inside].astype(np.int64), px[inside].astype(np.int64)]
        slack = rig.radius[rig.coco[have]][None, :] + jd / cam.focal + 1e-3
        seen = front >= jd - slack
        v = np.where(inside, np.where(seen, VISIBLE, HIDDEN), UNLABELLED)
        kp[:, have, 0] = np.where(inside, jp[..., 0], 0.0)
        kp[:, have, 1] = np.where(inside, jp[..., 1], 0.0)
        kp[:, have, 2] = v
        for i, body_id in enumerate(who.tolist()):
            group = GROUPS[0] if body_id < n else GROUPS[1] if body_id < n + s else GROUPS[2]
            people.append((body_id, {
                "id": body_id,
                "group": group,
                "keypoints_2d": [[round(float(x), 2), round(float(y), 2), int(c)] for x, y, c in kp[i]],
                "joints_3d": np.round(joints[i], 4).tolist(),
                "bbox": [int(c) for c in boxes[np.searchsorted(present, body_id)]],
            }))
    people.sort(key=lambda p: p[0])
    return {
        "frame": int(frame),
        "camera": {"position": cam.position.tolist(), "look_at": cam.look_at.tolist(), "fov_deg": cam.fov_deg,
                   "size": [w, h]},
        "characters": [p for _, p in people],
    }


def check_labels_path(path: str | os.PathLike, force: bool = False, flag: str = "--labels") -> Path:
    """Refuse a labels path that is not a .jsonl file or may not be written (FileExistsError without force)."""
    if Path(os.fspath(path)).suffix.lower() != ".jsonl":
        raise ValueError(f"{flag}: labels are written as a .jsonl file, one JSON line per frame (got {os.fspath(path)!r})")
    return check_writable(path, force)


class LabelsWriter:
    """Streams label lines into a hidden temporary file next to `path` and renames it into place when
    closed, like a video sink: finalised on normal exit and on Ctrl-C (the frames so far, matching the
    shorter video), discarded on any other exception.

        with LabelsWriter("labels.jsonl") as labels:
            for k in range(n):
                ...; frame = world.render(); labels.add(world, k)
    """

    def __init__(self, path: str | os.PathLike, force: bool = False):
        self.path = check_labels_path(path, force)
        self.force = bool(force)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = make_temp_path(self.path)
        self._file = open(self._tmp, "w", encoding="utf-8")
        self.count = 0

    def add(self, world, frame: int) -> dict:
        """Append the labels of the frame `world` last rendered; return them."""
        record = frame_labels(world, frame)
        self._file.write(json.dumps(record, separators=(",", ":")) + "\n")
        self.count += 1
        return record

    def close(self) -> Path:
        """Finish the file and rename it into place; return its path."""
        if not self._file.closed:
            try:
                self._file.close()
                publish(self._tmp, self.path, self.force)
            except BaseException:
                self._tmp.unlink(missing_ok=True)
                raise
        return self.path

    def abort(self) -> None:
        """Delete the temporary file; an existing file at `path` is left as it was."""
        if not self._file.closed:
            self._file.close()
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> LabelsWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None or (issubclass(exc_type, KeyboardInterrupt) and self.count):
            self.close()
        else:
            self.abort()
        return False
