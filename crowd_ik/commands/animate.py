"""`crowd-ik animate CLIP.bvh [-o OUT.mp4] [--count N] [--spacing S] [--stagger SECONDS] [--blend ...]
[--solver ...]`: a BVH clip played on N characters with IK on top (crowd_ik.animation), rendered like
`play`, with a progress bar on stderr and a short summary on stdout.

The arguments and the output are checked before the clip is read; the output defaults to
./<clip stem>.mp4 and is never overwritten without --force.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from crowd_ik import runtime


def run(args) -> int:
    """`crowd-ik animate`: see the module docstring."""
    from crowd_ik.animation import animate, check_video_output, parse_blend
    from crowd_ik.io.video import check_size
    from crowd_ik.scene import parse_size

    t_start = time.perf_counter()
    if Path(args.clip).suffix.lower() != ".bvh":
        raise ValueError(f"CLIP: expected a .bvh file (got {args.clip!r})")
    if not Path(args.clip).is_file():
        raise FileNotFoundError(f"{args.clip}: no such file")
    if args.count < 1:
        raise ValueError(f"--count: must be a positive integer (got {args.count})")
    for flag, value in (("--spacing", args.spacing), ("--stagger", args.stagger)):
        if not value >= 0 or value == float("inf"):
            raise ValueError(f"{flag}: must be a finite number >= 0 (got {value})")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames: must be a positive integer (got {args.frames})")
    blend = parse_blend(args.blend) if args.blend is not None else None
    size = check_size(parse_size(args.size, "--size"), "--size")
    out = args.output if args.output is not None else f"{Path(args.clip).stem}.mp4"
    check_video_output(out, args.force)
    arch = runtime.init(arch=args.arch, threads=args.threads)
    from crowd_ik.io.bvh import load_bvh
    from tqdm import tqdm

    rig, motion = load_bvh(args.clip, units=args.units)
    missing = sorted(set(blend or {}) - set(rig.effector_names))
    if missing:
        raise ValueError(f"--blend: no effector {missing[0]!r} in {args.clip} (its effectors: "
                         f"{', '.join(rig.effector_names)})")
    total = args.frames or motion.n_frames
    bar = tqdm(total=total, desc=Path(args.clip).stem, unit="frame", file=sys.stderr, dynamic_ncols=True,
               mininterval=0.5)
    with bar:
        result = animate((rig, motion), out, count=args.count, spacing=args.spacing, stagger=args.stagger,
                         blend=blend, method=args.solver, frames=args.frames, size=size, force=args.force,
                         progress=lambda k: bar.update())
    feet = [e.name for e in rig.effectors if e.name.startswith("foot")]
    w, h = size
    planted = result.planted.mean() * rig.n_effectors / max(len(feet), 1) if feet else 0.0
    lines = [
        f"{args.clip}: {result.n_frames} frames, {w}x{h} at {motion.fps:g} fps -> {out}",
        f"  rig         {rig.n_joints} joints, {rig.n_dof} DOF, effectors {', '.join(rig.effector_names)}; "
        f"units {motion.units} (scale {motion.scale:g})",
        f"  characters  {args.count}, {args.spacing:g} m apart, {args.stagger:g} s stagger; solver {args.solver}",
    ]
    if feet:
        slide = ("no foot contact in the clip" if result.slide_clip != result.slide_clip else
                 f"feet in contact {100 * planted:.0f}% of frames, sliding {1000 * result.slide_clip:.1f} mm/s "
                 f"in the clip, {1000 * result.slide:.1f} mm/s after IK")
        lines.append(f"  contact     {slide}")
    else:
        lines.append("  contact     no foot effectors (names foot...): nothing planted")
    lines.append(f"  wall time   {time.perf_counter() - t_start:.1f} s on {arch}")
    print("\n".join(lines), flush=True)
    return 0


__all__ = ["run"]
