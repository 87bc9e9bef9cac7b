"""Hostile input and hostile conditions (issue 16): a corpus of bad scenes and flags, each refused with exit 2
and one line naming the file and the key, by `scenes F` and `play F` alike; values at the bounds that play
without numpy warnings; a full disk (a small tmpfs, as root) for every writer; SIGTERM like Ctrl-C."""

import os
import re
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from crowd_ik.commands.cli import main
from crowd_ik.io.video import read_video
from crowd_ik.scene import parse_scene, scene_with
from tiny_scenes import tiny_scene

BAD_SCENES = sorted((Path(__file__).parent / "data" / "bad_scenes").glob("*.toml"))

TINY = tiny_scene(frames=6)


@pytest.fixture
def tiny(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


def _error_lines(err: str) -> list[str]:
    """stderr without the progress bar (tqdm, \\r-separated) and Taichi's banner."""
    return [ln for ln in err.replace("\r", "\n").splitlines()
            if ln.strip() and "%|" not in ln and not ln.startswith("[Taichi]")]


def _expected_key(path: Path) -> str:
    first = path.read_text().splitlines()[0]
    assert first.startswith("# expect: "), path
    return first[len("# expect: "):]


def test_the_corpus_is_large_enough():
    assert len(BAD_SCENES) >= 40


@pytest.mark.parametrize("path", BAD_SCENES, ids=lambda p: p.stem)
def test_bad_scene_is_refused_alike_by_scenes_and_play(path, tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)
    key = _expected_key(path)
    assert main(["scenes", str(path)]) == 2
    out, err = capfd.readouterr()
    lines = _error_lines(err)
    assert len(lines) == 1 and str(path) in lines[0] and f": {key}" in lines[0], err
    assert "ok" not in out
    assert main(["play", str(path), "-o", "x.mp4"]) == 2
    assert _error_lines(capfd.readouterr().err) == lines  # the same verdict, word for word
    assert list(tmp_path.iterdir()) == []  # a refused run creates no file or folder


@pytest.mark.parametrize("argv,key", [
    (["--fps", "0.5"], "override fps=0.5: video.fps"),
    (["--fps", "1e-300"], "video.fps"),
    (["--fps", "1001"], "video.fps"),
    (["--seconds", "1e300"], "override seconds=1e+300: video.seconds"),
    (["--seconds", "100000", "--fps", "30"], "video.seconds"),
    (["--frames", "1000001"], "override frames=1000001: video.frames"),
    (["--size", "16x100000"], "video.height"),
    (["--seed", "4294967296"], "seed"),
])
def test_bad_flags_are_refused_with_one_line(tiny, tmp_path, monkeypatch, capfd, argv, key):
    monkeypatch.chdir(tmp_path)
    assert main(["play", str(tiny), "-o", "out/x.mp4", *argv]) == 2
    lines = _error_lines(capfd.readouterr().err)
    assert len(lines) == 1 and key in lines[0] and "tiny.toml" in lines[0], lines
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]


@pytest.mark.parametrize("overrides", [
    {"camera.position": [0, 10, 0], "camera.look_at": [0.011, 0, 0]},  # just off straight down
    {"camera.position": [10000, 10000, -10000]},
    {"camera.fov_deg": 0.01},
    {"characters.spacing": 2000.0, "bullets.gravity": 0.0},  # the grid within 10^4 m, straight shots
    {"characters.scale": 1e-6},
    {"shooters.radius": 1000.0},  # far beyond the bullets' range: they aim high, without overflow
    {"bullets.speed": 1e6},
    {"bullets.radius": 1e4},
    {"shooters.fire_rate": 1e6},
    {"player.speed": 1e6},
    {"bullets.lifetime": 1e38},
], ids=lambda o: ",".join(o))
def test_values_at_the_bounds_play_without_numpy_warnings(overrides):
    from crowd_ik.game.world import World

    scene = scene_with(parse_scene(TINY, "tiny.toml"), **overrides)
    with warnings.catch_warnings(), np.errstate(all="raise", under="ignore"):
        warnings.simplefilter("error")
        world = World(scene)
        for k in range(6):
            if k:
                world.step()
            frame = world.render()
    assert frame.shape == (64, 96, 3)


# --------------------------------------------------------------------------------------------
# a full disk


@pytest.fixture
def full_disk(tmp_path):
    """A 1 MiB tmpfs filled to the brim (_leave frees some of it)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here")
    try:
        try:
            with open(disk / "filler", "wb") as fh:
                while True:
                    fh.write(b"\0" * 65536)
                    fh.flush()
        except OSError:
            pass  # the disk is full
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def _leave(disk: Path, free: int) -> None:
    """Free `free` bytes of the full disk."""
    filler = disk / "filler"
    os.truncate(filler, max(filler.stat().st_size - free, 0))


def _check_failed_cleanly(disk: Path, capfd, named: str) -> None:
    lines = _error_lines(capfd.readouterr().err)
    assert len(lines) == 1, lines
    assert named in lines[0] and "No space left on device" in lines[0] and lines[0].startswith("crowd-ik: error: ")
    assert sorted(p.name for p in disk.iterdir()) == ["filler"]  # nothing truncated, no temporary file


@pytest.mark.parametrize("name", ["x.mp4", "x.webm", "frames/", "new/x.png"])
def test_full_disk_fails_with_one_line_and_leaves_nothing(tiny, full_disk, capfd, name):
    out = f"{full_disk}/{name}"
    extra = ["--still", "2"] if name.endswith(".png") else []
    assert main(["play", str(tiny), "-o", out, *extra]) == 1
    _check_failed_cleanly(full_disk, capfd, str(full_disk / name.rstrip("/").split("/")[0]))


def test_webm_that_fills_the_disk_midway_is_not_published(tiny, full_disk, capfd):
    # OpenCV's VideoWriter fails silently here (it used to exit 0 and claim every frame)
    _leave(full_disk, 48 * 1024)
    out = full_disk / "x.webm"
    assert main(["play", str(tiny), "-o", str(out), "--frames", "120", "--size", "320x240"]) == 1
    _check_failed_cleanly(full_disk, capfd, str(out))


def test_stats_on_a_full_disk_fail_with_one_line(tiny, tmp_path, full_disk, capfd):
    stats = full_disk / "s.json"
    assert main(["play", str(tiny), "-o", str(tmp_path / "x.mp4"), "--stats", str(stats)]) == 1
    _check_failed_cleanly(full_disk, capfd, str(stats))


# --------------------------------------------------------------------------------------------
# SIGTERM


def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(c) for c in text.split()]


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def test_sigterm_finalises_a_shorter_video_and_exits_143(tiny, tmp_path):
    import signal

    out = tmp_path / "cut.mp4"
    proc = subprocess.Popen([sys.executable, "-m", "crowd_ik.commands.cli", "play", str(tiny), "-o", str(out),
                             "--frames", "100000"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = bytearray()

    def read() -> None:
        while chunk := os.read(proc.stderr.fileno(), 4096):
            err.extend(chunk)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            done = [int(n) for n in re.findall(rb"(\d+)/100000 frames", bytes(err))]
            if done and max(done) >= 5:
                break
            time.sleep(0.1)
        assert proc.poll() is None and time.monotonic() < deadline, bytes(err).decode("utf-8", "replace")[-500:]
        encoders = _children(proc.pid)
        assert encoders, "no ffmpeg child while rendering"
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=10)
    text = bytes(err).decode("utf-8", "replace")
    assert proc.returncode == 143, text
    assert _error_lines(text) == ["crowd-ik: terminated"], repr(text[-500:])
    n, h, w = read_video(out)
    assert 5 <= n < 100000 and (h, w) == (64, 96)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary file
    assert not any(_running(pid) for pid in encoders)  # the encoder was waited for, not orphaned


@pytest.mark.parametrize("layout,count", [("grid", 1), ("grid", 7), ("grid", 40), ("random", 40), ("ring", 3),
                                          ("ring", 500)])
def test_crowd_extent_bounds_the_game_layout(layout, count):
    from crowd_ik.game.layout import character_layout
    from crowd_ik.scene import crowd_extent

    scene = scene_with(parse_scene(TINY, "tiny.toml"), **{"characters.layout": layout, "characters.count": count})
    roots, _ = character_layout(scene)
    farthest = float(np.abs(roots[:, [0, 2]]).max())
    assert farthest <= crowd_extent(scene) + 1e-4
    if layout != "random":
        assert farthest >= crowd_extent(scene) * (0.99 if layout == "ring" else 1.0) - 1e-4


def test_scene_extent_is_the_library_bound():
    from crowd_ik import rig, scene

    assert scene.MAX_EXTENT == rig.MAX_EXTENT
