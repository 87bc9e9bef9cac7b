"""`crowd-ik play`: simulate a scene and render it to a video (or one still), with a progress bar
on stderr and a one-screen summary on stdout.

Order of work: check the arguments and that every output may be written (no clobbering without
--force) before anything is simulated; start Taichi once; build the World; then step and render
frame by frame into the sink through crowd_ik.io.pipeline (a writer thread feeds the sink, and the
encoder its own process, while the next frame is simulated; --serial does one stage after another,
the same frames). Ctrl-C finalises the frames handed over so far as a shorter, playable video (a --clip
keeps those frames too) and the CLI exits with 130.

--live plays in a window (crowd_ik.commands.live; --record F.csv saves the inputs); --inputs F.csv replays
such a recording headless, one video frame per row, with the recorded fps, size, seed and solver
unless the command line gives others; --clip F.npz also saves every body's root transforms and
joint angles per video frame (crowd_ik.io.clip); --labels F.jsonl writes every frame's pose labels
(camera, COCO keypoints with z-buffer visibility, 3D joints, boxes; crowd_ik.io.labels).
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from pathlib import Path

from crowd_ik import runtime
from crowd_ik.io.output import check_writable, check_writable_dir, is_dir_target, write_json
from crowd_ik.io.stats import format_summary, summary
from crowd_ik.commands.play_args import build_scene, check_modes  # noqa: F401  (play's API too)
from crowd_ik.scene import Scene, scene_with

def output_path(args, scene: Scene) -> str:
    """-o, or ./<scene>.mp4 (./<scene>_frame<K>.png with --still K)."""
    if args.output is not None:
        return args.output
    if args.still is not None:
        return f"{scene.name}_frame{args.still}.png"
    return f"{scene.name}.mp4"


def check_outputs(args, scene: Scene, out: str) -> None:
    """Refuse bad or existing outputs before any simulation (FileExistsError without --force)."""
    if args.still is not None:
        if args.still < 0 or args.still >= scene.n_frames:
            raise ValueError(f"--still: frame must be in [0, {scene.n_frames - 1}] for this scene's "
                             f"{scene.n_frames} frames (got {args.still})")
        if is_dir_target(out) or Path(out).suffix.lower() != ".png":
            raise ValueError(f"-o: a still is written as a .png file (got {out!r})")
        check_writable(out, args.force)
    elif is_dir_target(out):
        check_writable_dir(out, args.force)
    else:
        from crowd_ik.io.video import VIDEO_SUFFIXES

        suffix = Path(out).suffix.lower()
        if suffix == ".png":
            raise ValueError(f"-o: {out} is a single still; add --still K for one frame, or end the path "
                             f"with '/' for a folder of PNG frames")
        if suffix not in VIDEO_SUFFIXES:
            raise ValueError(f"-o: unknown video suffix {suffix or '(none)'!r} in {out!r}; use .mp4 (H.264), "
                             f".webm (VP8) or a folder ending in '/'")
        check_writable(out, args.force)
    if args.stats is not None:
        if Path(args.stats).suffix.lower() != ".json":
            raise ValueError(f"--stats: expected a .json file (got {args.stats!r})")
        if os.path.abspath(args.stats) == os.path.abspath(out):
            raise ValueError(f"--stats: {args.stats} is also the video output")
        check_writable(args.stats, args.force)
    if getattr(args, "clip", None) is not None:
        if Path(args.clip).suffix.lower() != ".npz":
            raise ValueError(f"--clip: a clip is written as a .npz file (got {args.clip!r})")
        check_writable(args.clip, args.force)
    if getattr(args, "labels", None) is not None:
        from crowd_ik.io.labels import check_labels_path

        check_labels_path(args.labels, args.force)
        for flag, other in (("-o", out), ("--stats", args.stats), ("--clip", getattr(args, "clip", None))):
            if other is not None and os.path.abspath(args.labels) == os.path.abspath(other):
                raise ValueError(f"--labels: {args.labels} is also the {flag} output")


def _progress(total: int, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", file=sys.stderr, dynamic_ncols=True, mininterval=0.5,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} frames "
                           "[{elapsed}<{remaining}, {rate_fmt}]")


def _inputs_scene(args, log) -> Scene:
    """The scene of a replay: the recorded settings as defaults, one video frame per row (or the
    first --frames / --seconds worth of them)."""
    scene = build_scene(args, log.settings)
    if args.frames is None and args.seconds is None:
        return scene_with(scene, frames=len(log))
    if scene.n_frames > len(log):
        flag = "--frames" if args.frames is not None else "--seconds"
        raise ValueError(f"{flag}: {log.path} holds {len(log)} frames of inputs (got {scene.n_frames} frames)")
    return scene


def run(args) -> int:
    """`crowd-ik play`: see the module docstring."""
    t_start = time.perf_counter()
    check_modes(args)
    if args.live:
        from crowd_ik.commands import live

        return live.run(args)
    log = None
    if args.inputs is not None:
        from crowd_ik.io.inputs import load_inputs

        log = load_inputs(args.inputs)
        scene = _inputs_scene(args, log)
    else:
        scene = build_scene(args)
    out = output_path(args, scene)
    check_outputs(args, scene, out)
    arch = runtime.init(arch=args.arch, threads=args.threads)
    from crowd_ik.io.render_process import started_early

    with started_early(_draws_in_process(args, scene)) as early:
        return _play(args, scene, log, out, arch, early, t_start)


def _draws_in_process(args, scene) -> bool:
    """Whether the pipeline will draw this video in a second process (io.render_process), which play then starts
    before building the World: not for a still, --serial, or --labels (whose visibility test reads each frame's
    z-buffer in this process right after it is drawn)."""
    from crowd_ik.io.pipeline import wants_render_process

    if args.still is not None or getattr(args, "serial", False) or args.labels is not None:
        return False
    return wants_render_process(scene)


def _play(args, scene, log, out, arch, early, t_start) -> int:
    from crowd_ik.game.world import World
    from crowd_ik.io.video import open_sink, write_png

    from crowd_ik.session import frames

    world = World(scene, hud_timings=args.hud_timings, open_ended=log is not None)
    count = (args.still + 1) if args.still is not None else scene.n_frames
    steps = frames(world, count, log.inputs if log is not None else None)

    clip = None
    if args.clip is not None:
        from crowd_ik.io.clip import ClipRecorder

        clip = ClipRecorder(world, count)
    labels = contextlib.nullcontext()
    if args.labels is not None:
        from crowd_ik.io.labels import LabelsWriter

        labels = LabelsWriter(args.labels, force=args.force)
    pipeline = None
    try:
        if args.still is not None:
            with labels, _progress(args.still + 1, f"{scene.name} still") as bar:
                for k in steps:
                    if clip is not None:
                        clip.add(world)
                    if k < args.still:
                        bar.update()
                frame = world.render()
                if args.labels is not None:
                    labels.add(world, args.still)
                bar.update()
                write_png(out, frame, force=args.force)
            rendered = 1
        else:
            from crowd_ik.io.pipeline import render_video

            def after(k):
                if args.labels is not None:
                    labels.add(world, k)
                bar.update()

            with labels, _progress(scene.n_frames, scene.name) as bar:
                sink = open_sink(out, scene.video.fps, (scene.video.width, scene.video.height), force=args.force)
                pipeline = render_video(world, steps, sink, serial=getattr(args, "serial", False),
                                        before=(lambda k: clip.add(world)) if clip is not None else None, after=after,
                                        render_process=early if early is not None else False)
            rendered = pipeline["frames"]
    except KeyboardInterrupt:
        if clip is not None and clip.count:
            clip.save(args.clip, force=args.force)  # the frames simulated so far, like the video
        raise
    if clip is not None:
        clip.save(args.clip, force=args.force)
    info = summary(world, scene, out, time.perf_counter() - t_start, arch, rendered, pipeline)
    if log is not None:
        info["inputs"] = str(args.inputs)
        info["player_shots"] = world.player.shots
    if clip is not None:
        info["clip"] = str(args.clip)
    if args.labels is not None:
        info["labels"] = str(args.labels)
    if args.stats is not None:
        write_json(args.stats, info, force=args.force)
    print(format_summary(info), flush=True)
    if log is not None:
        print(f"  inputs      {args.inputs} ({len(log)} rows, {world.player.shots} player shots)")
    if clip is not None:
        print(f"  clip        {args.clip} ({clip.count} frames)")
    if args.labels is not None:
        print(f"  labels      {args.labels} ({labels.count} frames)")
    if args.stats is not None:
        print(f"  stats       {args.stats}")
    return 0


__all__ = ["run", "check_modes", "build_scene", "output_path", "check_outputs", "summary", "format_summary"]
