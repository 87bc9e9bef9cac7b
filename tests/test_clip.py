"""Motion clips (.npz) and BVH export: Euler conversions, the clip's FK round trip, and a BVH
re-read by a small parser here whose FK must reproduce the World's joint positions."""

import math

import numpy as np
import pytest

from crowd_ik.commands.cli import main
from crowd_ik.io.clip import (bvh_from_clip, bvh_text, clip_joint_positions, euler_to_matrix, load_clip,
                           matrix_to_euler, quat_to_matrix, record_clip)
from crowd_ik.geometry.quat import euler_xyz_to_quat
from crowd_ik.rig import Rig

TINY = """
seed = 3
characters = { count = 3, spacing = 1.5, rig = "%s" }
shooters = { count = 2, fire_rate = 5.0, radius = 6.0 }
bullets = { pool_size = 256 }
time = { floor = 0.6 }
camera = { position = [0, 4, 9], look_at = [0, 1, 0], fov_deg = 50 }
video = { width = 96, height = 64, fps = 24, frames = 14 }
"""


def _scene_file(folder, rig="humanoid"):
    path = folder / f"tiny_{rig}.toml"
    path.write_text(TINY % rig)
    return path


def _reference_joints(path, frames):
    """Per video frame (as `play` renders them): characters (F, N, J, 3), shooters, player."""
    from crowd_ik.game.world import World
    from crowd_ik.scene import load_scene

    world = World(load_scene(path))
    out = {"characters": [], "shooters": [], "player": []}
    for k in range(frames):
        if k:
            world.step()
        out["characters"].append(world.joints())
        out["shooters"].append(world.shooters.joints)
        out["player"].append(world.player.crowd.joint_positions())
    return {k: np.array(v) for k, v in out.items()}


@pytest.fixture(scope="module")
def humanoid_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clip")
    scene = _scene_file(folder)
    clip = folder / "run.npz"
    assert main(["play", str(scene), "-o", str(folder / "run.mp4"), "--clip", str(clip)]) == 0
    return {"folder": folder, "scene": scene, "clip": clip, "ref": _reference_joints(scene, 14)}


# ---------------------------------------------------------------------------------------------
# Euler angles


@pytest.mark.parametrize("order", ["XYZ", "YXZ", "ZXY", "ZYX", "XZY", "YZX"])
def test_matrix_to_euler_round_trips_including_gimbal_lock(order):
    rng = np.random.default_rng(7)
    a = rng.uniform(-math.pi, math.pi, size=(400, 3))
    a[:, 1] = rng.uniform(-math.pi / 2, math.pi / 2, size=400)
    a[:20, 1] = math.pi / 2  # locked
    a[20:40, 1] = -math.pi / 2
    a[40:60, 1] = math.pi / 2 - 1e-7  # nearly locked
    R = euler_to_matrix(a, order)
    back = matrix_to_euler(R, order)
    np.testing.assert_allclose(euler_to_matrix(back, order), R, atol=1e-9)
    free = np.abs(np.abs(a[:, 1]) - math.pi / 2) > 1e-3
    np.testing.assert_allclose(back[free], a[free], atol=1e-9)  # unique away from the lock


def test_euler_xyz_matrix_is_the_rigs_ball_joint_rotation():
    rng = np.random.default_rng(3)
    a = rng.uniform(-1.5, 1.5, size=(50, 3))
    np.testing.assert_allclose(euler_to_matrix(a, "XYZ"), quat_to_matrix(euler_xyz_to_quat(a)), atol=1e-12)


# ---------------------------------------------------------------------------------------------
# the .npz clip


def test_clip_holds_every_frame_and_its_angles_reproduce_its_joints(humanoid_run):
    clip = load_clip(humanoid_run["clip"])
    ref = humanoid_run["ref"]
    rig = Rig.humanoid()
    assert list(clip["groups"]) == ["characters", "shooters", "player"]
    assert float(clip["fps"]) == 24.0 and list(clip["frame"]) == list(range(14))
    assert list(clip["characters_joint_names"]) == rig.joint_names
    assert list(clip["characters_kinds"]) == [j.kind for j in rig.joints]
    np.testing.assert_allclose(clip["characters_offsets"], [j.offset for j in rig.joints], atol=1e-7)
    assert clip["characters_angles"].shape == (14, 3, rig.n_dof)
    for group in ("characters", "shooters", "player"):
        np.testing.assert_allclose(clip[f"{group}_joints"], ref[group], atol=1e-6)  # what the World had
        np.testing.assert_allclose(clip_joint_positions(clip, group), clip[f"{group}_joints"], atol=1e-4)
        np.testing.assert_allclose(clip[f"{group}_root"], clip[f"{group}_joints"][:, :, 0], atol=0)
    # the player walks: its roots move; time passes
    assert np.linalg.norm(clip["player_root"][-1, 0] - clip["player_root"][0, 0]) > 0.2
    assert np.all(np.diff(clip["world_time"]) >= 0) and clip["world_time"][-1] > 0


def test_a_downed_shooter_is_recorded_as_not_alive():
    from crowd_ik.io.clip import ClipRecorder
    from crowd_ik.game.world import World
    from crowd_ik.scene import load_scene, scene_with

    scene = scene_with(load_scene(None), size=(96, 64), **{
        "characters.count": 1, "shooters.count": 2, "shooters.placement": "line", "shooters.radius": 6.0,
        "bullets.pool_size": 64, "time.floor": 1.0, "player.path": [[0.0, -3.0]]})
    world = World(scene, autofire=False)
    rec = ClipRecorder(world, 2)
    rec.add(world)
    chest = world.shooters.joints[1, world.hbody.chest]
    world.set_player_input((0.0, 0.0), chest, fire=True)
    world.simulate(0.3)
    rec.add(world)
    alive = rec.arrays()["shooters_alive"]
    assert alive.tolist() == [[True, True], [True, False]]


def test_existing_clip_is_refused_before_simulating(tmp_path, capsys):
    scene = _scene_file(tmp_path)
    clip, video = tmp_path / "c.npz", tmp_path / "v.mp4"
    clip.write_bytes(b"keep")
    assert main(["play", str(scene), "-o", str(video), "--clip", str(clip), "--frames", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "c.npz exists" in err[0]
    assert clip.read_bytes() == b"keep" and not video.exists()


@pytest.mark.parametrize("argv,message", [
    (["--clip", "c.txt"], ".npz"),
    (["--clip", "clips/"], ".npz"),
])
def test_bad_clip_arguments_exit_2(tmp_path, monkeypatch, capsys, argv, message):
    scene = _scene_file(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert main(["play", str(scene), *argv]) == 2
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == [scene.name]


# ---------------------------------------------------------------------------------------------
# BVH, read back by a parser written for this test


def parse_bvh(text: str) -> dict:
    """joints: [{name, parent, offset, channels, end}] in file order (an End Site is named
    '<parent>/End'); frames, frame_time, motion (frames, channels)."""
    tokens = text.split()
    joints, stack, pending = [], [], None
    i = 0
    assert tokens[0] == "HIERARCHY"
    i = 1
    while tokens[i] != "MOTION":
        t = tokens[i]
        if t in ("ROOT", "JOINT"):
            pending = {"name": tokens[i + 1], "parent": stack[-1] if stack else -1, "channels": [], "end": False}
            joints.append(pending)
            i += 2
        elif t == "End":
            assert tokens[i + 1] == "Site"
            parent = stack[-1]
            pending = {"name": joints[parent]["name"] + "/End", "parent": parent, "channels": [], "end": True}
            joints.append(pending)
            i += 2
        elif t == "{":
            stack.append(joints.index(pending))
            i += 1
        elif t == "}":
            stack.pop()
            i += 1
        elif t == "OFFSET":
            pending["offset"] = np.array([float(v) for v in tokens[i + 1 : i + 4]])
            i += 4
        elif t == "CHANNELS":
            n = int(tokens[i + 1])
            pending["channels"] = tokens[i + 2 : i + 2 + n]
            i += 2 + n
        else:
            raise AssertionError(f"unexpected token {t!r}")
    assert not stack
    assert tokens[i + 1] == "Frames:" and tokens[i + 3 : i + 5] == ["Frame", "Time:"]
    frames, frame_time = int(tokens[i + 2]), float(tokens[i + 5])
    values = np.array([float(v) for v in tokens[i + 6 :]])
    n_channels = sum(len(j["channels"]) for j in joints)
    return {"joints": joints, "frames": frames, "frame_time": frame_time,
            "motion": values.reshape(frames, n_channels)}


def _rot(axis: str, deg: np.ndarray) -> np.ndarray:
    r = np.radians(deg)
    c, s = np.cos(r), np.sin(r)
    m = np.zeros(r.shape + (3, 3))
    a = "XYZ".index(axis)
    b, d = [k for k in range(3) if k != a]
    m[..., a, a] = 1.0
    m[..., b, b], m[..., b, d], m[..., d, b], m[..., d, d] = c, -s, s, c
    if axis == "Y":  # R_y: z -> x is positive
        m[..., b, d], m[..., d, b] = s, -s
    return m


def bvh_fk(bvh: dict) -> np.ndarray:
    """(frames, joints incl. End Sites, 3) world positions: each joint's channels applied in their
    listed order (intrinsic), positions added to the offset."""
    F = bvh["frames"]
    pos, rot, col = [], [], 0
    for j in bvh["joints"]:
        t = np.broadcast_to(j["offset"], (F, 3)).copy()
        R = np.broadcast_to(np.eye(3), (F, 3, 3)).copy()
        for ch in j["channels"]:
            v = bvh["motion"][:, col]
            col += 1
            if ch.endswith("position"):
                t[:, "XYZ".index(ch[0])] += v
            else:
                R = R @ _rot(ch[0], v)
        if j["parent"] < 0:
            pos.append(t)
            rot.append(R)
        else:
            p = j["parent"]
            pos.append(pos[p] + np.einsum("fij,fj->fi", rot[p], t))
            rot.append(rot[p] @ R)
    return np.stack(pos, axis=1)


def _rig_order(rig: Rig, bvh: dict) -> list[int]:
    """Rig joint index of each parsed BVH entry (an End Site is its parent's only child)."""
    out = []
    for j in bvh["joints"]:
        if j["end"]:
            parent = rig.joint_names.index(j["name"][: -len("/End")])
            (child,) = rig.children[parent]
            out.append(child)
        else:
            out.append(rig.joint_names.index(j["name"]))
    return out


def test_bvh_round_trip_reproduces_the_worlds_joint_positions(humanoid_run, capsys):
    folder, ref = humanoid_run["folder"], humanoid_run["ref"]
    out = folder / "walk.bvh"
    assert main(["export", str(humanoid_run["scene"]), "--bvh", str(out), "--character", "1"]) == 0
    assert "14 frames" in capsys.readouterr().out
    bvh = parse_bvh(out.read_text())
    rig = Rig.humanoid()
    assert len(bvh["joints"]) == rig.n_joints == 21
    assert sum(j["end"] for j in bvh["joints"]) == 5  # head, hands, toes
    assert bvh["frames"] == 14 and bvh["frame_time"] == pytest.approx(1 / 24, abs=1e-8)
    assert bvh["joints"][0]["channels"][:3] == ["Xposition", "Yposition", "Zposition"]
    order = _rig_order(rig, bvh)
    assert sorted(order) == list(range(21))
    got = bvh_fk(bvh)
    want = ref["characters"][:, 1][:, order]
    assert np.abs(got - want).max() < 1e-4
    # a ball joint's channels are its clip angles in degrees (intrinsic XYZ in both)
    clip = load_clip(humanoid_run["clip"])
    col = sum(len(j["channels"]) for j in bvh["joints"][: [j["name"] for j in bvh["joints"]].index("spine")])
    s = rig.dof_start[rig.joint_names.index("spine")]
    np.testing.assert_allclose(bvh["motion"][:, col : col + 3], np.degrees(clip["characters_angles"][:, 1, s : s + 3]),
                               atol=2e-3)
    # and the root turns with the yaw: a character's heading is in the root's Y rotation
    assert abs(bvh["motion"][0, 3] - np.degrees(clip["characters_yaw"][0, 1])) < 5.0


def test_bvh_from_the_clip_equals_the_bvh_from_the_scene(humanoid_run, capsys):
    folder = humanoid_run["folder"]
    a, b = folder / "a.bvh", folder / "b.bvh"
    assert main(["export", str(humanoid_run["scene"]), "--bvh", str(a), "--character", "2", "--frames", "9"]) == 0
    assert main(["export", str(humanoid_run["clip"]), "--bvh", str(b), "--character", "2", "--frames", "9"]) == 0
    assert a.read_text() == b.read_text()
    assert "9 frames" in capsys.readouterr().out


def test_bvh_of_a_chain_character_round_trips(tmp_path):
    from crowd_ik.scene import load_scene

    path = _scene_file(tmp_path, "chain")
    clip = record_clip(load_scene(path), frames=6)
    ref = _reference_joints(path, 6)["characters"]
    for k in range(3):
        rig, text = bvh_from_clip(clip, k)
        bvh = parse_bvh(text)
        assert len(bvh["joints"]) == rig.n_joints == 9 and bvh["frames"] == 6
        got = bvh_fk(bvh)[:, np.argsort(_rig_order(rig, bvh))]
        assert np.abs(got - ref[:, k]).max() < 1e-4


def test_bvh_text_of_a_turned_posed_rig_matches_reference_fk():
    """Independent of the World: random poses of a rig with every joint kind (a fixed joint in the
    middle included), any yaw, through bvh_text and back."""
    from crowd_ik.geometry import fk as ref_fk
    from crowd_ik.rig import Joint

    rig = Rig((
        Joint("root", -1, (0.1, 0.9, 0.0)),
        Joint("a", 0, (0.0, 0.3, 0.0), "hinge", ((0.0, 0.6, 0.8),)),
        Joint("mid", 1, (0.0, 0.2, 0.1), "fixed"),
        Joint("b", 2, (0.2, 0.0, 0.0), "universal", ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0))),
        Joint("tip", 3, (0.0, 0.0, 0.25), "fixed"),
        Joint("c", 0, (-0.2, -0.1, 0.0)),
    ))
    rng = np.random.default_rng(11)
    F = 20
    angles = rng.uniform(-2.0, 2.0, size=(F, rig.n_dof))
    yaw = rng.uniform(-3.1, 3.1, size=F)
    base = rng.normal(size=(F, 3))
    pos, _ = ref_fk.forward_kinematics(rig, base, yaw, ref_fk.angles_to_rotations(rig, angles))
    bvh = parse_bvh(bvh_text(rig, pos[:, 0], yaw, angles, 30.0))
    names = [j["name"] for j in bvh["joints"]]
    assert names == ["root", "a", "mid", "b", "b/End", "c", "c/End"]  # a moving leaf gets a zero End Site
    assert bvh["joints"][2]["channels"] == ["Xrotation", "Yrotation", "Zrotation"]
    got = bvh_fk(bvh)
    for k, name in enumerate(names):
        j = rig.joint_names.index("tip" if name == "b/End" else name.replace("/End", ""))
        assert np.abs(got[:, k] - pos[:, j]).max() < 1e-4, name
    assert np.all(bvh["motion"][:, 9:12] == 0.0)  # the fixed joint's channels (after root 6 and a 3)


def test_existing_bvh_is_not_clobbered(tmp_path, capsys):
    scene = _scene_file(tmp_path)
    out = tmp_path / "walk.bvh"
    out.write_text("keep")
    assert main(["export", str(scene), "--bvh", str(out), "--frames", "2"]) == 2
    assert out.read_text() == "keep"
    assert "exists" in capsys.readouterr().err
    assert main(["export", str(scene), "--bvh", str(out), "--frames", "2", "--force"]) == 0
    assert parse_bvh(out.read_text())["frames"] == 2


@pytest.mark.parametrize("argv,message", [
    (["--bvh", "walk.txt"], "--bvh"),
    (["--bvh", "walk.bvh", "--character", "3"], "--character"),
    (["--bvh", "walk.bvh", "--frames", "0"], "--frames"),
    (["--bvh", "walk.bvh", "-o", "x.glb"], "-o"),
    (["--frames", "4"], "--frames"),
])
def test_bad_bvh_arguments_exit_2(tmp_path, monkeypatch, capsys, argv, message):
    scene = _scene_file(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(scene), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [scene.name]


def test_a_file_that_is_not_a_clip_is_refused(tmp_path, capsys):
    bad = tmp_path / "x.npz"
    np.savez(bad, a=np.zeros(3))
    assert main(["export", str(bad), "--bvh", str(tmp_path / "o.bvh")]) == 2
    assert "not a crowd-ik clip" in capsys.readouterr().err
