"""`crowd-ik export SCENE --frame K -o F.glb`: the world at frame K as coloured capsule meshes in a .glb.

The scene is simulated exactly as `crowd-ik play` would up to frame K; every limb capsule of that
frame (characters, shooters with their guns, the player, shards) and every bullet becomes part of
a mesh, one mesh per body: `character_<i>` for each standing character, `shooter_<k>` for each
standing shooter, `player`, and `shards` / `bullets` when there are any. glTF's axes are the
world's: y up, metres.

The capsules are built from one trimesh capsule template, moved and scaled per capsule in one
vectorised step (its upper hemisphere goes to the capsule's end b, the lower one to a).
The file is written atomically and never clobbers an existing one without --force.

`crowd-ik export SCENE --bvh OUT.bvh --character K [--frames N]` writes character K's motion as
BVH (crowd_ik.io.clip: metres, y up, one BVH frame per video frame). SCENE is simulated as `play`
would for N frames (default the scene's frame count), without rendering; SCENE may instead be a
clip saved by `crowd-ik play ... --clip F.npz` (a live session replayed with --inputs, say), whose
first N frames are then written.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from crowd_ik import runtime
from crowd_ik.io.output import atomic_path, check_writable
from crowd_ik.scene import load_scene

TEMPLATE_COUNT = (8, 8)  # template capsule resolution (trimesh count): 66 vertices a capsule


def _template():
    """(unit offsets (V, 3), top (V,) bool, faces (F, 3)) of a unit-radius capsule along +z."""
    import trimesh

    mesh = trimesh.creation.capsule(height=1.0, radius=1.0, count=list(TEMPLATE_COUNT))
    v = np.asarray(mesh.vertices, np.float64)
    top = v[:, 2] > 0.0
    unit = v - np.where(top[:, None], [0.0, 0.0, 0.5], [0.0, 0.0, -0.5])
    return unit, top, np.asarray(mesh.faces, np.int64)


def capsule_vertices(a: np.ndarray, b: np.ndarray, radius: np.ndarray):
    """Vertices (M, V, 3) and shared faces (F, 3) of M capsules from a (M, 3) to b (M, 3) with radius (M,)."""
    unit, top, faces = _template()
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    axis = b - a
    length = np.linalg.norm(axis, axis=1, keepdims=True)
    z = np.where(length > 1e-9, axis / np.maximum(length, 1e-9), [0.0, 1.0, 0.0])
    helper = np.where(np.abs(z[:, 1:2]) < 0.9, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    basis = np.stack([x, y, z], axis=1)  # (M, 3, 3): rows are the capsule's local axes in the world
    offsets = np.einsum("vk,mkd->mvd", unit, basis) * np.asarray(radius, np.float64)[:, None, None]
    ends = np.where(top[None, :, None], b[:, None, :], a[:, None, :])
    return ends + offsets, faces


def world_meshes(world) -> dict:
    """{name: trimesh.Trimesh} of the world's current frame, one mesh per body (see the module docstring)."""
    import trimesh

    prim = world.primitives()
    caps, sph = prim["capsules"], prim["spheres"]
    names = list(prim["body_names"])
    a = np.concatenate([caps["a"], sph["center"]])
    b = np.concatenate([caps["b"], sph["center"]])
    radius = np.concatenate([caps["radius"], sph["radius"]])
    color = np.concatenate([caps["color"], sph["color"]])
    body = np.concatenate([caps["body"], np.full(len(sph["center"]), len(names), np.int32)])
    names.append("bullets")
    keep = radius > 0.0  # fully faded shards have nothing left to export
    a, b, radius, color, body = a[keep], b[keep], radius[keep], color[keep], body[keep]
    verts, faces = capsule_vertices(a, b, radius)
    V = verts.shape[1]
    rgba = np.empty((len(a), 4), np.uint8)
    rgba[:, :3] = np.clip(np.rint(color[:, ::-1] * 255.0), 0, 255)  # BGR -> RGB
    rgba[:, 3] = 255
    order = np.argsort(body, kind="stable")
    bodies, starts = np.unique(body[order], return_index=True)
    meshes = {}
    for owner, idx in zip(bodies, np.split(order, starts[1:])):
        k = len(idx)
        mesh_faces = (faces[None, :, :] + (np.arange(k) * V)[:, None, None]).reshape(-1, 3)
        meshes[names[owner]] = trimesh.Trimesh(
            vertices=verts[idx].reshape(-1, 3),
            faces=mesh_faces,
            vertex_colors=np.repeat(rgba[idx], V, axis=0),
            process=False,
        )
    return meshes


def write_glb(path, meshes: dict, force: bool = False) -> Path:
    """Write {name: mesh} as a binary glTF scene, atomically and without clobbering."""
    import trimesh

    scene = trimesh.Scene()
    for name, mesh in meshes.items():
        scene.add_geometry(mesh, geom_name=name, node_name=name)
    with atomic_path(path, force) as tmp:
        tmp.write_bytes(scene.export(file_type="glb"))
    return Path(path)


def run_bvh(args) -> int:
    """`crowd-ik export SCENE --bvh OUT.bvh --character K [--frames N]` (see the module docstring)."""
    from crowd_ik.io.clip import bvh_from_clip, bvh_joints, load_clip, record_clip
    from crowd_ik.io.output import write_text
    from crowd_ik.scene import scene_with

    out = args.bvh
    if Path(out).suffix.lower() != ".bvh":
        raise ValueError(f"--bvh: motion is written as a .bvh file (got {out!r})")
    if args.output is not None:
        raise ValueError(f"-o: with --bvh the output is the --bvh file (got -o {args.output})")
    if args.frame != 0:
        raise ValueError(f"--frame: picks the .glb's frame; with --bvh give the length with --frames N "
                         f"(got --frame {args.frame})")
    if args.character < 0:
        raise ValueError(f"--character: must be zero or a positive integer (got {args.character})")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames: must be a positive integer (got {args.frames})")
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
    else:
        scene = load_scene(source)
        if args.frames is not None:
            scene = scene_with(scene, frames=args.frames)
        count = scene.characters.count
        if args.character >= count:
            raise ValueError(f"--character: {scene.name} has {count} characters, 0..{count - 1} (got {args.character})")
        check_writable(out, args.force)
        runtime.init(arch=args.arch, threads=args.threads)
        clip = record_clip(scene, characters=[args.character])
        name = scene.name
    rig, text = bvh_from_clip(clip, args.character, name)
    write_text(out, text, force=args.force)
    i = int(np.flatnonzero(np.asarray(clip["characters_index"]) == args.character)[0])
    alive = np.asarray(clip["characters_alive"])[:, i]
    frames = len(alive)
    hit = f"; hit at frame {int(np.argmin(alive))}, still after" if not alive.all() else ""
    channels = len(bvh_joints(rig))
    print(f"{out}: character {args.character} of {name}, {frames} frames at {float(clip['fps']):g} fps, "
          f"{channels} joints with channels and {rig.n_joints - channels} end sites, metres, y up{hit}")
    return 0


def run(args) -> int:
    """`crowd-ik export`: simulate the scene to --frame K and write its capsules to a .glb
    (with --bvh: one character's motion, see run_bvh)."""
    if getattr(args, "bvh", None):
        return run_bvh(args)
    if getattr(args, "frames", None) is not None:
        raise ValueError(f"--frames: only with --bvh; a .glb is one frame, chosen with --frame K "
                         f"(got --frames {args.frames})")
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

    world = World(scene)
    for _ in tqdm(range(args.frame), desc=f"simulating {scene.name}", unit="frame", file=sys.stderr,
                  dynamic_ncols=True, leave=False, disable=args.frame < 30):
        world.step()
    meshes = world_meshes(world)
    write_glb(out, meshes, force=args.force)
    standing = sum(name.startswith("character_") for name in meshes)
    shooters = sum(name.startswith("shooter_") for name in meshes)
    print(f"{out}: frame {args.frame} of {scene.name}, {len(meshes)} meshes "
          f"({standing} characters standing, {shooters} shooters, player"
          f"{', shards' if 'shards' in meshes else ''}{', bullets' if 'bullets' in meshes else ''})")
    return 0


__all__ = ["run", "run_bvh", "world_meshes", "write_glb", "capsule_vertices"]
