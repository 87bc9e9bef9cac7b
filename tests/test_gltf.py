"""glTF: Rig.from_gltf on files made here with pygltflib, the animated .glb of `export --animated` read back
with pygltflib (its joint nodes' world positions against the world's FK), and refused files."""

import struct

import numpy as np
import pygltflib as g
import pytest
from scipy.spatial.transform import Rotation

import crowd_ik as cik
from crowd_ik.commands.cli import main
from crowd_ik.io.clip import record_clip
from crowd_ik.scene import load_scene

TINY = """
seed = 5
characters = { count = 2 }
shooters = { count = 1, fire_rate = 6.0 }
bullets = { pool_size = 64 }
time = { floor = 1.0 }
video = { width = 96, height = 64, frames = 5 }
"""


def node_matrix(node) -> np.ndarray:
    m = np.eye(4)
    if node.matrix is not None:
        return np.asarray(node.matrix, float).reshape(4, 4).T
    if node.rotation is not None:
        m[:3, :3] = Rotation.from_quat(node.rotation).as_matrix()
    if node.scale is not None:
        m[:3, :3] = m[:3, :3] * np.asarray(node.scale)[None, :]
    if node.translation is not None:
        m[:3, 3] = node.translation
    return m


def world_positions(gltf, local: dict | None = None) -> dict[int, np.ndarray]:
    """Every node's world position, with local: {node: 4x4} overriding the nodes' own transforms."""
    local = local or {}
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}
    out = {}

    def glob(i):
        m = local.get(i, node_matrix(gltf.nodes[i]))
        return m if i not in parent else glob(parent[i]) @ m

    for i in range(len(gltf.nodes)):
        out[i] = glob(i)[:3, 3]
    return out


def accessor(gltf, index: int) -> np.ndarray:
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc.type]
    dtype = {g.FLOAT: np.float32, g.UNSIGNED_SHORT: np.uint16, g.UNSIGNED_INT: np.uint32}[acc.componentType]
    data = gltf.binary_blob()[view.byteOffset + (acc.byteOffset or 0):][: acc.count * width * np.dtype(dtype).itemsize]
    return np.frombuffer(data, dtype).reshape(acc.count, width)


def skinned_file(path, scale=(0.01, 0.01, 0.01), skins=1, cycle=False, nan=False):
    """An Armature node (turned 90 degrees about x, scaled to centimetres as Blender writes it) over a
    hips -> spine -> head chain and a left and right leg; joint nodes with their own rotations."""
    q = Rotation.from_euler("x", -90, degrees=True).as_quat().tolist()
    nodes = [
        g.Node(name="Armature", rotation=q, scale=list(scale), children=[1]),
        g.Node(name="Hips", translation=[0, 0, 95.0], rotation=[0, 0, 0.0871557, 0.9961947], children=[2, 4, 6]),
        g.Node(name="Spine", translation=[0, 0, 20.0], rotation=Rotation.from_euler("y", 20, degrees=True)
               .as_quat().tolist(), children=[3]),
        g.Node(name="Head", translation=[0, 0, 50.0]),
        g.Node(name="LeftUpLeg", translation=[10.0, 0, -5.0], children=[5]),
        g.Node(name="LeftFoot", translation=[0, 0, -85.0]),
        g.Node(name="RightUpLeg", translation=[-10.0, 0, -5.0], children=[7]),
        g.Node(name="RightFoot", translation=[0, 2.0, -85.0]),
    ]
    if nan:
        nodes[5].translation = [0, 12345.678, -85.0]  # made NaN in the text below (pygltflib writes no NaN)
    if cycle:
        nodes[3].children = [1]
    gltf = g.GLTF2(scene=0, scenes=[g.Scene(nodes=[0])], nodes=nodes,
                   skins=[g.Skin(joints=list(range(1, 8))) for _ in range(skins)])
    gltf.save(str(path))
    if nan:
        path.write_text(path.read_text().replace("12345.678", "NaN"))
    return gltf


def test_from_gltf_keeps_the_files_rest_pose_in_metres_y_up(tmp_path):
    path = tmp_path / "walker.gltf"
    gltf = skinned_file(path)
    rig = cik.Rig.from_gltf(path)
    assert rig.joint_names == ["Hips", "Spine", "Head", "LeftUpLeg", "LeftFoot", "RightUpLeg", "RightFoot"]
    assert [j.parent for j in rig.joints] == [-1, 0, 1, 0, 3, 0, 5]
    assert [j.kind for j in rig.joints] == ["ball", "ball", "fixed", "ball", "fixed", "ball", "fixed"]
    assert rig.effector_names == ["Head", "LeftFoot", "RightFoot"]  # no hands: one per leaf joint
    want = world_positions(gltf)
    crowd = cik.Crowd(rig, n=1)
    got = crowd.joint_positions()[0]  # zero angles: the rest pose
    np.testing.assert_allclose(got, [want[i] for i in range(1, 8)], atol=1e-5)
    assert got[2, 1] == pytest.approx(1.65, abs=0.05)  # the head about 1.6 m up: y up, metres
    rig = cik.Rig.from_gltf(path, effectors={"foot_l": "LeftFoot", "foot_r": "RightFoot"})
    assert rig.effector_names == ["foot_l", "foot_r"]


@pytest.mark.parametrize("kind,message", [
    ("two skins", "skins: expected one skin (got 2)"),
    ("no skin", "skins: expected one skin (got 0)"),
    ("non-uniform", "nodes[0].scale: non-uniform scale or shear"),
    ("cycle", "nodes[3].children: a cycle"),
    ("nan", "nodes[5].translation: expected 3 finite numbers"),
])
def test_bad_gltf_files_are_refused_naming_the_file_and_field(tmp_path, kind, message):
    path = tmp_path / "bad.gltf"
    skinned_file(path, scale=(0.01, 0.02, 0.01) if kind == "non-uniform" else (0.01,) * 3,
                 skins={"two skins": 2, "no skin": 0}.get(kind, 1), cycle=kind == "cycle", nan=kind == "nan")
    with pytest.raises(ValueError) as err:
        cik.Rig.from_gltf(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value), str(err.value)


def test_a_truncated_glb_is_refused(tmp_path):
    rig = cik.Rig.humanoid()
    from crowd_ik.io.gltf import animated_glb

    data = animated_glb(rig, np.zeros((2, 1, 3)), np.zeros((2, 1)), np.zeros((2, 1, rig.n_dof)), 30, ["a"])
    path = tmp_path / "cut.glb"
    path.write_bytes(data[: len(data) // 3])
    with pytest.raises(ValueError, match=f"{path}: not a readable glTF"):
        cik.Rig.from_gltf(path)
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 12))
    with pytest.raises(ValueError, match=f"{path}: "):
        cik.Rig.from_gltf(path)


def test_animated_glb_reads_back_as_the_worlds_motion(tmp_path, capsys):
    scene = tmp_path / "tiny.toml"
    scene.write_text(TINY)
    out = tmp_path / "motion.glb"
    assert main(["export", str(scene), "--animated", "-o", str(out)]) == 0
    assert "2 characters" in capsys.readouterr().out
    assert main(["export", str(scene), "--animated", "-o", str(out)]) == 2  # no clobbering
    clip = record_clip(load_scene(scene))
    world = np.asarray(clip["characters_joints"], np.float64)  # (F, n, J, 3)
    gltf = g.GLTF2().load(str(out))
    assert len(gltf.skins) == 2 and len(gltf.meshes) == 2 and len(gltf.animations) == 1
    names = [n.name for n in gltf.nodes]
    J = world.shape[2]
    animation = gltf.animations[0]
    times = accessor(gltf, animation.samplers[0].input)[:, 0]
    assert times.shape == (5,) and times[1] == pytest.approx(1 / 30)
    for f in range(5):
        local = {}
        for ch in animation.channels:
            value = accessor(gltf, animation.samplers[ch.sampler].output)[f]
            node = ch.target.node
            m = local.setdefault(node, node_matrix(gltf.nodes[node]))
            if ch.target.path == "rotation":
                m[:3, :3] = Rotation.from_quat(value).as_matrix()
            else:
                m[:3, 3] = value
        pos = world_positions(gltf, local)
        for k in range(2):
            first = names.index(f"character_{k}_pelvis")
            got = np.array([pos[first + j] for j in range(J)])
            np.testing.assert_allclose(got, world[f, k], atol=1e-4)
    # the skin binds each capsule vertex to one joint with weight 1, inverse bind = minus the rest position
    prim = gltf.meshes[0].primitives[0]
    assert np.all(accessor(gltf, prim.attributes.WEIGHTS_0)[:, 0] == 1.0)
    ibm = accessor(gltf, gltf.skins[0].inverseBindMatrices).reshape(J, 4, 4)
    rest = world_positions(gltf)
    np.testing.assert_allclose(-ibm[:, 3, :3], [rest[names.index("character_0_pelvis") + j] for j in range(J)],
                               atol=1e-5)
    import trimesh

    assert len(trimesh.load(out).geometry) == 2


def test_one_characters_animated_glb_gives_back_its_rig(tmp_path):
    from crowd_ik.io.gltf import write_animated_glb

    rig = cik.Rig.humanoid()
    out = tmp_path / "one.glb"
    write_animated_glb(out, rig, np.zeros((3, 1, 3)), np.zeros((3, 1)), np.zeros((3, 1, rig.n_dof)), 24, ["hero"])
    back = cik.Rig.from_gltf(out)
    assert back.joint_names == [f"hero_{n}" for n in rig.joint_names]
    np.testing.assert_allclose([j.offset for j in back.joints], [j.offset for j in rig.joints], atol=1e-9)
    assert back.effector_names == ["head", "hand_l", "hand_r", "foot_l", "foot_r"]
    with pytest.raises(FileExistsError):
        write_animated_glb(out, rig, np.zeros((3, 1, 3)), np.zeros((3, 1)), np.zeros((3, 1, rig.n_dof)), 24, ["x"])
