"""Issue 14's targets for the default video (`crowd-ik play`, the arena, 10 s), measured from --stats
and --clip: the player fights back, time keeps moving, bystanders walk on planted feet, keep apart
and fill the frame. `showcase_metrics` computes every figure; the fast test plays the whole 10 s
of simulation at a tiny frame size (the on-screen size is measured in 720p lines from the clip's
cameras, whatever the video's size), the slow one the full 1280x720 video.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

from crowd_ik.io.clip import load_clip
from crowd_ik.view.render import Camera

CONTACT = 0.02  # m: an ankle this close to the character's lowest ankle height is on the ground
TOO_CLOSE = 0.3  # m between roots on the ground plane


def showcase_metrics(stats: dict, clip: dict, width: int, height: int) -> dict:
    """The issue's figures from a play run's --stats and --clip (see the module docstring)."""
    names = list(clip["characters_joint_names"])
    ankles = [names.index("ankle_l"), names.index("ankle_r")]
    joints = clip["characters_joints"].astype(np.float64)  # (F, N, J, 3)
    alive = clip["characters_alive"]  # (F, N)
    wt = clip["world_time"]
    F = len(wt)
    out = {"shooters_down": stats["shooters_down"], "hits": stats["hits"], "frames": F}
    out["slow_fraction"] = float(np.mean(clip["time_scale"] <= 0.1))
    root = clip["characters_root"][..., [0, 2]].astype(np.float64)
    out["median_path_m"] = float(np.median(np.linalg.norm(np.diff(root, axis=0), axis=2).sum(axis=0)))
    # foot skating: ankles on the ground in two successive frames over which world time advanced
    a = joints[:, :, ankles]  # (F, N, 2, 3)
    low = a[..., 1].min(axis=2, keepdims=True)  # (F, N, 1)
    ground = a[..., 1] <= low + CONTACT  # (F, N, 2)
    dt = np.diff(wt)
    pair = (dt > 0)[:, None, None] & ground[1:] & ground[:-1] & (alive[1:] & alive[:-1])[..., None]
    speed = np.linalg.norm(np.diff(a[..., [0, 2]], axis=0), axis=3) / np.maximum(dt, 1e-12)[:, None, None]
    out["skate_p95_m_s"] = float(np.percentile(speed[pair], 95))
    out["contacts"] = int(pair.sum())
    # on screen: alive bystanders with every joint in the frame, every 10th frame, in 720p lines
    spans = []
    for f in range(0, F, 10):
        cam = Camera(clip["camera_position"][f], clip["camera_look_at"][f], float(clip["camera_fov_deg"][f]), width, height)
        idx = np.flatnonzero(alive[f])
        pix, depth = cam.project(joints[f, idx].reshape(-1, 3))
        pix = pix.reshape(len(idx), -1, 2)
        inside = np.all(np.isfinite(pix).all(axis=2) & (pix[..., 0] >= 0) & (pix[..., 0] <= width - 1)
                        & (pix[..., 1] >= 0) & (pix[..., 1] <= height - 1), axis=1)
        span = pix[inside, :, 1].max(axis=1) - pix[inside, :, 1].min(axis=1)
        spans.extend((span * 720.0 / height).tolist())
    out["median_height_px_720p"] = float(np.median(spans)) if spans else 0.0
    out["on_screen_samples"] = len(spans)
    # nobody within TOO_CLOSE of anybody: alive characters, standing shooters and the player
    close = 0
    for f in range(F):
        pts = np.concatenate([root[f][alive[f]], clip["shooters_root"][f][clip["shooters_alive"][f]][:, [0, 2]],
                              clip["player_root"][f][:, [0, 2]]]).astype(np.float64)
        d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
        np.fill_diagonal(d, np.inf)
        close += bool(d.min() < TOO_CLOSE)
    out["too_close_fraction"] = close / F
    return out


def _play(tmp_path, *extra) -> tuple[dict, dict]:
    stats, clip = tmp_path / "stats.json", tmp_path / "clip.npz"
    cmd = [sys.executable, "-m", "crowd_ik", "play", "-o", str(tmp_path / "v.mp4"), "--stats", str(stats),
           "--clip", str(clip), *extra]
    subprocess.run(cmd, check=True, capture_output=True, timeout=1800)
    return json.loads(stats.read_text()), load_clip(clip)


def _check(m: dict) -> None:
    assert m["frames"] == 300
    assert m["shooters_down"] >= 1 and m["hits"] >= 3, m
    assert m["slow_fraction"] <= 0.10, m
    assert m["median_path_m"] >= 1.5, m
    assert m["contacts"] > 1000 and m["skate_p95_m_s"] <= 0.15, m
    assert m["on_screen_samples"] >= 100 and m["median_height_px_720p"] >= 100.0, m
    assert m["too_close_fraction"] <= 0.01, m


def test_default_video_targets_at_a_tiny_size(tmp_path):
    stats, clip = _play(tmp_path, "--size", "160x90")
    m = showcase_metrics(stats, clip, 160, 90)
    print(m)
    _check(m)


@pytest.mark.slow
def test_default_video_targets(tmp_path):
    stats, clip = _play(tmp_path)
    m = showcase_metrics(stats, clip, 1280, 720)
    print(m)
    _check(m)
