"""The play command's scene and mode from its arguments, shared by `play` and `play --live`."""

from __future__ import annotations

from crowd_ik.scene import Scene, load_scene, parse_size, scene_with


def check_modes(args) -> None:
    """Refuse flag combinations that mean nothing: --live plays a window (no video, no clip)."""
    if args.live:
        for flag, given in (("-o", args.output), ("--still", args.still), ("--inputs", args.inputs),
                            ("--clip", args.clip), ("--labels", getattr(args, "labels", None))):
            if given is not None:
                raise ValueError(f"{flag}: not with --live, which writes no video; record the inputs with "
                                 f"--record F.csv and render them with --inputs F.csv -o OUT.mp4")
    elif args.record is not None:
        raise ValueError(f"--record: records the inputs of a --live session (got --record {args.record} "
                         f"without --live)")


def build_scene(args, recorded: dict | None = None) -> Scene:
    """The scene file (or the built-in arena) with the command line's overrides applied and checked.

    recorded: settings of a recorded session (seed, fps, size, solver as text), used where the
    command line gives none.
    """
    scene = load_scene(args.scene)
    if args.seed is not None and args.seed < 0:
        raise ValueError(f"--seed: must be zero or a positive integer (got {args.seed})")
    size = None if args.size is None else parse_size(args.size, "--size")
    rec = recorded or {}
    seed = args.seed if args.seed is not None or "seed" not in rec else int(rec["seed"])
    fps = args.fps if args.fps is not None or "fps" not in rec else float(rec["fps"])
    if size is None and "size" in rec:
        size = parse_size(rec["size"], "size")
    method = args.solver if args.solver is not None else rec.get("solver")
    return scene_with(scene, seed=seed, frames=args.frames, seconds=args.seconds, fps=fps, size=size,
                      method=method)
