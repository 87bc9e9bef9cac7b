"""`crowd-ik play SCENE --live`: play in a window (view.window), record the inputs, report."""

from __future__ import annotations

import sys
from pathlib import Path

from crowd_ik.io.inputs import scene_settings, write_inputs
from crowd_ik.session import Session
from crowd_ik.view.window import display_available, no_display_message, play_window


def run(args) -> int:
    """`crowd-ik play SCENE --live [--record F.csv] [--stats F.json] [--size WxH] ...`."""
    from crowd_ik import runtime
    from crowd_ik.io.output import check_writable, write_json
    from crowd_ik.commands.play_args import build_scene
    from crowd_ik.io.stats import summary

    scene = build_scene(args)
    if args.record is not None:
        if Path(args.record).suffix.lower() != ".csv":
            raise ValueError(f"--record: inputs are written as a .csv file (got {args.record!r})")
        check_writable(args.record, args.force)
    if args.stats is not None:
        if Path(args.stats).suffix.lower() != ".json":
            raise ValueError(f"--stats: expected a .json file (got {args.stats!r})")
        check_writable(args.stats, args.force)
    if not display_available():
        raise ValueError(no_display_message(args.scene))
    arch = runtime.init(arch=args.arch, threads=args.threads)
    sys.stdout.flush()
    from crowd_ik.view.render import warm_kernels

    warm_kernels()  # before the window opens: its first frames would otherwise wait for the frame kernel
    from crowd_ik.game.world import World

    world = World(scene, hud_timings=args.hud_timings, open_ended=True)
    session = Session(world)
    try:
        result = play_window(session, (scene.video.width, scene.video.height))
    finally:  # an interrupted session keeps its inputs too
        if args.record is not None and session.log:
            write_inputs(args.record, session.log, scene_settings(scene), force=args.force)
    print(f"{scene.name} live: {result.frames} frames played ({result.shown} shown) in {result.wall_s:.1f} s, "
          f"{result.mean_fps:.1f} fps while playing (median {result.median_fps:.1f}); hits {world.hits}, "
          f"dodges {world.dodges}, shots {world.player.shots}, shooters down {world.shooters_down}/{world.n_shooters}")
    if args.record is not None:
        print(f"  inputs      {args.record}" if result.frames else "  inputs      none recorded (no frame played)")
    if args.stats is not None:
        info = summary(world, scene, args.record or "(window)", result.wall_s, arch, result.frames)
        info.update(live_fps=result.mean_fps, live_median_fps=result.median_fps, shown=result.shown,
                    player_shots=world.player.shots, player_start=result.player_start, player_end=result.player_end)
        write_json(args.stats, info, force=args.force)
        print(f"  stats       {args.stats}")
    return 0
