"""Scene schema: defaults are the arena, both TOML forms agree, every bad input gets a precise one-line error,
the shipped scenes load, and `crowd-ik scenes` exits 0 / 2 as documented."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest

from crowd_ik.commands import cli
from crowd_ik.commands.scenes import describe
from crowd_ik.scene import (
    ALL_KEYS,
    MEMORY_LIMIT,
    Scene,
    load_scene,
    memory_estimate,
    parse_scene,
    scene_with,
    shipped_scenes,
)

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "scenes"


def test_defaults_are_arena_toml():
    builtin = load_scene(None)
    from_file = load_scene(SCENES / "arena.toml")
    assert from_file == builtin
    assert builtin.path is None and from_file.path == SCENES / "arena.toml"
    assert builtin.name == from_file.name == "arena"
    assert builtin.n_frames == 300
    # the documented defaults, spelled out once more so a silent change of a default fails here
    assert builtin.seed == 0
    assert (builtin.characters.count, builtin.characters.layout, builtin.characters.spacing) == (40, "grid", 1.5)
    assert builtin.player.path == ((0, 0), (2, 0), (2, 2), (0, 2), (0, 0)) and builtin.player.speed == 1.5
    assert (builtin.shooters.count, builtin.shooters.radius, builtin.shooters.spread_deg) == (4, 12.0, 2.0)
    assert (builtin.bullets.speed, builtin.bullets.pool_size, builtin.bullets.gravity) == (25.0, 4096, 9.81)
    assert (builtin.time.floor, builtin.time.response) == (0.05, 4.0)
    assert (builtin.solver.method, builtin.solver.iterations, builtin.solver.tolerance) == ("fabrik", 8, 0.005)
    assert builtin.camera.position == (0, 4.5, 8.5) and builtin.camera.fov_deg == 50 and builtin.camera.mode == "follow"
    assert builtin.characters.walk_speed == 1.0
    assert (builtin.video.width, builtin.video.height, builtin.video.fps, builtin.video.frames) == (1280, 720, 30, None)


def test_arena_toml_spells_out_every_key():
    raw = tomllib.loads((SCENES / "arena.toml").read_text())
    written = {"seed"} | {f"{s}.{k}" for s, t in raw.items() if isinstance(t, dict) for k in t}
    assert written == set(ALL_KEYS) - {"video.frames"}


def test_empty_file_is_arena(tmp_path):
    f = tmp_path / "empty.toml"
    f.write_text("")
    scene = load_scene(f)
    assert scene == Scene() and scene.name == "empty" and scene.path == f
    assert parse_scene("# only a comment\n") == Scene()


def test_table_and_inline_forms_are_equal():
    inline = parse_scene('characters = { count = 7, layout = "ring" }\nvideo = { width = 320, height = 240 }')
    table = parse_scene('[characters]\ncount = 7\nlayout = "ring"\n[video]\nwidth = 320\nheight = 240\n')
    dotted = parse_scene('characters.count = 7\ncharacters.layout = "ring"\nvideo.width = 320\nvideo.height = 240')
    assert inline == table == dotted
    assert inline.characters.count == 7 and inline.characters.layout == "ring" and inline.video.width == 320
    assert inline.characters.spacing == 1.5  # untouched keys keep their defaults


def test_int_accepted_where_float_expected():
    scene = parse_scene("bullets = { speed = 30, drag = 0 }\ncamera = { fov_deg = 60 }")
    assert scene.bullets.speed == 30.0 and isinstance(scene.bullets.speed, float)
    assert isinstance(scene.camera.fov_deg, float) and isinstance(scene.bullets.drag, float)


@pytest.mark.parametrize(
    "text, message",
    [
        ("characters = {count = -3}", "bad.toml: characters.count: must be a positive integer (got -3)"),
        ("characters.count = 0", "bad.toml: characters.count: must be a positive integer (got 0)"),
        ("characters.count = true", "bad.toml: characters.count: must be an integer, not a boolean (got true)"),
        ("characters.count = 40.0", "bad.toml: characters.count: must be an integer (got 40.0)"),
        ("characters.count = 2000000", "bad.toml: characters.count: must be at most 1000000 (got 2000000)"),
        ("bullets.speed = nan", "bad.toml: bullets.speed: must be a finite number (got nan)"),
        ("bullets.speed = inf", "bad.toml: bullets.speed: must be a finite number (got inf)"),
        ("bullets.speed = -inf", "bad.toml: bullets.speed: must be a finite number (got -inf)"),
        ("bullets.speed = true", "bad.toml: bullets.speed: must be a number, not a boolean (got true)"),
        ('bullets.speed = "fast"', 'bad.toml: bullets.speed: must be a number (got "fast")'),
        ("bullets.speed = -25", "bad.toml: bullets.speed: must be in (0, 1000000] m/s (got -25)"),
        ("bullets.radius = 0", "bad.toml: bullets.radius: must be in (0, 10000] m (got 0)"),
        ("bullets.gravity = -9.81", "bad.toml: bullets.gravity: must be zero or positive (got -9.81)"),
        ("bullets.pool_size = 20000000", "bad.toml: bullets.pool_size: must be at most 10000000 (got 20000000)"),
        ("bullets.pool_size = 3", "bad.toml: bullets.pool_size: must be at least shooters.count (4), one slot per shooter (got 3)"),
        ("video.width = 1281", "bad.toml: video.width: must be even (H.264 with yuv420p needs even sizes) (got 1281)"),
        ("video.height = 8", "bad.toml: video.height: must be from 16 to 7680 pixels (got 8)"),
        ("video.width = 8000", "bad.toml: video.width: must be at most 7680 pixels (got 8000)"),
        ("video.fps = 0", "bad.toml: video.fps: must be in [1, 1000] (got 0)"),
        ("video.frames = 0", "bad.toml: video.frames: must be a positive integer (got 0)"),
        ("video.seconds = 0.001", "bad.toml: video.seconds: gives no frames at 30 fps (seconds * fps < 0.5) (got 0.001)"),
        ("camera.fov_deg = 180", "bad.toml: camera.fov_deg: must be in [0.01, 180) (got 180)"),
        ("camera.fov_deg = 0", "bad.toml: camera.fov_deg: must be in [0.01, 180) (got 0)"),
        ("camera = { position = [0, 8, 16], look_at = [0, 8, 16] }", "bad.toml: camera.look_at: must be at least 1 mm from camera.position [0.0, 8.0, 16.0] (got [0.0, 8.0, 16.0])"),
        ("camera.position = [1, 2]", "bad.toml: camera.position: must be a list of 3 numbers [x, y, z] (got [1, 2])"),
        ("camera.position = [1, 2, nan]", "bad.toml: camera.position: must be 3 finite numbers [x, y, z] within +-10000 m (got [1, 2, nan])"),
        ("shooters.spread_deg = 90", "bad.toml: shooters.spread_deg: must be in [0, 90) (got 90)"),
        ("shooters.spread_deg = -1", "bad.toml: shooters.spread_deg: must be in [0, 90) (got -1)"),
        ("time.floor = 0", "bad.toml: time.floor: must be in (0, 1] (got 0)"),
        ("time.floor = 1.5", "bad.toml: time.floor: must be in (0, 1] (got 1.5)"),
        ("solver.tolerance = 0", "bad.toml: solver.tolerance: must be a positive number (got 0)"),
        ("solver.method = 'fabrick'", 'bad.toml: solver.method: must be one of "fabrik", "dls", "ccd"; did you mean "fabrik"? (got "fabrick")'),
        ("solver.method = 3", 'bad.toml: solver.method: must be a string, one of "fabrik", "dls", "ccd" (got 3)'),
        ("seed = -1", "bad.toml: seed: must be zero or a positive integer (got -1)"),
        ("player.path = 3", "bad.toml: player.path: must be a list of one or more [x, z] pairs (got 3)"),
        ("player.path = []", "bad.toml: player.path: must be a list of one or more [x, z] pairs (got [])"),
        ("player.path = [[0, 0], [1]]", "bad.toml: player.path[1]: must be an [x, z] pair of finite numbers within +-10000 m (got [1])"),
        ("player.path = [[0, 0], ['a', 1]]", 'bad.toml: player.path[1]: must be an [x, z] pair of finite numbers within +-10000 m (got ["a", 1])'),
        ("player.path = [[0, nan]]", "bad.toml: player.path[0]: must be an [x, z] pair of finite numbers within +-10000 m (got [0, nan])"),
        ("characters = 5", "bad.toml: characters: must be a table, e.g. [characters] or characters = { ... } (got 5)"),
        ("[charcters]\ncount = 1", "bad.toml: charcters: unknown section or key; did you mean characters? (got {count = 1})"),
        ("[characters]\ncont = 3", "bad.toml: characters.cont: unknown key; did you mean characters.count? (got 3)"),
        ("count = 4", "bad.toml: count: unknown section or key; did you mean characters.count or shooters.count? (got 4)"),
        ("[video]\nxyzzy = 1", "bad.toml: video.xyzzy: unknown key; known keys: width, height, fps, seconds, frames (got 1)"),
    ],
)
def test_bad_scene_messages(text, message):
    with pytest.raises(ValueError) as info:
        parse_scene(text, source="bad.toml")
    assert str(info.value) == message
    assert "\n" not in str(info.value)


def test_syntax_error_names_the_line(tmp_path):
    f = tmp_path / "broken.toml"
    f.write_text("seed = 1\n[characters]\ncount = \n")
    with pytest.raises(ValueError, match=r"broken\.toml: line 3, column 9: invalid TOML: Invalid value$"):
        load_scene(f)


def test_absurd_count_refused_by_memory_estimate():
    with pytest.raises(ValueError) as info:
        parse_scene("characters.count = 1000000", source="big.toml")
    msg = str(info.value)
    assert msg.startswith("big.toml: characters.count: scene needs about 11.5 GiB (characters 11.4 GiB + ")
    assert msg.endswith("more than the 8.0 GiB limit (got 1000000)")
    # the same count of a lighter rig fits; each part alone fits, their sum does not
    light = parse_scene('characters = { count = 1000000, rig = "chain" }')
    assert memory_estimate(light)["total"] < MEMORY_LIMIT
    assert memory_estimate(parse_scene("characters.count = 600000"))["total"] < MEMORY_LIMIT
    with pytest.raises(ValueError, match=r"characters\.count: scene needs about 8\.4 GiB .*\(got 600000\)$"):
        parse_scene("characters.count = 600000\nbullets.pool_size = 10000000")


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.toml: no such scene file"):
        load_scene(tmp_path / "nope.toml")
    with pytest.raises(IsADirectoryError):
        load_scene(tmp_path)
    f = tmp_path / "latin1.toml"
    f.write_bytes(b"# caf\xe9\n")
    with pytest.raises(ValueError, match=r"latin1\.toml: not UTF-8 text \(byte 5\)"):
        load_scene(f)


def test_n_frames_and_frames_wins():
    assert parse_scene("video = { seconds = 2, fps = 24 }").n_frames == 48
    assert parse_scene("video = { seconds = 2, fps = 24, frames = 7 }").n_frames == 7


def test_shipped_scenes_load_and_match_the_package_copy():
    paths = shipped_scenes()
    names = [p.stem for p in paths]
    assert names == sorted(names) and {"arena", "duel", "crowd_1k", "stress_10k"} <= set(names)
    loaded = {p.stem: load_scene(p) for p in paths}
    assert loaded["duel"].shooters.count == 1 and loaded["duel"].characters.count <= 2
    assert 5 <= loaded["duel"].video.seconds <= 7
    assert loaded["crowd_1k"].characters.count == 1000 and loaded["crowd_1k"].shooters.count == 8
    stress = loaded["stress_10k"]
    assert (stress.characters.count, stress.shooters.count, stress.video.width, stress.video.height) == (10000, 16, 640, 360)
    assert stress.n_frames == 90
    for p in paths:
        assert describe(p), f"{p.name} needs a comment header"
    # crowd_ik/scenes is what a non-editable install ships: it must be a faithful copy
    for p in paths:
        copy = ROOT / "crowd_ik" / "scenes" / p.name
        assert copy.exists() and copy.read_bytes() == p.read_bytes(), f"copy scenes/{p.name} to crowd_ik/scenes/"


def test_bare_name_finds_a_shipped_scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    duel = load_scene("duel")
    assert duel.name == "duel" and duel == load_scene(SCENES / "duel.toml")
    assert load_scene(None) == load_scene("arena")
    with pytest.raises(FileNotFoundError):
        load_scene("no_such_scene")


def test_to_toml_round_trips():
    for p in shipped_scenes():
        scene = load_scene(p)
        again = parse_scene(scene.to_toml())
        assert again == scene
    with_frames = parse_scene("video.frames = 12")
    assert parse_scene(with_frames.to_toml()) == with_frames


def test_scene_with_overrides():
    base = load_scene(SCENES / "duel.toml")
    s = scene_with(base, seconds=2, size="320x240", method="dls", seed=None, **{"characters.count": 3})
    assert (s.n_frames, s.video.width, s.video.height, s.solver.method, s.characters.count) == (60, 320, 240, "dls", 3)
    assert s.seed == base.seed and s.path == base.path and s.name == "duel"
    assert scene_with(base) == base
    framed = scene_with(parse_scene("video.frames = 5"), seconds=1)
    assert framed.video.frames is None and framed.n_frames == 30  # seconds clears the file's frames
    assert scene_with(base, frames=4).n_frames == 4
    assert scene_with(base, **{"camera.position": (1, 2, 3)}).camera.position == (1.0, 2.0, 3.0)
    assert dataclasses.replace(base) == base


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"fps": -1}, "with override fps=-1: video.fps: must be in [1, 1000] (got -1)"),
        ({"size": "10x10"}, 'with override size="10x10": video.width: must be from 16 to 7680 pixels (got 10)'),
        ({"size": "big"}, "size: expected WIDTHxHEIGHT such as 1280x720 (got 'big')"),
        ({"seed": True}, "with override seed=true: seed: must be an integer, not a boolean (got true)"),
        ({"method": "newton"}, 'solver.method: must be one of "fabrik", "dls", "ccd" (got "newton")'),
        ({"fsp": 2}, "scene_with: unknown override 'fsp'; did you mean fps?"),
        ({"frames": 3, "seconds": 1}, "give frames or seconds, not both"),
    ],
)
def test_scene_with_bad_overrides(overrides, message):
    with pytest.raises(ValueError) as info:
        scene_with(load_scene(None), **overrides)
    assert str(info.value).endswith(message)


def test_cli_lists_shipped_scenes(capsys):
    assert cli.main(["scenes"]) == 0
    out = capsys.readouterr().out
    header, *rows = out.splitlines()
    assert header.split()[:5] == ["name", "characters", "shooters", "frames", "size"]
    by_name = {r.split()[0]: r.split() for r in rows if r.strip() and not r.startswith("4 scenes")}
    assert by_name["stress_10k"][1:5] == ["10000", "16", "90", "640x360"]
    assert by_name["arena"][1:5] == ["40", "4", "300", "1280x720"]
    assert "Duel" in " ".join(by_name["duel"][5:])


def test_cli_checks_a_file(capsys):
    path = str(SCENES / "duel.toml")
    assert cli.main(["scenes", path]) == 0
    out = capsys.readouterr().out
    first, rest = out.split("\n", 1)
    assert first == f"{path}: ok"
    assert parse_scene(rest) == load_scene(path)  # the effective values are TOML for the same scene


def test_cli_bad_file_exits_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("characters = { count = -3 }\n")
    assert cli.main(["scenes", str(bad)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == f"crowd-ik: {bad}: characters.count: must be a positive integer (got -3)\n"
    broken = tmp_path / "broken.toml"
    broken.write_text("[video\n")
    assert cli.main(["scenes", str(broken)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "line 1" in err and "Traceback" not in err
    assert cli.main(["scenes", str(tmp_path / "missing.toml")]) == 2
    assert "no such scene file" in capsys.readouterr().err


def test_readme_documents_every_key():
    readme = (SCENES / "README.md").read_text()
    missing = [k for k in ALL_KEYS if f"| `{k}` |" not in readme]
    assert not missing, f"scenes/README.md lacks {missing}"


def test_deep_nesting_is_refused_with_the_line_not_a_recursion_error():
    """5,000 nested arrays overflowed the TOML parser's recursion; brackets in strings and comments do not count."""
    from crowd_ik.scene import parse_scene

    with pytest.raises(ValueError, match=r"deep\.toml: line 2: invalid TOML: nested deeper than 32 levels"):
        parse_scene("seed = 1\nx = " + "[" * 5000 + "]" * 5000 + "\n", "deep.toml")
    assert parse_scene('# [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[\nseed = 4\n', "c.toml").seed == 4
    assert parse_scene("seed = 5\ncharacters = { count = 3 }\n", "ok.toml").characters.count == 3


def test_a_closed_pipe_ends_the_listing_quietly():
    """`crowd-ik scenes FILE | head -1` exits 0 with no traceback (it raised BrokenPipeError)."""
    import subprocess
    import sys

    proc = subprocess.run(f"{sys.executable} -m crowd_ik.commands.cli scenes scenes/arena.toml | head -c 1",
                          shell=True, capture_output=True, text=True, timeout=120,
                          cwd=str(__import__("pathlib").Path(__file__).resolve().parent.parent))
    assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr, proc.stderr


def test_only_regular_readable_files_of_sensible_size_are_read(tmp_path):
    """A FIFO (it blocked forever), /dev/zero (MemoryError) and a 17 MB file are refused with one line."""
    import os

    from crowd_ik.scene import load_scene

    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="pipe.toml: not a regular file"):
        load_scene(str(fifo))
    if os.path.exists("/dev/zero"):
        with pytest.raises(ValueError, match="not a regular file"):
            load_scene("/dev/zero")
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (17 * 2**20))
    with pytest.raises(ValueError, match="at most 16,777,216"):
        load_scene(str(big))
