"""IK on top of a motion clip: ``cik.animate(clip, output=None, count=1, ...)`` plays a BVH clip on a
crowd and lets the solvers correct it, frame by frame; with an output it renders the result like
`crowd-ik play` (same renderer, video sinks and no-clobber rule).

Character c stands at the c-th spot of a centred grid (``spacing`` metres apart; the clip's first root
position is moved onto the spot) and plays the clip ``stagger`` seconds behind character c - 1 (rounded
to whole clip frames), looping. Video frame k shows every character at its clip frame, at the clip's
frame rate. Each frame: the clip's angles and root are set (so corrections never accumulate), each
effector gets a target, and one Crowd.solve moves the effectors to them.

Targets. A foot effector (name "foot...") is in contact on a clip frame when it is within CONTACT_HEIGHT
of the lowest height it reaches in the clip and slower than CONTACT_SPEED (central differences). While
in contact it is planted: its IK target is where the contact began, at that lowest height; when the
contact ends the target slides back to the clip's over RELEASE_FRAMES frames. Other effectors' IK
target is where the clip puts them, unless ``targets(k, clip_positions)`` (a callable returning
(count, E, 3) world points, NaN = the default) says otherwise. The solve's target for effector e is
``(1 - w_e) * clip + w_e * ik_target``, w_e from ``blend`` (a mapping effector name -> weight in
[0, 1]; feet default to 1, the others to 0).

The result (AnimateResult) holds every character's solved joint positions per frame and the measure
the correction is for: how far planted feet slide (mean horizontal speed during contact) in the clip
and after IK.
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crowd_ik.checks import is_number
from crowd_ik.rig import Rig
from crowd_ik.solvers.registry import DEFAULT, METHODS

CONTACT_HEIGHT = 0.02  # metres above the clip's lowest height of that foot
CONTACT_SPEED = 0.2  # metres per second
RELEASE_FRAMES = 4  # frames over which a released foot's target returns to the clip's
MAX_CHARACTERS = 10_000
PALETTE = ((0.80, 0.55, 0.30), (0.35, 0.65, 0.85), (0.45, 0.75, 0.45), (0.75, 0.45, 0.75),
           (0.30, 0.75, 0.80), (0.60, 0.60, 0.60))  # BGR, one per character in turn
PLANT_COLOR = (0.2, 0.85, 0.3)  # BGR: markers at planted feet


@dataclass(frozen=True)
class AnimateResult:
    """What animate computed: joints (K, N, J, 3) float32 world metres after IK, planted (K, N, E) bool,
    error (K, N) float32 metres (the solves' reports, 0 where nothing was solved), clip_frame (K, N) int,
    slide_clip / slide (m/s): mean horizontal speed of feet in contact in the clip / after IK (NaN when
    no foot is ever in contact), output (the written path or None)."""

    rig: Rig
    joints: np.ndarray
    planted: np.ndarray
    error: np.ndarray
    clip_frame: np.ndarray
    fps: float
    slide_clip: float
    slide: float
    output: Path | None

    @property
    def n_frames(self) -> int:
        return self.joints.shape[0]


def parse_blend(text: str, what: str = "--blend") -> dict[str, float]:
    """"foot_l=1,foot_r=1,hand_l=0.5" -> {"foot_l": 1.0, ...} (weights checked by animate)."""
    out = {}
    for item in [s for s in str(text).split(",") if s.strip()]:
        name, eq, value = item.partition("=")
        try:
            weight = float(value)
        except ValueError:
            weight = None
        if not eq or not name.strip() or weight is None:
            raise ValueError(f"{what}: expected EFFECTOR=WEIGHT[,...] such as foot_l=1,hand_l=0.5 (got {item!r})")
        if not (0.0 <= weight <= 1.0):
            raise ValueError(f"{what}: {name.strip()}: a weight in [0, 1] (got {value.strip()})")
        out[name.strip()] = weight
    if not out:
        raise ValueError(f"{what}: expected EFFECTOR=WEIGHT[,...] (got {text!r})")
    return out


def _weights(rig: Rig, blend, what: str) -> np.ndarray:
    w = np.array([1.0 if e.name.startswith("foot") else 0.0 for e in rig.effectors])
    for name, weight in dict(blend or {}).items():
        if name not in rig.effector_names:
            raise ValueError(f"{what}: no effector {name!r} (the rig's: {', '.join(rig.effector_names)})")
        if not is_number(weight) or not (0.0 <= float(weight) <= 1.0):
            raise ValueError(f"{what}: {name}: a weight in [0, 1] (got {weight!r})")
        w[rig.effector_names.index(name)] = float(weight)
    return w


def contacts(positions: np.ndarray, fps: float) -> np.ndarray:
    """(F, E) bool: effector positions (F, E, 3) within CONTACT_HEIGHT of their lowest and slower than
    CONTACT_SPEED (central differences; one-sided at the ends)."""
    p = np.asarray(positions, np.float64)
    if len(p) < 2:
        velocity = np.zeros_like(p)
    else:
        velocity = np.gradient(p, 1.0 / fps, axis=0)
    low = p[..., 1].min(axis=0)
    return (p[..., 1] <= low + CONTACT_HEIGHT) & (np.linalg.norm(velocity, axis=-1) < CONTACT_SPEED)


def _slide(feet: np.ndarray, contact: np.ndarray, fps: float) -> float:
    """Mean horizontal speed (m/s) of feet (K, N, E, 3) over consecutive frames both in contact."""
    both = contact[1:] & contact[:-1]
    if not both.any():
        return math.nan
    step = np.linalg.norm(np.diff(feet[..., [0, 2]], axis=0), axis=-1)
    return float(step[both].mean() * fps)


def _camera(points: np.ndarray, size: tuple[int, int]):
    """A fixed camera in front of (+z), above and to the side of everything in points (M, 3)."""
    from crowd_ik.view.render import Camera

    lo, hi = points.min(axis=0), points.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.5)
    fov = 45.0
    direction = np.array([0.45, 0.5, 1.0]) / np.linalg.norm([0.45, 0.5, 1.0])
    distance = 1.15 * radius / math.sin(math.radians(fov) / 2.0)
    return Camera(center + direction * distance, center, fov, size[0], size[1])


def _load(clip, units: str, effectors):
    if isinstance(clip, tuple) and len(clip) == 2:
        return clip
    from crowd_ik.io.bvh import load_bvh

    if Path(os.fspath(clip)).suffix.lower() != ".bvh":
        raise ValueError(f"clip: expected a .bvh file (got {os.fspath(clip)!r})")
    return load_bvh(clip, units=units, effectors=effectors)


def animate(clip, output=None, count: int = 1, spacing: float = 1.5, stagger: float = 0.0, blend=None,
            method: str = DEFAULT, frames: int | None = None, size=(1280, 720), force: bool = False,
            units: str = "auto", effectors=None, targets=None, max_iterations: int = 20,
            tolerance: float = 1e-3, progress=None) -> AnimateResult:
    """Play clip (a .bvh path, or a (rig, motion) pair from load_bvh) on `count` characters with IK on top
    (see the module docstring); output: .mp4, .webm or DIR/ to render to, or None. frames: video frames
    (default the clip's); progress: a callable taking the frame index after each frame."""
    from crowd_ik.crowd import Crowd, grid_positions
    from crowd_ik.io.video import check_size

    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or not 1 <= count <= MAX_CHARACTERS:
        raise ValueError(f"count: expected an integer in [1, {MAX_CHARACTERS}] (got {count!r})")
    for name, value in (("spacing", spacing), ("stagger", stagger)):
        if not is_number(value) or not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name}: expected a number >= 0 (got {value!r})")
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)} (got {method!r})")
    if targets is not None and not callable(targets):
        raise ValueError(f"targets: expected a callable (frame, clip positions) -> (count, E, 3) (got {targets!r})")
    size = check_size(size, "size")
    if output is not None:
        check_video_output(output, force)
    rig, motion = _load(clip, units, effectors)
    F, fps = motion.n_frames, motion.fps
    n_frames = F if frames is None else frames
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise ValueError(f"frames: expected a positive integer (got {frames!r})")
    n_frames = int(n_frames)
    blend_w = _weights(rig, blend, "blend")
    E, J = rig.n_effectors, rig.n_joints
    eff = rig.arrays["eff_joint"]
    feet = np.array([e.name.startswith("foot") for e in rig.effectors])

    clip_joints = motion.joint_positions()  # (F, J, 3)
    clip_eff = clip_joints[:, eff]
    contact = contacts(clip_eff, fps) & feet[None, :]
    ground = clip_eff[..., 1].min(axis=0)  # (E,) each foot's lowest height
    base, _ = motion.roots()
    angles = motion.angles()
    spots = grid_positions(count, float(spacing), 3).astype(np.float64)
    place = spots - np.array([base[0, 0], 0.0, base[0, 2]])  # (N, 3) added to the clip's positions
    lag = int(round(float(stagger) * fps))
    crowd = Crowd(rig, n=count)
    solve = bool(np.any(blend_w > 0)) or targets is not None

    joints = np.zeros((n_frames, count, J, 3), np.float32)
    planted_out = np.zeros((n_frames, count, E), bool)
    errors = np.zeros((n_frames, count), np.float32)
    frame_index = np.zeros((n_frames, count), np.int64)
    plant = np.zeros((count, E, 3))
    planted = np.zeros((count, E), bool)
    release = np.zeros((count, E, 3))  # planted minus clip position at release, fading out
    release_left = np.zeros((count, E), np.int64)
    weights = np.ones(E, np.float32)
    renderer = None
    parent = rig.arrays["parent"][1:]
    radius = np.tile(rig.arrays["radius"][1:], count)
    colors = np.repeat(np.array([PALETTE[c % len(PALETTE)] for c in range(count)]), J - 1, axis=0)
    if output is not None:
        from crowd_ik.io.video import open_sink
        from crowd_ik.view.render import Renderer

        corners = (clip_joints.reshape(-1, 3)[None] + place[:, None]).reshape(-1, 3)
        renderer = Renderer(_camera(np.concatenate([corners, np.zeros((1, 3))]), size), count * (J - 1), count * E)
    with (open_sink(output, fps, size, force=force) if output is not None else contextlib.nullcontext()) as sink:
        for k in range(n_frames):
            f = (k - lag * np.arange(count)) % F  # (N,) clip frame of each character
            frame_index[k] = f
            clip_now = clip_eff[f] + place[:, None]  # (N, E, 3)
            touch = contact[f]
            if k:  # a character whose clip starts over lets its feet go (the clip's root jumps back)
                looped = (f == 0)[:, None]
                planted &= ~looped
                release_left[np.broadcast_to(looped, release_left.shape)] = 0
            start = touch & ~planted
            plant[start] = clip_now[start]
            plant[..., 1] = np.where(start, ground[None, :], plant[..., 1])
            ended = planted & ~touch
            release[ended] = plant[ended] - clip_now[ended]
            release_left[ended] = RELEASE_FRAMES
            planted = touch
            fade = (release_left / (RELEASE_FRAMES + 1.0))[..., None]
            ik = np.where(planted[..., None], plant, clip_now + release * fade)
            release_left = np.maximum(release_left - 1, 0)
            if targets is not None:
                given = np.asarray(targets(k, clip_now), np.float64)
                if given.shape != (count, E, 3):
                    raise ValueError(f"targets: frame {k}: expected shape {(count, E, 3)} (got {given.shape})")
                ik = np.where(np.isnan(given), ik, given)
            goal = clip_now + blend_w[None, :, None] * (ik - clip_now)
            crowd.set_roots(base[f] + place)
            crowd.set_angles(angles[f])
            if solve:
                report = crowd.solve(goal, method=method, max_iterations=max_iterations, tolerance=tolerance,
                                     weights=weights)
                errors[k] = report.error
            joints[k] = crowd.joint_positions()
            planted_out[k] = planted
            if sink is not None:
                pos = joints[k]
                marks = plant[planted].astype(np.float32)
                frame = renderer.render(pos[:, parent].reshape(-1, 3), pos[:, 1:].reshape(-1, 3), radius, colors,
                                        marks, np.full(len(marks), 0.03, np.float32), PLANT_COLOR,
                                        hud_lines=[f"{rig.name}  frame {k + 1}/{n_frames}  clip {motion.fps:g} fps",
                                                   f"characters {count}  feet planted {int(planted.sum())}"])
                sink.write(frame)
            if progress is not None:
                progress(k)
    written = None if sink is None else sink.path
    clip_feet = (clip_eff[frame_index] + place[None, :, None])[..., feet, :]
    return AnimateResult(rig, joints, planted_out, errors, frame_index, fps,
                         _slide(clip_feet, planted_out[..., feet], fps),
                         _slide(joints[:, :, eff][..., feet, :], planted_out[..., feet], fps),
                         None if written is None else Path(written))


def check_video_output(output, force: bool) -> None:
    """Refuse a bad or existing output before any work (FileExistsError without force)."""
    from crowd_ik.io.output import check_writable, check_writable_dir, is_dir_target
    from crowd_ik.io.video import VIDEO_SUFFIXES

    text = os.fspath(output)
    if is_dir_target(text):
        check_writable_dir(text, force)
        return
    suffix = Path(text).suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"output: unknown video suffix {suffix or '(none)'!r} in {text!r}; use .mp4 (H.264), "
                         f".webm (VP8) or a folder ending in '/'")
    check_writable(text, force)


__all__ = ["animate", "AnimateResult", "parse_blend", "check_video_output", "contacts", "CONTACT_HEIGHT", "CONTACT_SPEED"]
