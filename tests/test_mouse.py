"""`crowd-ik mouse`: replay of paths and keyframes to video, the lost state, CSV errors, no-clobber,
the no-display message, the humanoid drag, and the live window driven under Xvfb with xdotool.

The ease curve itself (0 at 0, 1 at 1, monotone, zero end slopes, continuous velocity at k1, k2) is
tested in tests/test_ease.py; here the keyframe replay is checked end to end.
"""

import math
import time
from pathlib import Path

import numpy as np
import pytest
from xwindow import crowd_ik_window, xdo

from crowd_ik import planar
from crowd_ik.commands.cli import main
from crowd_ik.ease import load_keyframes
from crowd_ik.mouse.paths import Recorder, load_path, path_frames
from crowd_ik.mouse.replay import replay_keyframes, replay_path
from crowd_ik.mouse.session import LOST_TOL, ChainSession, chain_limits, rest_pose
from crowd_ik.mouse.view import BONE, HumanoidSession, View, reachable_mask, sample_reachable, to_gui_image
from crowd_ik.io.video import read_frames, read_video

SCENES = Path(__file__).resolve().parents[1] / "scenes"
SIZE = ["--size", "160x160"]


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_shipped_csvs_are_packaged_copies():
    package = Path(__file__).resolve().parents[1] / "crowd_ik" / "scenes"
    names = sorted(p.name for p in SCENES.glob("*.csv"))
    assert {"circle.csv", "figure_eight.csv", "leave_reach.csv", "wave_keyframes.csv"} <= set(names)
    for name in names:
        assert (package / name).read_bytes() == (SCENES / name).read_bytes(), name


def test_replay_writes_one_frame_per_row_at_the_size(tmp_path):
    out = tmp_path / "circle.mp4"
    assert main(["mouse", "--path", str(SCENES / "circle.csv"), "-o", str(out), *SIZE]) == 0
    rows = len(load_path(SCENES / "circle.csv")[0])
    assert read_video(out) == (rows, 160, 160)


def test_replay_resamples_on_t_with_fps(tmp_path):
    csv = _write(tmp_path / "p.csv", "t,x,y\n0.0,2.0,0.0\n0.25,2.0,1.0\n1.0,0.0,2.0\n")
    out = f"{tmp_path}/frames/"
    assert main(["mouse", "--path", str(csv), "-o", str(out), "--fps", "10", *SIZE]) == 0
    assert read_video(out) == (11, 160, 160)  # t = 0, 0.1, ..., 1.0
    times, targets, rate = path_frames(*load_path(csv), fps=10)
    assert rate == 10 and len(times) == 11
    np.testing.assert_allclose(targets[1], [2.0, 0.4])  # 0.1 s of the way to (2, 1) at 0.25 s
    np.testing.assert_allclose(targets[-1], [0.0, 2.0])
    # without --fps: one frame per row, the video at the rows' mean rate
    assert path_frames(*load_path(csv), fps=None)[2] == pytest.approx(2.0)


@pytest.mark.parametrize("method", ["newton", "dls", "follow", "fabrik", "ccd"])
def test_lost_on_leaving_the_reach_and_found_on_return(tmp_path, method):
    t, xy = load_path(SCENES / "leave_reach.csv")
    result = replay_path(SCENES / "leave_reach.csv", f"{tmp_path}/out/", n_bones=4, method=method, size=(160, 160))
    dist = np.linalg.norm(xy, axis=1)
    assert result.frames == len(t)
    assert dist.max() > 4.5 and dist[0] < 3 and dist[-1] < 3
    assert not result.lost[dist < 3.9].any()  # the path starts and ends well inside the reach
    assert result.lost[dist > 4.05].all()  # and is lost while beyond it
    assert not result.lost[-10:].any() and result.error[-1] <= LOST_TOL
    # while lost the chain points at the target, stretched toward it
    far = np.flatnonzero(dist > 4.3)
    tips = np.array([planar.chain(a) for a in result.angles[far]])
    cos = np.sum(tips * xy[far], axis=1) / (np.linalg.norm(tips, axis=1) * dist[far])
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 3.0
    assert np.linalg.norm(tips, axis=1).min() > 3.9


def test_lost_target_is_drawn_white(tmp_path):
    replay_path(SCENES / "leave_reach.csv", f"{tmp_path}/out/", n_bones=4, method="dls", size=(480, 480), fps=6)
    frames = read_frames(tmp_path / "out")
    t, xy = path_frames(*load_path(SCENES / "leave_reach.csv"), fps=6)[:2]
    view = View(4, 480, 480)
    for k, white in ((0, False), (int(np.argmax(np.linalg.norm(xy, axis=1))), True)):
        u, v = np.rint(view.to_px(xy[k])).astype(int)
        pixel = frames[k][v, u].astype(int)
        assert (pixel.min() > 240) == white, (k, pixel)
        if not white:
            assert pixel[2] > 200 and pixel[0] < 120  # red


def test_keyframe_replay_frames_and_end_poses(tmp_path):
    keys = SCENES / "wave_keyframes.csv"
    durations, poses = load_keyframes(keys)
    out = f"{tmp_path}/keys/"
    assert main(["mouse", "--keyframes", str(keys), "-o", str(out), "--fps", "12", "--k1", "0.3", "--k2", "0.7", *SIZE]) == 0
    expected = math.ceil(durations.sum() * 12) + 1
    assert read_video(out) == (expected, 160, 160)
    result = replay_keyframes(keys, f"{tmp_path}/again/", fps=12, k1=0.3, k2=0.7, size=(160, 160), limits=True)
    assert result.frames == expected
    np.testing.assert_array_equal(result.angles[0], poses[0])
    np.testing.assert_array_equal(result.angles[-1], poses[-1])
    frames = read_frames(out)
    view = View(4, 160, 160)
    for frame, pose in ((frames[0], poses[0]), (frames[-1], poses[-1])):
        joints = planar.chain_all(pose)
        for a, b in zip(joints[1:-1], joints[2:]):  # the middle of each bone is bone-coloured
            u, v = np.rint(view.to_px((a + b) / 2)).astype(int)
            assert np.abs(frame[v, u].astype(int) - BONE).max() < 40


def test_keyframes_must_match_bones_and_limits(tmp_path, capsys):
    keys = _write(tmp_path / "k.csv", "duration_s,theta1,theta2\n0,0,0\n1,80,10\n")
    assert main(["mouse", "--keyframes", str(keys), "--bones", "3", "-o", str(f"{tmp_path}/o/"), *SIZE]) == 2
    assert f"{keys}: has 2 angles per key pose but --bones is 3" in capsys.readouterr().err
    assert main(["mouse", "--keyframes", str(keys), "--limits", "-o", str(f"{tmp_path}/o/"), *SIZE]) == 2
    assert "key pose 2: theta1 = 80 deg is outside" in capsys.readouterr().err
    assert main(["mouse", "--keyframes", str(keys), "-o", str(f"{tmp_path}/o/"), *SIZE]) == 0


@pytest.mark.parametrize(
    "text, line, words",
    [
        ("", 1, "expected header t,x,y"),
        ("# a comment\nt,x,z\n0,1,1\n", 2, "expected header t,x,y"),
        ("t,x,y\n0,1,1\n\n0.1,1,oops\n", 4, "y: expected a finite number (got 'oops')"),
        ("t,x,y\n0,1,1\n0.1,1,nan\n", 3, "y: expected a finite number"),
        ("t,x,y\n0,1,1\n0.1,1\n", 3, "expected 3 fields"),
        ("t,x,y\n0,1,1\n0.2,1,1\n0.2,2,2\n", 4, "t: expected times increasing"),
        ("t,x,y\n", 2, "expected at least one row"),
    ],
)
def test_bad_path_csv_is_refused_with_file_and_line(tmp_path, capsys, text, line, words):
    csv = _write(tmp_path / "bad.csv", text)
    out = tmp_path / "out.mp4"
    assert main(["mouse", "--path", str(csv), "-o", str(out), *SIZE]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"crowd-ik: {csv}:{line}: ") and words in err and "\n" not in err
    assert not out.exists()


def test_bad_keyframe_csv_is_refused_with_file_and_line(tmp_path, capsys):
    keys = _write(tmp_path / "k.csv", "duration_s,theta1\n0,0\n1,x\n")
    assert main(["mouse", "--keyframes", str(keys), "-o", str(tmp_path / "o.mp4"), *SIZE]) == 2
    assert f"{keys}:3: theta1: expected a finite number" in capsys.readouterr().err


def test_existing_output_is_not_clobbered(tmp_path, capsys):
    out = tmp_path / "circle.mp4"
    out.write_bytes(b"precious")
    assert main(["mouse", "--path", str(SCENES / "circle.csv"), "-o", str(out), *SIZE]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == b"precious"
    assert not [p for p in tmp_path.iterdir() if p.name != "circle.mp4"]  # no temporary left behind
    assert main(["mouse", "--path", str(SCENES / "circle.csv"), "-o", str(out), "--fps", "5", "--force", *SIZE]) == 0
    assert read_video(out) == (21, 160, 160)


def test_no_display_and_no_output_exits_2_with_one_line(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    assert main(["mouse"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "no display" in err and "crowd-ik mouse --path scenes/circle.csv -o circle.mp4" in err
    assert main(["mouse", "--rig", "humanoid"]) == 2


@pytest.mark.parametrize(
    "args, words",
    [
        (["-o", "x.mp4"], "needs --path"),
        (["--rig", "humanoid", "--path", "circle"], "humanoid is live only"),
        (["--rig", "humanoid", "--method", "newton"], "humanoid is solved with"),
        (["--path", "circle", "--keyframes", "wave_keyframes"], "give one of them"),
        (["--bones", "0", "--path", "circle"], "--bones"),
        (["--size", "15x16", "--path", "circle"], "--size"),
        (["--fps", "0", "--path", "circle"], "--fps"),
        (["--path", "no_such_path.csv"], "no such file"),
    ],
)
def test_bad_arguments_exit_2(tmp_path, monkeypatch, capsys, args, words):
    monkeypatch.chdir(tmp_path)
    assert main(["mouse", *args]) == 2
    assert words in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_shipped_paths_resolve_by_name_from_anywhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["mouse", "--path", "scenes/figure_eight.csv", "--fps", "4", *SIZE]) == 0
    assert read_video(tmp_path / "figure_eight.mp4") == (25, 160, 160)  # 6 s at 4 fps, default name


def test_recorder_never_overwrites_and_replays(tmp_path):
    (tmp_path / "path_001.csv").write_text("keep")
    rec = Recorder(tmp_path)
    for x in (1.0, 1.5, 2.0):
        rec.add((x, -x))
        time.sleep(0.002)
    out = rec.save()
    assert out == tmp_path / "path_002.csv" and (tmp_path / "path_001.csv").read_text() == "keep"
    t, xy = load_path(out)
    np.testing.assert_allclose(xy, [[1, -1], [1.5, -1.5], [2, -2]])
    assert np.all(np.diff(t) > 0)
    assert Recorder(tmp_path).save() == tmp_path / "path_003.csv"


def test_switching_method_keeps_the_pose():
    s = ChainSession(4, "dls")
    s.target = np.array([1.5, 2.0])
    s.step()
    assert not s.lost and s.error < 1e-3
    before = s.thetas.copy()
    for method in ("fabrik", "ccd", "newton", "follow"):
        s.set_method(method)
        s.step()  # already on the target: every method leaves the pose (nearly) as it is
        assert s.error < LOST_TOL and not s.lost, method
        np.testing.assert_allclose(s.thetas, before, atol=2e-3)


def test_limits_clamp_the_pose_and_shape_the_area():
    s = ChainSession(3, "dls", limits=True)
    lo, hi = chain_limits(3)
    np.testing.assert_allclose(np.degrees(hi), [45, 90, 170])  # the coursework's ranges
    s.target = np.array([-2.5, -0.2])
    for _ in range(3):
        s.step()
    assert np.all(s.thetas >= lo - 1e-12) and np.all(s.thetas <= hi + 1e-12)
    assert s.lost  # behind the root, out of the limited chain's area
    view = View(4, 200, 200)
    limited = reachable_mask(view, *chain_limits(4))
    free = reachable_mask(view, np.full(4, -np.inf), np.full(4, np.inf))
    for point, in_limited in (((2.0, 1.0), True), ((3.0, -1.5), True), ((-3.5, 0.0), False)):
        u, v = np.rint(view.to_px(point)).astype(int)
        assert limited[v, u] == in_limited and free[v, u], point
    assert free.sum() > limited.sum()
    tips = sample_reachable(4, *chain_limits(4), samples=2000)
    assert np.linalg.norm(tips, axis=1).max() <= 4 + 1e-9


def test_gui_image_is_rgb_indexed_x_then_y_up():
    frame = np.zeros((4, 6, 3), np.uint8)
    frame[0, 0] = (10, 20, 30)  # top-left, BGR
    img = to_gui_image(frame)
    assert img.shape == (6, 4, 3)
    assert tuple(img[0, 3]) == (30, 20, 10)  # x = 0, y = top (y up)


@pytest.mark.parametrize("method", ["fabrik", "ccd"])
def test_humanoid_drag_puts_the_effector_on_the_cursor_ray(method):
    s = HumanoidSession((320, 320), method)
    pix, _ = s.camera.project(s.effectors())
    assert s.press(5.0, 5.0) is None  # nowhere near an effector
    k = s.rig.effector_names.index("hand_r")
    px, py = pix[k]
    assert s.press(px + 2, py - 1) == k
    feet = s.effectors()[3:]
    for i in range(1, 9):  # drag up and out, as the window's loop does frame by frame
        s.drag_to(px - 4 * i, py - 6 * i)
        s.step()
    for _ in range(4):
        s.step()
    origin, d = s.camera.ray(px - 32, py - 48)
    v = s.effectors()[k] - origin
    assert np.linalg.norm(v - (v @ d) * d) < 0.02  # within 2 cm of the cursor's ray
    np.testing.assert_allclose(s.effectors()[3:], feet, atol=0.02)  # the feet are held
    frame = s.render()
    assert frame.shape == (320, 320, 3) and frame.dtype == np.uint8
    s.release()
    assert s.step() is None


# ---------------------------------------------------------------------------------------------
# the live window, driven under Xvfb with xdotool



@pytest.mark.gui
def test_live_window_drag_keys_and_recording(tmp_path):
    with crowd_ik_window(["mouse", "--bones", "4", "--size", "320x320"], "crowd-ik mouse", tmp_path) as (app, display,
                                                                                                      win):
        xdo(display, "key", "--window", win, "c")  # start recording
        xdo(display, "mousemove", "--window", win, "250", "100")
        time.sleep(0.2)
        xdo(display, "mousedown", "1")
        for i in range(1, 11):
            xdo(display, "mousemove", "--window", win, str(250 - 4 * i), str(100 - 3 * i))
            time.sleep(0.05)
        time.sleep(0.3)
        xdo(display, "mouseup", "1")
        for key in ("2", "l", "c"):  # dls, limits on, stop recording
            xdo(display, "key", "--window", win, key)
            time.sleep(0.3)
        xdo(display, "key", "--window", win, "Escape")
        out, err = app.communicate(timeout=60)
    assert app.returncode == 0, err
    assert "recorded" in out and "path_001.csv" in out
    t, xy = load_path(tmp_path / "path_001.csv")
    assert len(t) >= 5 and np.all(np.diff(t) > 0)
    view = View(4, 320, 320)
    np.testing.assert_allclose(xy[0], planar.chain(rest_pose(4)), atol=1e-4)  # recording began before the drag
    np.testing.assert_allclose(xy[-1], view.to_world(210, 70), atol=0.02)  # and ends where the drag let go
