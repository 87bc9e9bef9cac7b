"""load_bvh: hierarchy, channel orders, units, effectors, motion -> Crowd, export round trips, bad files.

The oracle is an independent reading of the same file: the `bvh` package's parse, with scipy's
intrinsic Euler rotations, forward kinematics written out here.
"""

from pathlib import Path

import numpy as np
import pytest
from bvh import Bvh
from scipy.spatial.transform import Rotation

import crowd_ik as cik
from crowd_ik.commands.cli import main
from crowd_ik.io.bvh import load_bvh
from crowd_ik.io.clip import record_clip
from crowd_ik.scene import load_scene

DATA = Path(__file__).parent / "data"
WALKER = DATA / "walker_cm_zxy.bvh"
TINY = """
seed = 3
characters = { count = 3 }
shooters = { count = 1, fire_rate = 6.0 }
bullets = { pool_size = 64 }
time = { floor = 1.0 }
video = { width = 96, height = 64, frames = 6 }
"""


def reference_positions(text: str, root: int = 0, scale: float = 1.0) -> tuple[list[str], np.ndarray]:
    """(joint names with End Sites as <parent>_end, (F, J, 3) world positions) by the bvh package."""
    doc = Bvh(text)
    frames = np.array(doc.frames, float)
    names, out, column = [], [], 0
    roots = list(doc.root.filter("ROOT"))

    def walk(node, pos, rot, name):
        nonlocal column
        offset = np.array([float(v) for v in node["OFFSET"]])
        channels = node["CHANNELS"][1:] if node.value[0] != "End" else []
        values = frames[:, column : column + len(channels)]
        column += len(channels)
        local_offset = np.broadcast_to(offset, (len(frames), 3)).copy()
        for c, v in zip(channels, values.T):
            if c.endswith("position"):  # translation channels add to the offset, in the parent's frame
                local_offset[:, "XYZ".index(c[0])] += v
        here_pos = pos + np.einsum("fij,fj->fi", rot, local_offset)
        rot_axes = "".join(c[0] for c in channels if c.endswith("rotation"))
        rot_cols = [v for c, v in zip(channels, values.T) if c.endswith("rotation")]
        local = (Rotation.from_euler(rot_axes.upper(), np.stack(rot_cols, 1), degrees=True).as_matrix()
                 if rot_axes else np.broadcast_to(np.eye(3), rot.shape))
        here_rot = rot @ local
        if record:
            names.append(name)
            out.append(here_pos)
        for child in node:
            if child.value[0] == "JOINT":
                walk(child, here_pos, here_rot, child.value[1])
            elif child.value[0] == "End":
                walk(child, here_pos, here_rot, f"{name}_end")

    F = len(frames)
    for k, node in enumerate(roots):
        record = k == root
        walk(node, np.zeros((F, 3)), np.broadcast_to(np.eye(3), (F, 3, 3)), node.value[1])
    return names, scale * np.stack(out, 1)


def test_a_hand_written_centimetre_zxy_file_loads_as_its_independent_reading():
    rig, motion = load_bvh(WALKER)
    names, want = reference_positions(WALKER.read_text(), scale=0.01)
    assert rig.joint_names == names
    assert rig.joint_names[:5] == ["Hips", "Spine", "Neck", "Head", "Head_end"]
    kinds = dict(zip(rig.joint_names, (j.kind for j in rig.joints)))
    assert (kinds["Hips"], kinds["LeftForeArm"], kinds["LeftHand"], kinds["LHipJoint"], kinds["Head_end"]) == \
        ("ball", "hinge", "universal", "fixed", "fixed")
    assert rig.joints[rig.joint_names.index("LeftHand")].axes == ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0))
    assert motion.units == "cm" and motion.scale == 0.01
    assert motion.n_frames == 4 and motion.frame_time == pytest.approx(0.04) and motion.fps == pytest.approx(25)
    assert rig.effector_names == ["head", "hand_l", "hand_r", "foot_l", "foot_r"]
    assert [rig.joint_names[e.joint] for e in rig.effectors] == ["Head", "LeftHand", "RightHand", "LeftFoot",
                                                                 "RightFoot"]
    got = motion.joint_positions()
    assert got.shape == (4, rig.n_joints, 3)
    np.testing.assert_allclose(got, want, atol=1e-5)  # the zero-length LHipJoint bone is 1 um long
    assert 1.7 < got[0, :, 1].max() - got[0, :, 1].min() < 1.8  # metres, y up


def test_the_crowd_reproduces_every_frame_from_the_motions_angles_and_roots():
    rig, motion = load_bvh(WALKER)
    crowd = cik.Crowd(rig, n=motion.n_frames)
    base, yaw = motion.roots()
    crowd.set_roots(base, yaw)
    crowd.set_angles(motion.angles())
    assert np.abs(crowd.joint_positions() - motion.joint_positions()).max() <= 1e-4
    assert motion.angles().shape == (motion.n_frames, rig.n_dof)


def test_units_given_or_guessed(tmp_path):
    _, metres = load_bvh(WALKER, units="m")
    _, cm = load_bvh(WALKER, units="cm")
    assert metres.scale == 1.0 and metres.units == "m"
    np.testing.assert_allclose(metres.joint_positions(), 100 * cm.joint_positions(), atol=2e-4)  # zero bones: 1 um
    small = tmp_path / "small.bvh"
    text = WALKER.read_text()
    lines = []
    for line in text.splitlines():  # the same skeleton written in metres
        words = line.split()
        if words and words[0] == "OFFSET":
            line = "OFFSET " + " ".join(f"{float(v) / 100:.4f}" for v in words[1:])
        lines.append(line)
    small.write_text("\n".join(lines) + "\n")
    _, guessed = load_bvh(small)
    assert guessed.units == "m"
    with pytest.raises(ValueError, match="units: expected"):
        load_bvh(WALKER, units="mm")


def test_effectors_given_or_one_per_end_site(tmp_path):
    rig, _ = load_bvh(WALKER, effectors=["LeftFoot", "Head_end"])
    assert rig.effector_names == ["LeftFoot", "Head_end"]
    rig, _ = load_bvh(WALKER, effectors={"foot_l": "LeftFoot"})
    assert rig.effector_names == ["foot_l"] and rig.joint_names[rig.effectors[0].joint] == "LeftFoot"
    with pytest.raises(ValueError, match=r"walker_cm_zxy.bvh: effectors: no joint named 'Tail'"):
        load_bvh(WALKER, effectors=["Tail"])
    plain = tmp_path / "plain.bvh"
    plain.write_text(WALKER.read_text().replace("Head", "Bone").replace("Hand", "Paw"))
    rig, _ = load_bvh(plain)
    assert rig.effector_names == [n for n in rig.joint_names if n.endswith("_end")]


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bvh_export")
    scene = folder / "tiny.toml"
    scene.write_text(TINY)
    return folder, scene, record_clip(load_scene(scene))


def _world_order(rig_names: list[str], prefix: str, clip) -> list[int]:
    """The world rig's joint index of each imported joint (End Sites: the parent's only child)."""
    world = [str(n) for n in clip["characters_joint_names"]]
    parents = np.asarray(clip["characters_parents"])
    out = []
    for name in rig_names:
        name = name[len(prefix):]
        if name.endswith("_end"):
            parent = world.index(name[: -len("_end")])
            out.append(int(np.flatnonzero(parents == parent)[0]))
        else:
            out.append(world.index(name))
    return out


def test_exported_bvh_of_several_characters_re_imports_to_the_worlds_joints(tiny_clip, capsys):
    folder, scene, clip = tiny_clip
    out = folder / "all.bvh"
    assert main(["export", str(scene), "--bvh", str(out), "--characters", "all"]) == 0
    assert "3 characters" in capsys.readouterr().out
    text = out.read_text()
    doc = Bvh(text)
    assert [r.value[1] for r in doc.root.filter("ROOT")] == ["c0_pelvis", "c1_pelvis", "c2_pelvis"]
    assert len(doc.frames) == 6 and len(doc.frames[0]) == 3 * (6 + 3 * 15)
    world = np.asarray(clip["characters_joints"], np.float64)  # (F, n, J, 3)
    for k in range(3):
        rig, motion = load_bvh(out, root=k)
        order = _world_order(rig.joint_names, f"c{k}_", clip)
        np.testing.assert_allclose(motion.joint_positions(), world[:, k, order], atol=1e-4)
        names, independent = reference_positions(text, root=k)
        assert names == rig.joint_names
        np.testing.assert_allclose(independent, world[:, k, order], atol=1e-4)
    with pytest.raises(ValueError, match="root: .* has 3 ROOT hierarchies"):
        load_bvh(out, root=3)


def test_exported_bvh_of_one_character_still_re_imports(tiny_clip, capsys):
    folder, scene, clip = tiny_clip
    out = folder / "one.bvh"
    assert main(["export", str(scene), "--bvh", str(out), "--character", "2"]) == 0
    rig, motion = load_bvh(out)
    assert rig.joint_names[0] == "pelvis" and motion.units == "m"
    order = _world_order(rig.joint_names, "", clip)
    np.testing.assert_allclose(motion.joint_positions(), np.asarray(clip["characters_joints"])[:, 2, order],
                               atol=1e-4)
    assert main(["export", str(scene), "--bvh", str(folder / "x.bvh"), "--character", "1",
                 "--characters", "all"]) == 2
    assert "not both" in capsys.readouterr().err


def _edit(text: str, old: str, new: str, count: int = 1) -> str:
    assert old in text, old
    return text.replace(old, new, count)


W = WALKER.read_text()
HEAD_LINES = W.splitlines()
FRAME1 = HEAD_LINES.index("MOTION") + 4  # line number of the first frame line
BAD = {
    "truncated hierarchy": ("\n".join(HEAD_LINES[:40]) + "\n", "40: truncated: the file ends before MOTION"),
    "truncated frames": ("\n".join(HEAD_LINES[:FRAME1 + 1]) + "\n", f"{FRAME1 + 1}: truncated: 2 frame lines of 'Frames: 4'"),
    "channel count": (_edit(W, "CHANNELS 1 Xrotation", "CHANNELS 2 Xrotation"), "31: CHANNELS 2 lists 1 channels"),
    "frame values": (_edit(W, "0.0 0.0 0.0\n2.00", "0.0 0.0\n2.00"), f"{FRAME1}: frame 0 has 44 values; the channels need 45"),
    "NaN offset": (_edit(W, "OFFSET 0.00 40.00 0.00", "OFFSET 0.00 nan 0.00"), "12: OFFSET: value 2 is not a finite number"),
    "NaN motion": (_edit(W, "2.00 94.50", "2.00 inf"), f"{FRAME1 + 1}: frame 1: value 2 is not a finite number"),
    "repeated name": (_edit(W, "JOINT RightArm", "JOINT LeftArm"), "43: joint name 'LeftArm' repeats line 24's"),
    "unknown channel": (_edit(W, "CHANNELS 1 Xrotation", "CHANNELS 1 Wrotation"), "31: unknown channel 'Wrotation'"),
    "missing brace": (_edit(W, "\tJOINT Spine\n\t{", "\tJOINT Spine"), "7: expected '{' after line 6"),
    "no frames": (_edit(W, "Frames: 4", "Frames: 0"), "Frames: a clip needs at least one frame"),
    "bad frame time": (_edit(W, "Frame Time: 0.04", "Frame Time: -1"), "Frame Time: expected a positive number"),
    "not bvh": ("hello\n", "1: expected HIERARCHY"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_are_refused_with_the_file_and_line(tmp_path, case):
    text, message = BAD[case]
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        load_bvh(path)
    assert str(err.value).startswith(f"{path}:") and message in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


def test_a_moving_translation_on_a_non_root_joint_is_refused(tmp_path):
    text = _edit(W, "CHANNELS 3 Zrotation Xrotation Yrotation\n\t\tJOINT Neck",
                 "CHANNELS 4 Xposition Zrotation Xrotation Yrotation\n\t\tJOINT Neck")
    lines = text.splitlines()
    start = lines.index("MOTION") + 3
    for f, line in enumerate(lines[start:]):  # insert the Spine's Xposition after the root's 6 values
        v = line.split()
        lines[start + f] = " ".join(v[:6] + [str(float(f))] + v[6:])
    path = tmp_path / "stretch.bvh"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"stretch.bvh:6: joint 'Spine': its Xposition channel moves"):
        load_bvh(path)
    for f, line in enumerate(lines[start:]):  # the same channel held constant is part of the offset
        v = line.split()
        v[6] = "5.0"
        lines[start + f] = " ".join(v)
    path.write_text("\n".join(lines) + "\n")
    rig, motion = load_bvh(path)
    assert rig.joints[1].offset == pytest.approx((0.05, 0.12, -0.015))


def test_the_command_line_reports_a_bad_clip_in_one_line(tmp_path, capsys):
    path = tmp_path / "bad.bvh"
    path.write_text(BAD["channel count"][0])
    assert main(["animate", str(path), "-o", str(tmp_path / "out.mp4")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{path}:31: CHANNELS 2 lists 1 channels" in err[0]
    assert not (tmp_path / "out.mp4").exists()
