"""glTF in and out: a file's skin as a joint tree (``Rig.from_gltf``), and an animated .glb of bodies moving.

Reading (pygltflib): the one skin's joints become the rig's joints, in depth-first order of the node
tree (parents first); a joint's parent is its nearest ancestor among the skin's joints. The rest pose is
the nodes' transforms at load, ancestors of the skin's root joint included: each offset is the joint's
rest position minus its parent's, in world axes (glTF: y up, metres), so zero angles give the file's
rest pose. Joints with joint children are ball joints, leaf joints fixed; effectors as
crowd_ik.io.skeleton.find_effectors. Refused with ValueError("path: field: problem"): no skin or several,
several root joints, a node tree with a cycle or a node with two parents, non-uniform scale or shear
on a joint or its ancestors, NaN or infinite transforms, repeated joint names.

Writing (``animated_glb``): per body one capsule mesh skinned to a joint tree (each bone's capsule bound
wholly to its parent joint, which carries it rigidly), the nodes at the rig's rest pose, and one
animation "motion" whose channels set, per frame, the root joint's translation and every moving
joint's rotation (LINEAR, t = k / fps). glTF viewers and Blender play it as it is.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from crowd_ik.io.skeleton import Tree, joint_matrices, make_tree, matrix_to_quat, yaw_matrix

if TYPE_CHECKING:  # annotations only: rig.py builds rigs from these modules' trees
    from crowd_ik.rig import Rig

TEMPLATE_COUNT = (8, 8)  # template capsule resolution (trimesh count): 66 vertices a capsule
BODY_COLOR = (0.55, 0.62, 0.75, 1.0)  # RGBA base colour of the animated bodies
_SCALE_TOLERANCE = 1e-5  # relative: scale factors this close count as uniform


# ------------------------------------------------------------------------------------------------
# capsules


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


# ------------------------------------------------------------------------------------------------
# reading


def _node_matrix(path: str, i: int, node) -> np.ndarray:
    """(4, 4) local transform of node i, checked finite, with uniform scale and no shear."""
    where = f"{path}: nodes[{i}]"
    if node.matrix is not None:
        m = np.asarray(node.matrix, np.float64)
        if m.shape != (16,) or not np.all(np.isfinite(m)):
            raise ValueError(f"{where}.matrix: expected 16 finite numbers (got {node.matrix!r})")
        m = m.reshape(4, 4).T  # glTF stores column-major
        field = "matrix"
    else:
        t = np.asarray(node.translation if node.translation is not None else (0, 0, 0), np.float64)
        q = np.asarray(node.rotation if node.rotation is not None else (0, 0, 0, 1), np.float64)
        s = np.asarray(node.scale if node.scale is not None else (1, 1, 1), np.float64)
        for name, v, n in (("translation", t, 3), ("rotation", q, 4), ("scale", s, 3)):
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise ValueError(f"{where}.{name}: expected {n} finite numbers (got {v.tolist()})")
        norm = np.linalg.norm(q)
        if norm < 1e-9:
            raise ValueError(f"{where}.rotation: a zero quaternion (got {q.tolist()})")
        x, y, z, w = q / norm
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        m = np.eye(4)
        m[:3, :3] = R * s[None, :]
        m[:3, 3] = t
        field = "scale"
    gram = m[:3, :3].T @ m[:3, :3]
    s2 = float(np.trace(gram)) / 3.0
    if s2 <= 0 or np.abs(gram - s2 * np.eye(3)).max() > _SCALE_TOLERANCE * s2:
        shown = np.sqrt(np.clip(np.diag(gram), 0, None)).round(6).tolist()
        raise ValueError(f"{where}.{field}: non-uniform scale or shear (scale factors {shown}); "
                         f"a rig's joints need uniform scale")
    return m


def _tree(path: str, gltf) -> list[int]:
    """Each node's parent (-1 for none), refusing out-of-range children, two parents and cycles."""
    n = len(gltf.nodes)
    parent = [-1] * n
    for i, node in enumerate(gltf.nodes):
        for c in node.children or []:
            if not isinstance(c, int) or not 0 <= c < n:
                raise ValueError(f"{path}: nodes[{i}].children: no node {c!r} (the file has {n})")
            if c == i or parent[c] >= 0:
                what = "is its own child" if c == i else f"has two parents, nodes[{parent[c]}] and nodes[{i}]"
                raise ValueError(f"{path}: nodes[{i}].children: a cycle (nodes[{c}] {what})")
            parent[c] = i
    for i in range(n):  # with one parent each, a cycle is a walk up that comes back
        seen, k = set(), i
        while k >= 0:
            if k in seen:
                raise ValueError(f"{path}: nodes[{i}].children: a cycle through nodes[{k}]")
            seen.add(k)
            k = parent[k]
    return parent


def _check_glb_length(path: str) -> None:
    """A binary .glb's 12-byte header states its length: refuse a file cut short (or padded)."""
    with open(path, "rb") as fh:
        head = fh.read(12)
        size = fh.seek(0, os.SEEK_END)
    if head[:4] != b"glTF":
        return  # a JSON .gltf
    if len(head) < 12:
        raise ValueError(f"{path}: not a readable glTF file (a .glb header needs 12 bytes, got {len(head)})")
    version, length = struct.unpack("<II", head[4:])
    if version != 2 or length != size:
        raise ValueError(f"{path}: not a readable glTF file (.glb version {version}, header says {length} bytes, "
                         f"the file has {size}: truncated?)")


def read_gltf_tree(path, effectors=None) -> Tree:
    """The joint tree of a .glb/.gltf file's skin, for Rig.from_tree (see the module docstring)."""
    import pygltflib

    path = os.fspath(path)
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such file")
    _check_glb_length(path)
    try:
        gltf = pygltflib.GLTF2().load(path)
    except Exception as exc:  # pygltflib raises what its JSON, struct and dataclass layers raise
        raise ValueError(f"{path}: not a readable glTF file ({type(exc).__name__}: {exc})") from None
    if gltf is None:
        raise ValueError(f"{path}: not a readable glTF file")
    skins = gltf.skins or []
    if len(skins) != 1:
        raise ValueError(f"{path}: skins: expected one skin (got {len(skins)}); "
                         + ("a rig is read from a skin's joints" if not skins else "a rig is one skin"))
    joints = list(skins[0].joints or [])
    parent = _tree(path, gltf)
    n = len(gltf.nodes)
    bad = [j for j in joints if not isinstance(j, int) or not 0 <= j < n]
    if bad or len(set(joints)) != len(joints) or len(joints) < 2:
        raise ValueError(f"{path}: skins[0].joints: expected at least 2 distinct node indices below {n} "
                         f"(got {joints[:12]})")
    members = set(joints)

    def joint_parent(i: int) -> int:
        k = parent[i]
        while k >= 0 and k not in members:
            k = parent[k]
        return k

    roots = [j for j in joints if joint_parent(j) < 0]
    if len(roots) != 1:
        names = [gltf.nodes[j].name or f"nodes[{j}]" for j in roots]
        raise ValueError(f"{path}: skins[0].joints: expected one root joint (got {len(roots)}: {', '.join(names[:6])})")
    cache: dict[int, np.ndarray] = {}

    def global_matrix(i: int) -> np.ndarray:
        if i not in cache:
            local = _node_matrix(path, i, gltf.nodes[i])
            cache[i] = local if parent[i] < 0 else global_matrix(parent[i]) @ local
        return cache[i]

    order, todo = [], [roots[0]]
    while todo:  # depth first, children in file order
        i = todo.pop()
        if i in members:
            order.append(i)
        todo.extend(reversed(gltf.nodes[i].children or []))
    index = {node: k for k, node in enumerate(order)}
    names, seen = [], {}
    for node in order:
        name = gltf.nodes[node].name or f"joint{len(names)}"
        if name in seen:
            raise ValueError(f"{path}: nodes[{node}].name: {name!r} repeats nodes[{seen[name]}]'s")
        seen[name] = node
        names.append(name)
    parents = [index[joint_parent(node)] if joint_parent(node) >= 0 else -1 for node in order]
    rest = np.array([global_matrix(node)[:3, 3] for node in order])
    offsets = np.array([rest[k] - (rest[p] if p >= 0 else 0.0) for k, p in enumerate(parents)])
    has_child = set(parents)
    kinds = ["ball" if k in has_child else "fixed" for k in range(len(order))]
    return make_tree(names, parents, offsets, kinds, [()] * len(order), effectors, Path(path).stem, path)


# ------------------------------------------------------------------------------------------------
# writing


class _Blob:
    """The binary buffer of a .glb and its accessors."""

    def __init__(self, gltf):
        self.gltf, self.data = gltf, bytearray()

    def add(self, array: np.ndarray, kind: str, target=None, minmax: bool = False) -> int:
        import pygltflib as g

        array = np.ascontiguousarray(array)
        component = {np.dtype(np.float32): g.FLOAT, np.dtype(np.uint16): g.UNSIGNED_SHORT,
                     np.dtype(np.uint32): g.UNSIGNED_INT}[array.dtype]
        self.data += b"\0" * (-len(self.data) % 4)
        view = g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=array.nbytes, target=target)
        self.data += array.tobytes()
        self.gltf.bufferViews.append(view)
        count = array.shape[0]
        flat = array.reshape(count, -1)
        accessor = g.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=component, count=count,
                              type=kind, min=flat.min(0).tolist() if minmax else None,
                              max=flat.max(0).tolist() if minmax else None)
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1


def animated_glb(rig: Rig, root, yaw, angles, fps: float, names) -> bytes:
    """A binary glTF of n bodies: root (F, n, 3) world positions of their root joints (metres), yaw
    (F, n) radians about +y, angles (F, n, DOF) radians, at fps frames per second; names (n,) prefix
    each body's node names ("<name>_<joint>") and name its mesh."""
    import pygltflib as g

    root = np.asarray(root, np.float64)
    yaw = np.asarray(yaw, np.float64)
    angles = np.asarray(angles, np.float64)
    F, n = yaw.shape
    if root.shape != (F, n, 3) or angles.shape != (F, n, rig.n_dof) or len(names) != n or F < 1:
        raise ValueError(f"glb: expected per frame and body a root, a yaw and {rig.n_dof} angles "
                         f"(got {root.shape}, {yaw.shape}, {angles.shape} for {len(names)} names)")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"glb: fps must be positive (got {fps!r})")
    gltf = g.GLTF2(asset=g.Asset(generator="crowd_ik", version="2.0"), scene=0, scenes=[g.Scene(nodes=[])])
    gltf.materials.append(g.Material(name="body", pbrMetallicRoughness=g.PbrMetallicRoughness(
        baseColorFactor=list(BODY_COLOR), metallicFactor=0.0, roughnessFactor=0.8)))
    blob = _Blob(gltf)
    J = rig.n_joints
    parent = rig.arrays["parent"]
    offsets = np.array([j.offset for j in rig.joints])
    rest = np.zeros((J, 3))
    for j in range(J):
        rest[j] = offsets[j] + (rest[parent[j]] if j else 0.0)
    bones = np.arange(1, J)
    verts, faces = capsule_vertices(rest[parent[bones]], rest[bones], rig.arrays["radius"][bones])
    V = verts.shape[1]
    seg_a, seg_b = rest[parent[bones]][:, None], rest[bones][:, None]
    along = np.clip(np.einsum("mvk,mvk->mv", verts - seg_a, seg_b - seg_a)
                    / np.maximum(np.einsum("mvk,mvk->mv", seg_b - seg_a, seg_b - seg_a), 1e-18), 0, 1)
    normals = verts - (seg_a + along[..., None] * (seg_b - seg_a))
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    tri = (faces[None] + (np.arange(len(bones)) * V)[:, None, None]).reshape(-1, 3).astype(np.uint32)
    mesh_attrs = dict(
        POSITION=blob.add(verts.reshape(-1, 3).astype(np.float32), g.VEC3, g.ARRAY_BUFFER, minmax=True),
        NORMAL=blob.add(normals.reshape(-1, 3).astype(np.float32), g.VEC3, g.ARRAY_BUFFER),
        JOINTS_0=blob.add(np.repeat(np.stack([parent[bones], 0 * bones, 0 * bones, 0 * bones], 1), V, 0)
                          .astype(np.uint16), g.VEC4, g.ARRAY_BUFFER),
        WEIGHTS_0=blob.add(np.tile(np.array([1, 0, 0, 0], np.float32), (len(bones) * V, 1)), g.VEC4, g.ARRAY_BUFFER),
    )
    indices = blob.add(tri.reshape(-1), g.SCALAR, g.ELEMENT_ARRAY_BUFFER)
    ibm = np.tile(np.eye(4, dtype=np.float32), (J, 1, 1))
    ibm[:, 3, :3] = -rest  # column-major storage of a translation by -rest
    ibm_accessor = blob.add(ibm.reshape(J, 16), g.MAT4)
    times = blob.add((np.arange(F) / float(fps)).astype(np.float32), g.SCALAR, minmax=True)
    local = joint_matrices(rig, angles.reshape(F * n, -1)).reshape(F, n, J, 3, 3)
    local[:, :, 0] = yaw_matrix(yaw) @ local[:, :, 0]
    quats = matrix_to_quat(local)  # (F, n, J, 4)
    animation = g.Animation(name="motion", samplers=[], channels=[])
    moving = [j for j in range(J) if j == 0 or rig.joints[j].dof > 0]
    for b, name in enumerate(names):
        first = len(gltf.nodes)
        for j, joint in enumerate(rig.joints):
            kids = [first + int(k) for k in rig.children[j]]
            gltf.nodes.append(g.Node(name=f"{name}_{joint.name}", translation=offsets[j].tolist(),
                                     children=kids or None))
        q = _continuous(quats[:, b])
        for j in moving:
            samplers = [("rotation", blob.add(q[:, j].astype(np.float32), g.VEC4))]
            if j == 0:
                samplers.append(("translation", blob.add(root[:, b].astype(np.float32), g.VEC3)))
            for path, output in samplers:
                animation.samplers.append(g.AnimationSampler(input=times, output=output, interpolation="LINEAR"))
                animation.channels.append(g.AnimationChannel(
                    sampler=len(animation.samplers) - 1, target=g.AnimationChannelTarget(node=first + j, path=path)))
        gltf.skins.append(g.Skin(name=name, joints=list(range(first, first + J)), skeleton=first,
                                 inverseBindMatrices=ibm_accessor))
        gltf.meshes.append(g.Mesh(name=name, primitives=[g.Primitive(attributes=g.Attributes(**mesh_attrs),
                                                                     indices=indices, material=0)]))
        gltf.nodes.append(g.Node(name=f"{name}_mesh", mesh=len(gltf.meshes) - 1, skin=len(gltf.skins) - 1))
        gltf.scenes[0].nodes += [first, len(gltf.nodes) - 1]
    gltf.animations.append(animation)
    gltf.buffers.append(g.Buffer(byteLength=len(blob.data)))
    gltf.set_binary_blob(bytes(blob.data))
    return b"".join(gltf.save_to_bytes())


def _continuous(q: np.ndarray) -> np.ndarray:
    """(F, J, 4) quaternions with each frame's sign chosen nearest the previous frame's (q and -q are one
    rotation; LINEAR interpolation between opposite signs would swing the long way round)."""
    q = q.copy()
    for f in range(1, len(q)):
        flip = np.sum(q[f] * q[f - 1], axis=-1) < 0
        q[f, flip] *= -1.0
    return q


def write_animated_glb(path, rig: Rig, root, yaw, angles, fps: float, names, force: bool = False) -> Path:
    """animated_glb written to path (.glb) atomically, never clobbering without force."""
    from crowd_ik.io.output import write_bytes

    if Path(path).suffix.lower() != ".glb":
        raise ValueError(f"{path}: an animated glTF is written as a .glb file")
    return write_bytes(path, animated_glb(rig, root, yaw, angles, fps, names), force=force)


__all__ = ["read_gltf_tree", "animated_glb", "write_animated_glb", "capsule_vertices", "TEMPLATE_COUNT"]
