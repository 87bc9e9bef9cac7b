"""animate: a clip on a crowd with IK on top - feet planted, blend weights, offsets in time and place,
the command line (video out, no clobbering, one-line errors)."""

import re
from pathlib import Path

import numpy as np
import pytest

import crowd_ik as cik
from crowd_ik.animation import animate, contacts, parse_blend
from crowd_ik.commands.cli import main
from crowd_ik.io.bvh import load_bvh
from crowd_ik.io.clip import bvh_text
from crowd_ik.io.video import read_video
from crowd_ik.solvers.registry import DLS

WALKER = Path(__file__).parent / "data" / "walker_cm_zxy.bvh"
FPS, FRAMES = 30.0, 18
# the humanoid's End Sites come back as <parent>_end; its ankles are the feet
EFFECTORS = {"head": "neck_end", "hand_l": "wrist_l_end", "hand_r": "wrist_r_end", "foot_l": "ankle_l",
             "foot_r": "ankle_r"}


@pytest.fixture(scope="module")
def skating(tmp_path_factory):
    """A crouching humanoid whose pelvis glides forward at 0.1 m/s with its legs fixed: the clip's feet
    skate on the ground (slower than the contact speed), and its arms swing."""
    rig = cik.Rig.humanoid()
    names = rig.joint_names
    angles = np.zeros((FRAMES, rig.n_dof))
    s = rig.dof_start
    for side in "lr":
        angles[:, s[names.index(f"hip_{side}")]] = -0.35  # thigh forward
        angles[:, s[names.index(f"knee_{side}")]] = 0.7  # shin back under the hip
        angles[:, s[names.index(f"ankle_{side}")]] = -0.35
    angles[:, s[names.index("shoulder_l")]] = np.linspace(-0.3, 0.3, FRAMES)
    t = np.arange(FRAMES) / FPS
    root = np.stack([0.1 * t, np.full(FRAMES, 0.90), np.zeros(FRAMES)], 1)
    path = tmp_path_factory.mktemp("animate") / "skate.bvh"
    path.write_text(bvh_text(rig, root, np.zeros(FRAMES), angles, FPS))
    return path, load_bvh(path, effectors=EFFECTORS)


def test_contact_needs_the_lowest_height_and_a_slow_foot():
    p = np.zeros((5, 2, 3))
    p[:, 1, 1] = [0.0, 0.001, 0.1, 0.001, 0.0]  # the second lifts fast in the middle
    p[:, 0, 0] = [0.0, 0.001, 0.002, 0.1, 0.2]  # the first slides fast at the end
    c = contacts(p, fps=30.0)
    assert c[:, 1].tolist() == [True, False, False, False, True]
    assert c[:2, 0].all() and not c[2:, 0].any()


def test_planted_feet_stop_sliding_and_the_rest_follows_the_clip(skating):
    _, (rig, motion) = skating
    result = animate((rig, motion), count=2, spacing=2.0)
    feet = [rig.effector_names.index("foot_l"), rig.effector_names.index("foot_r")]
    assert result.planted[:, :, feet].all()  # the feet stay low and slow: in contact all along
    assert result.slide_clip == pytest.approx(0.1, rel=0.05)
    assert result.slide < 0.01  # planted by IK: a tenth of the clip's slide at most
    eff = rig.arrays["eff_joint"]
    clip = motion.joint_positions()[:, eff]
    base, _ = motion.roots()
    for c, spot in enumerate(cik.Crowd(rig, n=2, spacing=2.0).roots()[0]):
        place = spot - np.array([base[0, 0], 0.0, base[0, 2]])
        got = result.joints[:, c][:, eff]
        head_hands = [0, 1, 2]
        np.testing.assert_allclose(got[:, head_hands], clip[:, head_hands] + place, atol=2e-3)  # blend 0: the clip
        first = clip[0, feet] + place
        np.testing.assert_allclose(got[:, feet, 0], np.broadcast_to(first[:, 0], (FRAMES, 2)), atol=3e-3)
        np.testing.assert_allclose(got[:, feet, 2], np.broadcast_to(first[:, 2], (FRAMES, 2)), atol=3e-3)


def test_blend_zero_plays_the_clip_unchanged_with_offsets_in_time_and_place(skating):
    _, (rig, motion) = skating
    result = animate((rig, motion), count=3, spacing=1.0, stagger=2 / FPS, blend={"foot_l": 0, "foot_r": 0},
                     frames=FRAMES + 4)
    k = np.arange(FRAMES + 4)[:, None]
    assert np.array_equal(result.clip_frame, (k - 2 * np.arange(3)[None]) % FRAMES)
    clip = motion.joint_positions()
    base, _ = motion.roots()
    spots = cik.Crowd(rig, n=3, spacing=1.0).roots()[0]
    for c in range(3):
        place = spots[c] - np.array([base[0, 0], 0.0, base[0, 2]])
        np.testing.assert_allclose(result.joints[:, c], clip[result.clip_frame[:, c]] + place, atol=1e-4)
    assert result.slide == pytest.approx(result.slide_clip, rel=1e-3)  # nothing corrected


def test_blend_and_target_arguments_are_checked(skating):
    _, pair = skating
    assert parse_blend("foot_l=1, hand_l=0.5") == {"foot_l": 1.0, "hand_l": 0.5}
    for text, message in (("foot_l", "EFFECTOR=WEIGHT"), ("foot_l=2", "a weight in [0, 1]"), ("", "expected")):
        with pytest.raises(ValueError, match=re.escape(message)):
            parse_blend(text)
    with pytest.raises(ValueError, match="blend: no effector 'tail'"):
        animate(pair, blend={"tail": 1})
    with pytest.raises(ValueError, match="count: expected an integer"):
        animate(pair, count=0)
    def up(k, clip):  # a target callable: the left hand reaches 10 cm up, blended halfway
        out = np.full(clip.shape, np.nan)
        out[:, 1] = clip[:, 1] + [0.0, 0.1, 0.0]
        return out

    result = animate(pair, blend={"hand_l": 0.5}, targets=up, frames=3, method=DLS)  # FABRIK stalls 1.4 cm off here
    rig, motion = pair
    got = result.joints[:, 0, rig.arrays["eff_joint"][1], 1]
    clip = motion.joint_positions()[:3, rig.arrays["eff_joint"][1], 1]
    np.testing.assert_allclose(got - clip, 0.05, atol=2e-3)


def test_the_command_renders_a_video_and_never_clobbers(tmp_path, capsys):
    out = tmp_path / "walk.mp4"
    argv = ["animate", str(WALKER), "-o", str(out), "--count", "2", "--size", "96x64", "--stagger", "0.04",
            "--blend", "foot_l=1,foot_r=1,hand_l=0.5", "--solver", "dls"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "2, 1.5 m apart" in text and "units cm" in text and "solver dls" in text
    assert read_video(out) == (4, 64, 96)  # frames, height, width
    before = out.read_bytes()
    assert main(argv) == 2
    assert "--force" in capsys.readouterr().err and out.read_bytes() == before
    assert main(argv + ["--force"]) == 0


@pytest.mark.parametrize("extra,message", [
    (["--blend", "foot_x=1"], "--blend: no effector 'foot_x'"),
    (["--blend", "foot_l=-1"], "--blend: foot_l: a weight in [0, 1]"),
    (["--count", "0"], "--count: must be a positive integer"),
    (["--size", "95x64"], "95x64"),
    (["-o", "x.png"], "unknown video suffix"),
])
def test_bad_arguments_exit_2_with_one_line(tmp_path, capsys, monkeypatch, extra, message):
    monkeypatch.chdir(tmp_path)
    assert main(["animate", str(WALKER), "--size", "96x64", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not list(tmp_path.iterdir())
