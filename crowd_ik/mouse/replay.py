"""`crowd-ik mouse --path / --keyframes`: a target path or eased key poses replayed to a video."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crowd_ik import planar
from crowd_ik.mouse.paths import load_path, path_frames, resolve_input
from crowd_ik.mouse.session import DEFAULT_BONES, MAX_BONES, TRAIL_LENGTH, ChainSession
from crowd_ik.mouse.view import (
    ChainPicture,
    View,
    draw_chain_frame,
    tips,
)
from crowd_ik.solvers.registry import (
    PLANAR_DEFAULT,
)

# ---------------------------------------------------------------------------------------------
# replay to video


@dataclass(frozen=True)
class Replay:
    """What a replay wrote, frame by frame."""

    output: Path
    fps: float
    size: tuple[int, int]
    angles: np.ndarray  # (F, n) radians
    lost: np.ndarray  # (F,) bool
    error: np.ndarray  # (F,) chain units (0 for keyframes)

    @property
    def frames(self) -> int:
        return len(self.angles)


def replay_path(csv, output, *, n_bones=DEFAULT_BONES, method=PLANAR_DEFAULT, limits=False, size=(720, 720), fps=None,
                force=False) -> Replay:
    """Solve the chain toward each target of a path CSV and write one frame per target."""
    from crowd_ik.io.video import open_sink

    src = resolve_input(csv)
    t, xy = load_path(src)
    times, targets, rate = path_frames(t, xy, fps, str(src))
    session = ChainSession(n_bones, method, limits)
    view = View(n_bones, *size)
    angles, lost, error = [], [], []
    trail: deque = deque(maxlen=TRAIL_LENGTH)
    with open_sink(output, rate, size, force) as sink:
        background = session.background(view)
        session.settle(targets[0])
        for k, (now, target) in enumerate(zip(times, targets)):
            session.target = target
            session.step()
            joints = session.joints()
            trail.append(joints[-1])
            hud = session.hud() + [f"t {now:.2f} s   frame {k + 1}/{len(times)}"]
            pic = ChainPicture(joints, target, session.lost, background, hud, [f"replay {src.name}"], np.array(trail))
            sink.write(draw_chain_frame(view, pic))
            angles.append(session.thetas.copy())
            lost.append(session.lost)
            error.append(session.error)
    return Replay(Path(sink.path), rate, tuple(size), np.array(angles), np.array(lost), np.array(error))


def replay_keyframes(csv, output, *, n_bones=None, limits=False, size=(720, 720), fps=None, k1=0.2, k2=0.75,
                     force=False) -> Replay:
    """Ease between the key poses of a keyframe CSV (crowd_ik.ease) and write every frame."""
    from crowd_ik.ease import interpolate_keyframes, load_keyframes
    from crowd_ik.io.video import open_sink

    src = resolve_input(csv)
    durations, poses = load_keyframes(src)
    n = poses.shape[1]
    if n_bones is not None and n_bones != n:
        raise ValueError(f"{src}: has {n} angles per key pose but --bones is {n_bones}")
    if n > MAX_BONES:
        raise ValueError(f"{src}: {n} angles per key pose; at most {MAX_BONES} bones")
    session = ChainSession(n, PLANAR_DEFAULT, limits)
    if limits:
        lo, hi = session.bounds
        bad = np.argwhere((poses < lo - 1e-9) | (poses > hi + 1e-9))
        if bad.size:
            k, j = bad[0]
            raise ValueError(f"{src}: key pose {k + 1}: theta{j + 1} = {math.degrees(poses[k, j]):g} deg is outside "
                             f"the --limits range +-{math.degrees(hi[j]):g} deg")
    rate = 30.0 if fps is None else float(fps)
    angles = interpolate_keyframes(durations, poses, rate, k1, k2)
    total = float(durations.sum())
    view = View(n, *size)
    marks = tips(poses)
    trail: deque = deque(maxlen=TRAIL_LENGTH)
    with open_sink(output, rate, size, force) as sink:
        background = session.background(view)
        for k, theta in enumerate(angles):
            joints = planar.chain_all(theta)
            trail.append(joints[-1])
            hud = [f"keyframes ({len(poses)} poses)   sine ease k1 {k1:g}  k2 {k2:g}",
                   f"t {min(k / rate, total):.2f} s of {total:.2f} s   frame {k + 1}/{len(angles)}"]
            pic = ChainPicture(joints, None, False, background, hud, [f"replay {src.name}"], np.array(trail), marks)
            sink.write(draw_chain_frame(view, pic))
    return Replay(Path(sink.path), rate, tuple(size), angles, np.zeros(len(angles), bool), np.zeros(len(angles)))
