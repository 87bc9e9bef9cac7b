"""Live play: player inputs steering the World, the inputs CSV and its headless replay (frame
for frame), mouse/keys -> input, the no-display refusal, and the window under Xvfb + xdotool."""

import json
import time

import numpy as np
import pytest
from xwindow import crowd_ik_window, xdo

from crowd_ik.game import world as game
from crowd_ik.commands.cli import main
from crowd_ik.game.world import World
from crowd_ik.io.inputs import HEADER, PlayerInput, format_inputs, load_inputs, scene_settings, write_inputs
from crowd_ik.session import Session
from crowd_ik.view.window import CHEST_HEIGHT, aim_point, move_from_keys, shooter_chests, walk_toward
from crowd_ik.view.render import Camera
from crowd_ik.io.video import read_frames

TINY = """
seed = 3
characters = { count = 3, spacing = 1.5 }
shooters = { count = 2, fire_rate = 4.0, radius = 6.0 }
bullets = { pool_size = 256 }
time = { floor = 0.3 }
camera = { position = [0, 4, 9], look_at = [0, 1, 0], fov_deg = 50 }
video = { width = 96, height = 64, fps = 24, frames = 12 }
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    path = tmp_path_factory.mktemp("live") / "tiny.toml"
    path.write_text(TINY)
    return path


def _scripted_inputs(n=16):
    """Walk 'into' the screen, then right, fire twice, then stand (time slows down)."""
    out = []
    for k in range(n):
        move = (0.0, -1.0) if k < 6 else (0.7, 0.0) if k < 10 else (0.0, 0.0)
        aim = (2.5 - 0.1 * k, 1.3, -6.0 + 0.123456789 * k)  # more decimals than are kept
        out.append(PlayerInput(move, aim, k in (3, 8)))
    return out


def _session(tiny, inputs):
    from crowd_ik.scene import load_scene

    session = Session(World(load_scene(tiny), hud_timings=False, open_ended=True))
    frames = [session.frame(inp).copy() for inp in inputs]
    return session, frames


@pytest.fixture(scope="module")
def live_run(tiny, tmp_path_factory):
    """A session driven through the live loop's per-frame function, its inputs recorded to CSV,
    and the CSV replayed headless by `crowd-ik play --inputs` to PNG frames."""
    folder = tmp_path_factory.mktemp("replay")
    session, frames = _session(tiny, _scripted_inputs())
    csv = folder / "session.csv"
    write_inputs(csv, session.log, scene_settings(session.world.scene))
    saved = game.HUD_TIMINGS
    game.HUD_TIMINGS = False  # measured milliseconds would differ between runs
    try:
        assert main(["play", str(tiny), "--inputs", str(csv), "-o", str(folder / "a") + "/"]) == 0
    finally:
        game.HUD_TIMINGS = saved
    return {"folder": folder, "csv": csv, "session": session, "frames": frames,
            "replay": read_frames(folder / "a")}


# ---------------------------------------------------------------------------------------------
# the World steered by inputs


def test_inputs_move_the_player_set_the_time_scale_and_fire(live_run):
    session = live_run["session"]
    world = session.world
    log = session.log
    assert len(log) == 16 and world.frame == 16
    assert world.player.shots == 2
    # 6 frames at speed 1.5 m/s toward -z, then 4 frames at 0.7 * 1.5 m/s toward +x
    end = world.player.position()
    assert end[2] == pytest.approx(-6 * 1.5 / 24, abs=1e-6)
    assert end[0] == pytest.approx(4 * 0.7 * 1.5 / 24, abs=1e-6)
    assert world.time_scale < 0.9  # standing still for the last 6 frames: time slows down
    # the right hand is held on the line from the shoulder to the aim point
    hb = world.hbody
    joints = world.player.crowd.joint_positions()[0]
    aim = np.array(log[-1].aim)
    shoulder, hand = joints[hb.shoulder_r], joints[hb.hand_r]
    d = (aim - shoulder) / np.linalg.norm(aim - shoulder)
    off_line = np.linalg.norm((hand - shoulder) - d * np.dot(hand - shoulder, d))
    assert off_line < 0.08 and np.dot(hand - shoulder, d) > 0.3


def test_canonical_inputs_are_what_is_recorded_and_applied(live_run):
    log = live_run["session"].log
    assert log[5].aim[2] == round(-6.0 + 0.123456789 * 5, 6)
    again = load_inputs(live_run["csv"])
    assert again.inputs == tuple(log)
    assert again.settings == {"scene": "tiny", "seed": "3", "fps": "24.0", "size": "96x64", "solver": "fabrik"}
    assert PlayerInput((3.0, 4.0), (0, 0, 0)).canonical().move == (0.6, 0.8)


def test_fire_spawns_one_bullet_from_the_hand_toward_the_aim(tiny):
    from crowd_ik.scene import load_scene

    world = World(load_scene(tiny), autofire=False, open_ended=True)
    assert len(world.live_bullets()[0]) == 0
    hand = world.player.crowd.joint_positions()[0, world.hbody.hand_r]
    aim = np.array([0.0, 1.3, -8.0])
    slots = world.set_player_input((0.0, 0.0), aim, fire=True)
    assert len(slots) == 1 and world.player.shots == 1
    pos, vel = world.live_bullets()
    assert np.linalg.norm(pos[0] - hand) < 0.1
    # its ballistic path (no drag in this scene) passes through the aim point
    t = np.linalg.norm((aim - pos[0])[[0, 2]]) / np.linalg.norm(vel[0][[0, 2]])
    reach = pos[0] + vel[0] * t - [0.0, 0.5 * 9.81 * t * t, 0.0]
    assert np.linalg.norm(reach - aim) < 0.02
    with pytest.raises(ValueError, match="move"):
        world.set_player_input((0.0, 2.0))
    with pytest.raises(ValueError, match="aim"):
        world.set_player_input((0.0, 0.0), (np.nan, 0.0, 0.0))


RANGE = """
seed = 5
characters = { count = 1 }
shooters = { count = 2, placement = "line", radius = 6.0, fire_rate = 3.0 }
player = { path = [[0, -3]] }
bullets = { pool_size = 64 }
time = { floor = 1.0 }
camera = { position = [0, 4, 9], look_at = [0, 1, 0], fov_deg = 50 }
video = { width = 160, height = 96, fps = 24, frames = 12 }
"""


def test_a_click_on_a_shooter_downs_it(tmp_path):
    """The live loop's path: the cursor near a shooter snaps the aim to its chest, a click fires, the
    player's bullet downs that shooter; the HUD counts it and the aim no longer snaps to it."""
    from crowd_ik.scene import load_scene

    path = tmp_path / "range.toml"
    path.write_text(RANGE)
    world = World(load_scene(path), hud_timings=False, open_ended=True)
    session = Session(world)
    cam = world.camera
    chests = shooter_chests(world)
    assert len(chests) == 2
    ((px, py),), _ = cam.project(chests[1][None])
    aim = aim_point(cam, px + 2, py - 1, CHEST_HEIGHT * world.hbody.scale, chests)
    np.testing.assert_allclose(aim, chests[1])  # snapped
    shots = world.shooters.shots_fired.copy()
    session.advance(PlayerInput((0.0, 0.0), tuple(aim), True))
    for _ in range(10):  # about 0.4 s of world time; the bullet needs about 0.12 s
        session.advance(PlayerInput((0.0, 0.0), tuple(aim), False))
    assert world.player.shots == 1
    assert world.shooters.alive.tolist() == [True, False] and world.stats["shooters_down"] == 1
    assert "shooters down 1/2" in world.hud_lines()[2]
    np.testing.assert_allclose(shooter_chests(world), chests[:1], atol=0.05)  # only the standing one
    down_shots = world.shooters.shots_fired[1]
    for _ in range(24):
        session.advance(PlayerInput((0.0, 0.0), tuple(aim), False))
    assert world.shooters.shots_fired[1] == down_shots and world.shooters.shots_fired[0] > shots[0]
    assert session.frame(PlayerInput((0.0, 0.0), tuple(aim), False)).shape == (96, 160, 3)


# ---------------------------------------------------------------------------------------------
# replays


def test_replay_reproduces_the_live_session_frame_for_frame(live_run):
    live, replay = live_run["frames"], live_run["replay"]
    assert len(replay) == len(live) == 16
    for k, (a, b) in enumerate(zip(live, replay)):
        assert np.array_equal(a, b), f"frame {k} differs"
    assert not np.array_equal(live[0], live[-1])


def test_a_second_replay_is_identical(live_run, tiny, monkeypatch):
    monkeypatch.setattr(game, "HUD_TIMINGS", False)
    out = live_run["folder"] / "b"
    assert main(["play", str(tiny), "--inputs", str(live_run["csv"]), "-o", str(out) + "/"]) == 0
    again = read_frames(out)
    assert len(again) == 16
    for k, (a, b) in enumerate(zip(live_run["replay"], again)):
        assert np.array_equal(a, b), f"frame {k} differs"


def test_replay_uses_the_recorded_settings(tiny, tmp_path, monkeypatch):
    """Recorded at another size and fps than the scene's: the replay takes them from the file."""
    csv = tmp_path / "r.csv"
    write_inputs(csv, _scripted_inputs(3), {"scene": "tiny", "seed": "3", "fps": "12.0", "size": "64x48",
                                            "solver": "fabrik"})
    stats = tmp_path / "s.json"
    assert main(["play", str(tiny), "--inputs", str(csv), "-o", str(tmp_path / "f") + "/", "--stats", str(stats)]) == 0
    info = json.loads(stats.read_text())
    assert info["size"] == [64, 48] and info["fps"] == 12.0 and info["frames"] == 3
    assert info["player_shots"] == 0 and info["inputs"] == str(csv)
    assert read_frames(tmp_path / "f")[0].shape == (48, 64, 3)


BAD = [
    ("", 1, "header"),
    ("frame,move_x,move_z\n", 1, "header"),
    ("frame,move_x,move_z,aim_x,aim_y,aim_z,fire\n", 2, "at least one row"),
    ("frame,move_x,move_z,aim_x,aim_y,aim_z,fire\n0,0,0,1,1,1\n", 2, "7 fields"),
    ("frame,move_x,move_z,aim_x,aim_y,aim_z,fire\n0,0,0,1,1,1,0\n2,0,0,1,1,1,0\n", 3, "frame: expected 1"),
    ("frame,move_x,move_z,aim_x,aim_y,aim_z,fire\n\n# note\n0,0,abc,1,1,1,0\n", 4, "move_z"),
    ("frame,move_x,move_z,aim_x,aim_y,aim_z,fire\n0,1.5,0,1,1,1,0\n", 2, "[-1, 1]"),
    ("frame,move_x,move_z,aim_x,aim_y,aim_z,fire\n0,0,0,nan,1,1,0\n", 2, "aim_x"),
    ("frame,move_x,move_z,aim_x,aim_y,aim_z,fire\n0,0,0,1,1,1,2\n", 2, "fire"),
    ("# crowd-ik play inputs: fps=fast\nframe,move_x,move_z,aim_x,aim_y,aim_z,fire\n0,0,0,1,1,1,0\n", 1, "fps"),
]


@pytest.mark.parametrize("text,line,problem", BAD)
def test_bad_inputs_file_exits_2_naming_file_and_line(tiny, tmp_path, monkeypatch, capsys, text, line, problem):
    monkeypatch.chdir(tmp_path)
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    assert main(["play", str(tiny), "--inputs", str(bad), "-o", "out.mp4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{bad}:{line}: " in err[0] and problem in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]


def test_missing_inputs_file_and_too_many_frames_exit_2(tiny, live_run, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["play", str(tiny), "--inputs", "nope.csv"]) == 2
    assert "--inputs: nope.csv: no such file" in capsys.readouterr().err
    assert main(["play", str(tiny), "--inputs", str(live_run["csv"]), "--frames", "17"]) == 2
    assert "holds 16 frames" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_format_inputs_has_the_header_and_one_row_per_frame():
    text = format_inputs([PlayerInput((0.0, -1.0), (1.0, 1.3, -2.0), True)], {"fps": "30.0"})
    lines = text.splitlines()
    assert lines[0] == "# crowd-ik play inputs: fps=30.0"
    assert lines[1] == ",".join(HEADER) and lines[2] == "0,0.0,-1.0,1.0,1.3,-2.0,1"


# ---------------------------------------------------------------------------------------------
# mouse and keys


def test_keys_walk_camera_relative_and_the_mouse_aims_through_the_camera():
    cam = Camera((0, 8, 16), (0, 1, 0), 50, 1280, 720)
    assert move_from_keys(cam, True, False, False, False) == pytest.approx((0.0, -1.0))  # W: away from the camera
    assert move_from_keys(cam, False, False, False, True) == pytest.approx((1.0, 0.0))  # D: screen right
    assert move_from_keys(cam, True, False, False, True) == pytest.approx((2 ** -0.5, -(2 ** -0.5)))
    assert move_from_keys(cam, True, True, False, False) == (0.0, 0.0)
    point = np.array([2.0, 1.3, -3.0])
    ((px, py),), _ = cam.project(point[None])
    np.testing.assert_allclose(aim_point(cam, px, py, 1.3), point, atol=1e-6)
    shooter = np.array([[5.0, 1.2, -8.0], [-5.0, 1.2, -8.0]])
    ((sx, sy),), _ = cam.project(shooter[:1])
    np.testing.assert_allclose(aim_point(cam, sx + 10, sy - 8, 1.3, shooter), shooter[0])  # snaps
    far = aim_point(cam, 640, 5, 1.3)  # above the horizon: far along the ray
    assert np.linalg.norm(far - cam.position) == pytest.approx(60.0)
    ((gx, gy),), _ = cam.project(np.array([[3.0, 0.0, 4.0]]))
    assert walk_toward(cam, gx, gy, (0.0, 0.0)) == pytest.approx((0.6, 0.8))
    assert walk_toward(cam, gx, gy, (3.0, 3.95)) == (0.0, 0.0)


# ---------------------------------------------------------------------------------------------
# the window


def test_live_without_a_display_exits_2_with_one_line(tiny, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    assert main(["play", str(tiny), "--live"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "--live needs a display; render headless instead: crowd-ik play" in err[0] and "-o OUT.mp4" in err[0]


def test_existing_record_file_is_refused_before_the_window(tiny, tmp_path, capsys):
    rec = tmp_path / "rec.csv"
    rec.write_text("keep")
    assert main(["play", str(tiny), "--live", "--record", str(rec)]) == 2
    assert "rec.csv exists" in capsys.readouterr().err and rec.read_text() == "keep"


@pytest.mark.parametrize("argv,message", [
    (["--record", "r.csv"], "--live"),
    (["--live", "-o", "x.mp4"], "-o"),
    (["--live", "--clip", "c.npz"], "--clip"),
    (["--live", "--record", "r.txt"], ".csv"),
])
def test_flag_combinations_exit_2(tiny, tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(["play", str(tiny), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert list(tmp_path.iterdir()) == []



@pytest.mark.gui
def test_live_window_w_key_moves_the_player_and_a_click_fires(tiny, tmp_path):
    rec, stats = tmp_path / "rec.csv", tmp_path / "live.json"
    argv = ["play", str(tiny), "--live", "--size", "160x96", "--record", str(rec), "--stats", str(stats)]
    with crowd_ik_window(argv, "crowd-ik play", tmp_path) as (app, display, win):
        xdo(display, "mousemove", "--window", win, "120", "30")
        xdo(display, "keydown", "--window", win, "w")
        time.sleep(1.5)
        xdo(display, "keyup", "--window", win, "w")
        time.sleep(0.3)
        xdo(display, "click", "--window", win, "1")
        time.sleep(0.5)
        xdo(display, "key", "--window", win, "Escape")
        out, err = app.communicate(timeout=60)
    assert app.returncode == 0, err
    assert "live:" in out and str(rec) in out
    log = load_inputs(rec)
    moving = [inp for inp in log.inputs if inp.move == (0.0, -1.0)]
    assert len(moving) >= 5 and log.inputs[-1].move == (0.0, 0.0)
    assert sum(inp.fire for inp in log.inputs) == 1
    assert log.settings["size"] == "160x96"
    info = json.loads(stats.read_text())
    assert info["frames"] == len(log) and info["player_shots"] == 1
    start, end = np.array(info["player_start"]), np.array(info["player_end"])
    assert end[2] - start[2] == pytest.approx(-len(moving) * 1.5 / 24, abs=1e-4)
    assert abs(end[0] - start[0]) < 1e-6
