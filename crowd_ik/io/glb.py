"""A world's frame as a .glb: one coloured capsule mesh per body (trimesh), written atomically.

The capsules are built from one trimesh capsule template, moved and scaled per capsule in one
vectorised step (its upper hemisphere goes to the capsule's end b, the lower one to a; see
crowd_ik.io.gltf.capsule_vertices). glTF's axes are the world's: y up, metres.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from crowd_ik.io.gltf import capsule_vertices
from crowd_ik.io.output import atomic_path


def world_meshes(world) -> dict:
    """{name: trimesh.Trimesh} of the world's current frame, one mesh per body: character_<i> per standing
    character, shooter_<k> per standing shooter (with its gun), player, and shards / bullets when there are any."""
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


__all__ = ["world_meshes", "write_glb"]
