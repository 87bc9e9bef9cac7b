"""`crowd-ik export SCENE --frame K -o F.glb`: the world at frame K as coloured capsule meshes in a .glb.

The scene is simulated exactly as `crowd-ik play` would up to frame K; every limb capsule of that
frame (characters, shooters with their guns, the player, shards) and every bullet becomes part of
a mesh, one mesh per body: `character_<i>` for each standing character, `shooter_<k>` for each
standing shooter, `player`, and `shards` / `bullets` when there are any. glTF's axes are the
world's: y up, metres.

The meshes are built by crowd_ik.io.glb. The file is written atomically and never clobbers an existing one without --force.

`crowd-ik export SCENE --bvh OUT.bvh --character K [--frames N]` writes character K's motion as
BVH (crowd_ik.io.clip: metres, y up, one BVH frame per video frame). SCENE is simulated as `play`
would for N frames (default the scene's frame count), without rendering; SCENE may instead be a
clip saved by `crowd-ik play ... --clip F.npz` (a live session replayed with --inputs, say), whose
first N frames are then written. `--characters all|K,L,...` instead writes several characters into
one file, one ROOT each (joint names prefixed c<K>_).

`crowd-ik export SCENE --animated [-o F.glb] [--characters all|K,L,...] [--frames N]` writes the
characters' motion (all by default) as an animated .glb: per character a capsule mesh skinned to its
joint nodes and one animation of their rotations and the root's translation (crowd_ik.io.gltf).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from crowd_ik import runtime
from crowd_ik.io.glb import world_meshes, write_glb
from crowd_ik.io.output import check_writable
from crowd_ik.scene import load_scene

def _pick(text: str, valid: list[int], source: str) -> list[int]:
    """--characters "all" or "K,L,...": indices among valid (a scene's 0..N-1, or those a clip holds)."""
    if text.strip() == "all":
        return list(valid)
    try:
        picked = [int(k) for k in text.split(",")]
    except ValueError:
        raise ValueError(f"--characters: expected 'all' or indices such as 0,2,5 (got {text!r})") from None
    for k in picked:
        if k not in valid:
            shown = f"0..{valid[-1]}" if valid == list(range(len(valid))) else str(valid[:10])
            raise ValueError(f"--characters: {source} has characters {shown} (got {k})")
    if len(set(picked)) != len(picked):
        raise ValueError(f"--characters: an index repeats (got {text!r})")
    return picked


def _motion(args, out: str, what: str, default_all: bool):
    """(clip arrays, source name, characters) for --bvh or --animated: a scene simulated as `play` would
    for --frames N (default its own), or the first N frames of a clip .npz. characters: an int for
    --character K, else the list --characters names (all by default when default_all)."""
    from crowd_ik.io.clip import load_clip, record_clip
    from crowd_ik.scene import scene_with

    if args.character is not None and args.characters is not None:
        raise ValueError(f"--character: give --character K or --characters {args.characters}, not both")
    if args.character is not None and args.character < 0:
        raise ValueError(f"--character: must be zero or a positive integer (got {args.character})")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames: must be a positive integer (got {args.frames})")
    wanted = args.characters if args.characters is not None else ("all" if default_all and args.character is None
                                                                   else None)
    single = 0 if args.character is None else args.character
    source = args.scene
    if source is not None and Path(source).suffix.lower() == ".npz":
        check_writable(out, args.force)
        clip = load_clip(source)
        available = len(clip["frame"])
        if args.frames is not None and args.frames > available:
            raise ValueError(f"--frames: {source} holds {available} frames (got {args.frames})")
        if args.frames is not None:
            for key in [k for k in clip if k.endswith(("_root", "_yaw", "_angles", "_alive"))]:
                clip[key] = clip[key][: args.frames]
        name = Path(source).name
        held = [int(k) for k in clip["characters_index"]]
        return clip, name, single if wanted is None else _pick(wanted, held, name)
    scene = load_scene(source)
    if args.frames is not None:
        scene = scene_with(scene, frames=args.frames)
    count = scene.characters.count
    if wanted is None and single >= count:
        raise ValueError(f"--character: {scene.name} has {count} characters, 0..{count - 1} (got {single})")
    characters = single if wanted is None else _pick(wanted, list(range(count)), scene.name)
    check_writable(out, args.force)
    runtime.init(arch=args.arch, threads=args.threads)
    record = [characters] if wanted is None else characters
    return record_clip(scene, characters=record, what=what), scene.name, characters


def _alive_note(clip, characters: list[int]) -> str:
    index = [int(k) for k in clip["characters_index"]]
    alive = np.asarray(clip["characters_alive"])[:, [index.index(k) for k in characters]]
    hits = [f"{k} at frame {int(np.argmin(alive[:, i]))}" for i, k in enumerate(characters) if not alive[:, i].all()]
    return f"; hit: {', '.join(hits[:8])}{' ...' if len(hits) > 8 else ''} (still after)" if hits else ""


def run_bvh(args) -> int:
    """`crowd-ik export SCENE --bvh OUT.bvh [--character K | --characters all|K,L,...] [--frames N]`."""
    from crowd_ik.io.clip import bvh_from_clip, bvh_joints
    from crowd_ik.io.output import write_text

    out = args.bvh
    if Path(out).suffix.lower() != ".bvh":
        raise ValueError(f"--bvh: motion is written as a .bvh file (got {out!r})")
    if args.output is not None:
        raise ValueError(f"-o: with --bvh the output is the --bvh file (got -o {args.output})")
    if args.animated:
        raise ValueError("--animated: writes a .glb given with -o; --bvh writes the BVH")
    if args.frame != 0:
        raise ValueError(f"--frame: picks the .glb's frame; with --bvh give the length with --frames N "
                         f"(got --frame {args.frame})")
    clip, name, characters = _motion(args, out, "--bvh", default_all=False)
    rig, text = bvh_from_clip(clip, characters, name)
    write_text(out, text, force=args.force)
    many = isinstance(characters, list)
    chosen = characters if many else [characters]
    frames = len(clip["characters_root"])
    channels = len(bvh_joints(rig))
    who = f"{len(chosen)} characters ({', '.join(map(str, chosen[:8]))}{' ...' if len(chosen) > 8 else ''}), " \
          f"one ROOT each, joints named c<K>_..." if many else f"character {characters}"
    print(f"{out}: {who} of {name}, {frames} frames at {float(clip['fps']):g} fps, "
          f"{channels} joints with channels and {rig.n_joints - channels} end sites, metres, y up"
          f"{_alive_note(clip, chosen)}")
    return 0


def run_animated(args) -> int:
    """`crowd-ik export SCENE --animated [-o F.glb] [--characters all|K,L,...] [--frames N]`: the
    characters' motion as skinned capsule meshes with one animation (crowd_ik.io.gltf)."""
    from crowd_ik.io.clip import rig_from_arrays
    from crowd_ik.io.gltf import write_animated_glb

    if args.frame != 0:
        raise ValueError(f"--frame: picks a still .glb's frame; with --animated give the length with --frames N "
                         f"(got --frame {args.frame})")
    stem = Path(args.scene).stem if args.scene is not None else "arena"
    out = args.output if args.output is not None else f"{stem}_motion.glb"
    if Path(out).suffix.lower() != ".glb":
        raise ValueError(f"-o: an animated scene is written as a .glb file (got {out!r})")
    clip, name, characters = _motion(args, out, "--animated", default_all=True)
    chosen = characters if isinstance(characters, list) else [characters]
    index = [int(k) for k in clip["characters_index"]]
    cols = [index.index(k) for k in chosen]
    rig = rig_from_arrays(clip, "characters", name)
    root, yaw, angles = (clip[f"characters_{key}"][:, cols] for key in ("root", "yaw", "angles"))
    write_animated_glb(out, rig, root, yaw, angles, float(clip["fps"]), [f"character_{k}" for k in chosen],
                       force=args.force)
    print(f"{out}: {len(chosen)} characters of {name}, {len(root)} frames at {float(clip['fps']):g} fps, "
          f"{rig.n_joints} joints each, skinned capsules with one animation, metres, y up"
          f"{_alive_note(clip, chosen)}")
    return 0


def run(args) -> int:
    """`crowd-ik export`: simulate the scene to --frame K and write its capsules to a .glb
    (with --bvh: one character's motion, see run_bvh)."""
    if getattr(args, "bvh", None):
        return run_bvh(args)
    if getattr(args, "animated", False):
        return run_animated(args)
    if getattr(args, "frames", None) is not None:
        raise ValueError(f"--frames: only with --bvh or --animated; a .glb is one frame, chosen with --frame K "
                         f"(got --frames {args.frames})")
    for flag in ("character", "characters"):
        if getattr(args, flag, None) is not None:
            raise ValueError(f"--{flag}: only with --bvh or --animated; a still .glb holds every body")
    if args.frame < 0:
        raise ValueError(f"--frame: must be zero or a positive integer (got {args.frame})")
    scene = load_scene(args.scene)
    if args.frame >= scene.n_frames:  # the scene's own length bounds the simulation (no run until killed)
        raise ValueError(f"--frame: {args.scene} has {scene.n_frames} frames, so 0 to {scene.n_frames - 1} "
                         f"(got {args.frame})")
    out = args.output if args.output is not None else f"{scene.name}_frame{args.frame}.glb"
    if Path(out).suffix.lower() != ".glb":
        raise ValueError(f"-o: the posed world is written as a .glb file (got {out!r})")
    check_writable(out, args.force)
    runtime.init(arch=args.arch, threads=args.threads)
    from crowd_ik.game.world import World

    from tqdm import tqdm

    from crowd_ik.session import frames

    world = World(scene)
    for _ in tqdm(frames(world, args.frame + 1), total=args.frame + 1, desc=f"simulating {scene.name}",
                  unit="frame", file=sys.stderr, dynamic_ncols=True, leave=False, disable=args.frame < 30):
        pass
    meshes = world_meshes(world)
    write_glb(out, meshes, force=args.force)
    standing = sum(name.startswith("character_") for name in meshes)
    shooters = sum(name.startswith("shooter_") for name in meshes)
    print(f"{out}: frame {args.frame} of {scene.name}, {len(meshes)} meshes "
          f"({standing} characters standing, {shooters} shooters, player"
          f"{', shards' if 'shards' in meshes else ''}{', bullets' if 'bullets' in meshes else ''})")
    return 0


__all__ = ["run", "run_bvh", "run_animated"]
