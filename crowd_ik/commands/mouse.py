"""`crowd-ik mouse`: argument handling and reporting; the work is in crowd_ik/mouse/."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from crowd_ik.mouse.live import live_chain, live_humanoid
from crowd_ik.mouse.replay import replay_keyframes, replay_path
from crowd_ik.mouse.session import (
    DEFAULT_BONES,
    HUMANOID_METHODS,
    MAX_BONES,
    NO_DISPLAY,
)
from crowd_ik.view.display import display_available

# ---------------------------------------------------------------------------------------------
# command line


def _parse_size(text: str) -> tuple[int, int]:
    from crowd_ik.io.video import check_size

    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise ValueError(f"--size: expected WxH, e.g. 720x720 (got {text!r})") from None
    return check_size((w, h), "--size")


def run(args) -> int:
    """Handler of `crowd-ik mouse` (see cli.py for the arguments)."""
    from crowd_ik import runtime

    size = _parse_size(args.size)
    if args.fps is not None and not (math.isfinite(args.fps) and 0 < args.fps <= 1000):
        raise ValueError(f"--fps: expected a number in (0, 1000] (got {args.fps:g})")
    if args.bones is not None and not 1 <= args.bones <= MAX_BONES:
        raise ValueError(f"--bones: expected an integer in [1, {MAX_BONES}] (got {args.bones})")
    if args.path and args.keyframes:
        raise ValueError("--path and --keyframes: give one of them (got both)")
    replay = args.path or args.keyframes
    if args.rig == "humanoid":
        if replay or args.output:
            raise ValueError("--rig humanoid: the humanoid is live only; --path, --keyframes and -o replay the chain")
        if args.method not in HUMANOID_METHODS:
            raise ValueError(f"--method: the humanoid is solved with {', '.join(HUMANOID_METHODS)} (got {args.method})")
    elif replay:
        output = args.output or f"{Path(replay).stem}.mp4"
        runtime.init(args.arch, args.threads)
        if args.path:
            result = replay_path(args.path, output, n_bones=args.bones or DEFAULT_BONES, method=args.method,
                                 limits=args.limits, size=size, fps=args.fps, force=args.force)
            extra = f"; target lost on {int(result.lost.sum())} of them"
        else:
            result = replay_keyframes(args.keyframes, output, n_bones=args.bones, limits=args.limits, size=size,
                                      fps=args.fps, k1=args.k1, k2=args.k2, force=args.force)
            extra = ""
        print(f"crowd-ik mouse: wrote {result.output} ({result.frames} frames, {size[0]}x{size[1]}, "
              f"{result.fps:g} fps{extra})")
        return 0
    elif args.output:
        raise ValueError(f"-o {args.output}: needs --path PATH.csv or --keyframes FILE.csv to replay (the window writes no video)")
    if not display_available():
        raise ValueError(NO_DISPLAY)
    runtime.init(args.arch, args.threads)
    sys.stdout.flush()
    if args.rig == "humanoid":
        return live_humanoid(args.method, size)
    return live_chain(args.bones or DEFAULT_BONES, args.method, args.limits, size)


__all__ = ["run"]
