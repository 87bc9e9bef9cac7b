"""`crowd-ik play` through crowd_ik.commands.cli.main: videos, stills, stats, no clobbering, exit codes."""

import json

import cv2
import numpy as np
import pytest

from crowd_ik.game import world as game
from crowd_ik.commands.cli import main
from crowd_ik.io.video import read_frames, read_video
from tiny_scenes import tiny_scene

TINY = tiny_scene(frames=12)


@pytest.fixture
def tiny(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


def test_video_has_the_frame_count_and_size(tiny, tmp_path, capsys):
    out = tmp_path / "clip.mp4"
    assert main(["play", str(tiny), "-o", str(out), "--frames", "10", "--size", "112x80"]) == 0
    assert read_video(out) == (10, 80, 112)
    text = capsys.readouterr().out
    for word in ("10 frames", "hits", "dodges", "simulation", "IK", "render", str(out), "wall time"):
        assert word in text


def test_default_output_is_the_scene_name_in_the_current_folder(tiny, tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["play", str(tiny), "--frames", "3"]) == 0
    assert read_video(work / "tiny.mp4") == (3, 64, 96)


def test_existing_output_is_not_clobbered(tiny, tmp_path, capsys):
    out = tmp_path / "clip.mp4"
    out.write_bytes(b"precious")
    assert main(["play", str(tiny), "-o", str(out)]) == 2
    assert out.read_bytes() == b"precious"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0] and "--force" in err[0]
    assert main(["play", str(tiny), "-o", str(out), "--frames", "2", "--force"]) == 0
    assert read_video(out)[0] == 2


def test_existing_stats_file_is_checked_before_simulating(tiny, tmp_path):
    out, stats = tmp_path / "clip.mp4", tmp_path / "s.json"
    stats.write_text("{}")
    assert main(["play", str(tiny), "-o", str(out), "--stats", str(stats)]) == 2
    assert not out.exists() and stats.read_text() == "{}"


def test_still_writes_one_png(tiny, tmp_path):
    out = tmp_path / "still.png"
    assert main(["play", str(tiny), "--still", "7", "-o", str(out)]) == 0
    image = cv2.imread(str(out))
    assert image.shape == (64, 96, 3) and image.std() > 1
    assert list(tmp_path.iterdir()) == [tiny, out] or set(tmp_path.iterdir()) == {tiny, out}


def test_still_matches_the_same_frame_of_the_world(tiny, tmp_path, monkeypatch):
    from crowd_ik.game.world import World
    from crowd_ik.scene import load_scene

    monkeypatch.setattr(game, "HUD_TIMINGS", False)
    out = tmp_path / "still.png"
    assert main(["play", str(tiny), "--still", "5", "-o", str(out)]) == 0
    world = World(load_scene(tiny))
    for _ in range(5):
        world.step()
    np.testing.assert_array_equal(cv2.imread(str(out)), world.render())


def test_stats_json(tiny, tmp_path):
    out, stats = tmp_path / "clip.mp4", tmp_path / "run.json"
    assert main(["play", str(tiny), "-o", str(out), "--stats", str(stats), "--seed", "5"]) == 0
    info = json.loads(stats.read_text())
    assert info["frames"] == 12 and info["characters"] == 6 and info["shooters"] == 2 and info["seed"] == 5
    assert info["size"] == [96, 64] and info["output"] == str(out)
    assert info["hits"] >= 0 and info["dodges"] >= 0 and info["shots"] > 0
    for key in ("mean_simulation_ms", "mean_ik_ms", "mean_render_ms", "wall_s"):
        assert info[key] > 0


def test_two_runs_give_identical_videos(tiny, tmp_path, monkeypatch):
    monkeypatch.setattr(game, "HUD_TIMINGS", False)  # the HUD's measured milliseconds differ run to run
    a, b = tmp_path / "a.mp4", tmp_path / "b.mp4"
    assert main(["play", str(tiny), "-o", str(a), "--frames", "48"]) == 0
    assert main(["play", str(tiny), "-o", str(b), "--frames", "48"]) == 0
    frames_a, frames_b = read_frames(a), read_frames(b)
    assert len(frames_a) == 48
    np.testing.assert_array_equal(np.stack(frames_a), np.stack(frames_b))
    assert a.read_bytes() == b.read_bytes()


def test_png_folder_output(tiny, tmp_path):
    out = tmp_path / "frames"
    assert main(["play", str(tiny), "-o", f"{out}/", "--frames", "3"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["frame_00000.png", "frame_00001.png", "frame_00002.png"]


def test_interrupt_keeps_a_shorter_video(tiny, tmp_path, monkeypatch):
    real_render = game.World.render
    calls = {"n": 0}

    def render_then_interrupt(self):
        calls["n"] += 1
        if calls["n"] > 5:
            raise KeyboardInterrupt
        return real_render(self)

    monkeypatch.setattr(game.World, "render", render_then_interrupt)
    out = tmp_path / "cut.mp4"
    assert main(["play", str(tiny), "-o", str(out)]) == 130
    assert read_video(out) == (5, 64, 96)


@pytest.mark.parametrize("argv,message", [
    (["--size", "95x64"], "even"),
    (["--size", "big"], "--size"),
    (["--frames", "0"], "frames"),
    (["--fps", "-3"], "fps"),
    (["--seed", "-1"], "seed"),
    (["--still", "12", "-o", "x.png"], "--still"),
    (["--still", "2", "-o", "x.mp4"], ".png"),
    (["-o", "x.png"], "--still"),
    (["-o", "x.avi"], "suffix"),
    (["--stats", "s.txt"], ".json"),
    (["--live"], "--live"),
    (["--inputs", "i.csv"], "--inputs"),
    (["--clip", "c.txt"], "--clip"),
])
def test_bad_input_exits_2_with_one_line(tiny, tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("DISPLAY", raising=False)  # --live must refuse, never open a window
    assert main(["play", str(tiny), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]


def test_missing_scene_exits_2(tmp_path, capsys):
    assert main(["play", str(tmp_path / "nope.toml")]) == 2
    assert "nope" in capsys.readouterr().err


def test_frames_and_seconds_together_are_refused(tiny):
    with pytest.raises(SystemExit) as exc:
        main(["play", str(tiny), "--frames", "3", "--seconds", "1"])
    assert exc.value.code == 2


def test_cuda_without_a_gpu_is_bad_input_for_play(tiny, tmp_path):
    """`play --arch cuda` on a machine without a GPU is refused like bad input (exit 2, one line, no file), as
    `bench --arch cuda` is; run in a fresh process, since this one already runs Taichi on the CPU."""
    import subprocess
    import sys

    from crowd_ik import runtime

    if runtime._probe_cuda_device():
        pytest.skip("this machine has a CUDA GPU")
    out = tmp_path / "x.mp4"
    proc = subprocess.run([sys.executable, "-m", "crowd_ik.commands.cli", "play", str(tiny), "--arch", "cuda", "--frames", "2",
                           "-o", str(out)], capture_output=True, text=True, timeout=300)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and not ln.startswith("[Taichi]")]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and "cuda" in lines[0] and "no CUDA GPU" in lines[0]
    assert not out.exists() and list(tmp_path.glob("*.mp4")) == []
