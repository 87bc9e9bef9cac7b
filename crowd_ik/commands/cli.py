"""Command line: `crowd-ik play | mouse | bench | export | animate | scenes`.

Each subcommand's work lives in its own module (play.py, mouse.py, bench.py, export.py, scene.py);
this file only declares the arguments and maps errors to exit codes:
0 done; 1 failure at run time (an OS error such as a full disk is one line naming the file); 2 bad
input or an existing output without --force; 130 interrupted by Ctrl-C, 143 by SIGTERM (handled like
Ctrl-C: the shorter video is finalised and the encoder waited for).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import threading

from crowd_ik import __version__
from crowd_ik.solvers.registry import DEFAULT, METHODS, PLANAR_DEFAULT, PLANAR_METHODS

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143


class Terminated(KeyboardInterrupt):
    """SIGTERM (timeout, docker stop, CI) raised as an interrupt, so that every `except KeyboardInterrupt`
    and sink finalises the work so far as Ctrl-C does; main() then returns 143."""


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """Raise Terminated on the first SIGTERM while the command runs (a second one is ignored, so that it
    cannot cut the finalisation short); the previous handler is restored afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _os_error_line(exc: OSError) -> str:
    """`FILE: strerror` for an OS error with a file name, else its text."""
    if exc.errno is not None and exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    return str(exc)


class UsageError(ValueError):
    """Bad input the user can fix; printed as one line, exit code 2."""


def _add_common_runtime(p: argparse.ArgumentParser) -> None:
    p.add_argument("--arch", choices=("auto", "cpu", "cuda"), default="auto", help="Taichi backend (default: auto = CUDA if present, else CPU)")
    p.add_argument("--threads", type=int, default=None, help="CPU threads for Taichi (default: all cores)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="crowd-ik",
        description="Batched inverse kinematics for crowds of characters, a SUPERHOT-style bullet game, and its video.",
    )
    parser.add_argument("--version", action="version", version=f"crowd-ik {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    play = sub.add_parser("play", help="render a gameplay video of a scene (default: the arena)")
    play.add_argument("scene", nargs="?", default=None, help="scene TOML (default: the built-in arena)")
    play.add_argument("-o", "--output", default=None, help="OUT.mp4 (H.264), OUT.webm (VP8), DIR/ (PNG frames), or a .png with --still (default: ./<scene>.mp4)")
    length = play.add_mutually_exclusive_group()
    length.add_argument("--frames", type=int, default=None, help="number of video frames")
    length.add_argument("--seconds", type=float, default=None, help="video length in seconds")
    play.add_argument("--size", default=None, metavar="WxH", help="frame size, e.g. 1280x720 (even numbers)")
    play.add_argument("--fps", type=float, default=None, help="video frame rate")
    play.add_argument("--seed", type=int, default=None, help="random seed (overrides the scene)")
    play.add_argument("--solver", choices=METHODS, default=None, help="IK method (overrides the scene)")
    play.add_argument("--stats", default=None, metavar="F.json", help="write the run summary as JSON")
    play.add_argument("--still", type=int, default=None, metavar="K", help="write only frame K as a PNG (-o F.png)")
    play.add_argument("--live", action="store_true", help="play in a window (WASD to move, mouse to aim, click to fire)")
    play.add_argument("--record", default=None, metavar="F.csv", help="with --live: save the player's inputs")
    play.add_argument("--inputs", default=None, metavar="F.csv", help="replay recorded inputs headless")
    play.add_argument("--clip", default=None, metavar="F.npz", help="also save every character's root transforms and joint angles")
    play.add_argument("--labels", default=None, metavar="F.jsonl",
                      help="also write per-frame pose labels: camera, COCO keypoints with visibility, 3D joints, boxes")
    play.add_argument("--force", action="store_true", help="overwrite existing outputs")
    play.add_argument("--hud-timings", action="store_true",
                      help="show measured milliseconds in the HUD (frames then differ run to run)")
    play.add_argument("--serial", action="store_true",
                      help="draw, paint and encode one frame after another on one thread (no writer thread; same frames)")
    _add_common_runtime(play)
    play.set_defaults(handler="crowd_ik.commands.play:run")

    mouse = sub.add_parser("mouse", help="single-character IK: drag the target with the mouse, or replay a path to video")
    mouse.add_argument("--bones", type=int, default=None, help="planar chain bones (default 4; with --keyframes, the file's angle count)")
    mouse.add_argument("--rig", choices=("chain", "humanoid"), default="chain", help="chain (planar) or humanoid (3D)")
    mouse.add_argument("--method", choices=PLANAR_METHODS, default=PLANAR_DEFAULT,
                       help=f"IK method (default {PLANAR_DEFAULT})")
    mouse.add_argument("--limits", action="store_true", help="honour joint limits")
    mouse.add_argument("--path", default=None, metavar="PATH.csv", help="replay a target path (CSV t,x,y) to video")
    mouse.add_argument("--keyframes", default=None, metavar="FILE.csv", help="ease between key poses (CSV duration_s, angles in degrees)")
    mouse.add_argument("--k1", type=float, default=0.2, help="ease-in end, 0..1 (default 0.2)")
    mouse.add_argument("--k2", type=float, default=0.75, help="ease-out start, k1..1 (default 0.75)")
    mouse.add_argument("--fps", type=float, default=None, help="resample the path on t at this rate")
    mouse.add_argument("--size", default="720x720", metavar="WxH", help="frame size (default 720x720)")
    mouse.add_argument("-o", "--output", default=None, help="OUT.mp4 | OUT.webm | DIR/")
    mouse.add_argument("--force", action="store_true", help="overwrite existing outputs")
    _add_common_runtime(mouse)
    mouse.set_defaults(handler="crowd_ik.commands.mouse:run")

    bench = sub.add_parser("bench", help="IK throughput against character count, solver and backend, beside a NumPy baseline")
    bench.add_argument("--chars", default=None, help="comma-separated character counts (default 100,1000,10000,100000)")
    bench.add_argument("--solver", default=None, help="comma-separated: fabrik,dls,ccd (default all)")
    bench.add_argument("--rig", default=None, help="comma-separated: chain16,humanoid (default both)")
    bench.add_argument("--arch", default=None, help="comma-separated: cpu,cuda (default cpu, plus cuda when present; "
                       "cuda without a GPU is refused with exit 2)")
    bench.add_argument("--threads", type=int, default=None, help="CPU threads for Taichi (default: all cores)")
    bench.add_argument("--json", default=None, metavar="F.json", help="write the results as JSON")
    bench.add_argument("--plot", default=None, metavar="F.png", help="write a log-log chart")
    bench.add_argument("--compare", default=None, metavar="OLD.json", help="print the change against an earlier --json")
    bench.add_argument("--repeats", type=int, default=None, help="timed repeats per cell, best kept (default 3; --quick 1)")
    bench.add_argument("--baseline-budget", type=float, default=None, metavar="S",
                       help="seconds of NumPy baseline per cell, 0 to skip it (default 10; --quick 1)")
    bench.add_argument("--game-chars", type=int, default=None, metavar="N",
                       help="humanoids in the warm-start game workload, 0 to skip it (default 10000; --quick 256)")
    bench.add_argument("--peers", default=None, metavar="numba",
                       help="also time compiled peers on chain16 FABRIK/DLS (numba: pip install -e '.[peers]')")
    bench.add_argument("--render-frames", type=int, default=None, metavar="N",
                       help="frames per scene of the render workload: arena, crowd_1k, stress_10k to H.264, "
                            "frames/s (default 90; --quick 0 = skipped)")
    bench.add_argument("--quick", action="store_true", help="small defaults for a smoke test (explicit flags win)")
    bench.add_argument("--force", action="store_true", help="overwrite existing outputs")
    bench.set_defaults(handler="crowd_ik.bench.run:run")

    export = sub.add_parser("export", help="export a posed world (.glb) or a character's motion (.bvh)")
    export.add_argument("scene", nargs="?", default=None, help="scene TOML (default: the built-in arena)")
    export.add_argument("--frame", type=int, default=0, help="frame to export as .glb (default 0)")
    export.add_argument("-o", "--output", default=None, help="OUT.glb")
    export.add_argument("--bvh", default=None, metavar="OUT.bvh", help="write one character's motion as BVH")
    export.add_argument("--character", type=int, default=None, help="character index for --bvh (default 0)")
    export.add_argument("--characters", default=None, metavar="all|K,L,...",
                        help="several characters: --bvh writes one ROOT each; --animated .glb (default all)")
    export.add_argument("--animated", action="store_true",
                        help="-o F.glb: the characters' motion over --frames as an animated, skinned .glb")
    export.add_argument("--frames", type=int, default=None, help="frames of motion for --bvh or --animated")
    export.add_argument("--force", action="store_true", help="overwrite existing outputs")
    _add_common_runtime(export)
    export.set_defaults(handler="crowd_ik.commands.export:run")

    many = sub.add_parser("render-many", help="render many videos (scenes x seeds x solvers) on Ray; resumable")
    many.add_argument("jobs", metavar="JOBS", help="jobs TOML: scenes/seeds/solvers sweep or [[job]] tables, [overrides]")
    many.add_argument("-o", "--output", required=True, metavar="DIR/", help="folder of the videos and manifest.jsonl")
    many.add_argument("--address", default=None, metavar="auto|HOST:PORT",
                      help="join a running Ray cluster (default: start a local Ray instance on this machine)")
    many.add_argument("--workers", type=int, default=None,
                      help="worker processes (default: the CPUs Ray offers / --threads, at most one per job)")
    many.add_argument("--retries", type=int, default=1, help="extra attempts for a failed job (default 1)")
    many.add_argument("--force", action="store_true", help="render complete jobs again and overwrite outputs")
    many.add_argument("--arch", choices=("auto", "cpu", "cuda"), default="auto", help="Taichi backend of the workers")
    many.add_argument("--threads", type=int, default=None,
                      help="CPU threads per worker (default: local cores / workers; 1 on a cluster)")
    many.set_defaults(handler="crowd_ik.commands.render_many:run")

    animate = sub.add_parser("animate", help="play a BVH clip on a crowd with IK on top (feet planted) and render it")
    animate.add_argument("clip", metavar="CLIP.bvh", help="motion clip (BVH; any channel order, m or cm)")
    animate.add_argument("-o", "--output", default=None, help="OUT.mp4 | OUT.webm | DIR/ (default: ./<clip>.mp4)")
    animate.add_argument("--count", type=int, default=1, help="characters (default 1)")
    animate.add_argument("--spacing", type=float, default=1.5, help="metres between characters (default 1.5)")
    animate.add_argument("--stagger", type=float, default=0.0, metavar="SECONDS",
                         help="each character plays the clip this much later than the previous (default 0)")
    animate.add_argument("--blend", default=None, metavar="foot_l=1,hand_l=0.5",
                         help="per effector, 0 = the clip, 1 = the IK target (default: feet 1, others 0)")
    animate.add_argument("--solver", choices=METHODS, default=DEFAULT, help=f"IK method (default {DEFAULT})")
    animate.add_argument("--frames", type=int, default=None, help="video frames (default: the clip's)")
    animate.add_argument("--size", default="1280x720", metavar="WxH", help="frame size (default 1280x720)")
    animate.add_argument("--units", choices=("auto", "m", "cm"), default="auto",
                         help="the clip's length unit (default auto: cm when the skeleton is taller than 10)")
    animate.add_argument("--force", action="store_true", help="overwrite an existing output")
    _add_common_runtime(animate)
    animate.set_defaults(handler="crowd_ik.commands.animate:run")

    scenes = sub.add_parser("scenes", help="list the shipped scenes, or check one and print its effective values")
    scenes.add_argument("file", nargs="?", default=None, help="scene TOML to check")
    scenes.set_defaults(handler="crowd_ik.commands.scenes:run")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "handler", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    module, func = args.handler.split(":")
    try:
        with _sigterm_as_interrupt():
            handler = getattr(importlib.import_module(module), func)
            return int(handler(args) or EXIT_OK)
    except Terminated:
        print("crowd-ik: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        print("crowd-ik: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # `crowd-ik scenes X | head`: the reader has what it wanted
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so that the interpreter's final flush does not fail again
        return EXIT_OK
    except FileExistsError as exc:
        print(f"crowd-ik: {exc} (use --force to overwrite)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError) as exc:
        print(f"crowd-ik: {_os_error_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ValueError as exc:
        print(f"crowd-ik: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:  # no space left, permission denied, read-only file system: one line, not a traceback
        print(f"crowd-ik: error: {_os_error_line(exc)}", file=sys.stderr)
        return EXIT_FAILURE
    except RuntimeError as exc:
        print(f"crowd-ik: error: {exc}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    raise SystemExit(main())
