"""crowd_ik.io.output: no-clobber checks and atomic writes through a hidden same-suffix temporary file."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

from crowd_ik.io.output import (
    atomic_path,
    check_writable,
    check_writable_dir,
    is_dir_target,
    make_temp_path,
    write_bytes,
    write_json,
    write_text,
)


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name)


def _default_file_mode(folder):
    probe = folder / "probe"
    probe.write_bytes(b"")
    mode = stat.S_IMODE(probe.stat().st_mode)
    probe.unlink()
    return mode


def test_check_writable_accepts_new_file_and_creates_nothing(tmp_path):
    target = tmp_path / "a" / "b" / "out.json"
    assert check_writable(target) == target
    assert not (tmp_path / "a").exists()


def test_check_writable_refuses_existing_file_without_force(tmp_path):
    target = tmp_path / "out.mp4"
    target.write_bytes(b"old")
    with pytest.raises(FileExistsError, match=r"out\.mp4 exists"):
        check_writable(target)
    assert check_writable(target, force=True) == target
    assert target.read_bytes() == b"old"


def test_check_writable_refuses_folders_and_file_parents(tmp_path):
    with pytest.raises(IsADirectoryError):
        check_writable(tmp_path)
    with pytest.raises(IsADirectoryError):
        check_writable(str(tmp_path / "new") + "/")
    (tmp_path / "plain").write_text("x")
    with pytest.raises(NotADirectoryError, match="plain"):
        check_writable(tmp_path / "plain" / "sub" / "out.json")
    with pytest.raises(ValueError, match="empty"):
        check_writable("")


def test_check_writable_dir(tmp_path):
    assert check_writable_dir(tmp_path / "new") == tmp_path / "new"
    empty = tmp_path / "empty"
    empty.mkdir()
    check_writable_dir(empty)
    (empty / "frame_00000.png").write_bytes(b"x")
    with pytest.raises(FileExistsError, match="not empty"):
        check_writable_dir(empty)
    assert check_writable_dir(empty, force=True) == empty
    (tmp_path / "file").write_text("x")
    with pytest.raises(NotADirectoryError):
        check_writable_dir(tmp_path / "file", force=True)
    assert is_dir_target("frames/") and is_dir_target(tmp_path) and not is_dir_target(tmp_path / "x.mp4")


def test_make_temp_path_is_hidden_unique_same_folder_same_suffix(tmp_path):
    final = tmp_path / "arena.mp4"
    a, b = make_temp_path(final), make_temp_path(final)
    assert a != b and a.parent == b.parent == tmp_path
    assert a.name.startswith(".arena.mp4.tmp-") and a.suffix == ".mp4" and a.is_file()
    d = make_temp_path(tmp_path / "frames", folder=True)
    assert d.is_dir() and d.name.startswith(".frames.tmp-")


def test_atomic_path_publishes_with_normal_permissions(tmp_path):
    target = tmp_path / "deep" / "er" / "out.txt"
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp.suffix == ".txt" and tmp.name.startswith(".")
        assert not target.exists()
        tmp.write_text("done")
    assert target.read_text() == "done"
    assert _leftovers(target.parent) == []
    assert stat.S_IMODE(target.stat().st_mode) == _default_file_mode(tmp_path)


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_atomic_path_failure_keeps_old_file_and_removes_temp(tmp_path, exc):
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(type(exc)):
        with atomic_path(target, force=True) as tmp:
            tmp.write_text("half")
            raise exc
    assert target.read_text() == "old"
    assert _leftovers(tmp_path) == []


def test_atomic_path_no_clobber_and_force(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(FileExistsError):
        with atomic_path(target):
            pytest.fail("must refuse before yielding")
    assert target.read_text() == "old"
    with atomic_path(target, force=True) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new"
    assert _leftovers(tmp_path) == []


def test_atomic_path_never_clobbers_a_file_that_appears_meanwhile(tmp_path):
    target = tmp_path / "out.csv"
    with pytest.raises(FileExistsError):
        with atomic_path(target) as tmp:
            tmp.write_text("mine")
            target.write_text("someone else's")
    assert target.read_text() == "someone else's"
    assert _leftovers(tmp_path) == []


def test_atomic_path_serves_suffix_driven_writers(tmp_path):
    target = tmp_path / "clip.npz"
    with atomic_path(target) as tmp:
        np.savez(tmp, a=np.arange(5))  # np.savez would append .npz to a name without it
    assert sorted(os.listdir(tmp_path)) == ["clip.npz"]
    np.testing.assert_array_equal(np.load(target)["a"], np.arange(5))


def test_write_bytes_and_text(tmp_path):
    p = write_bytes(tmp_path / "a.bin", b"\x00\x01")
    assert p.read_bytes() == b"\x00\x01"
    with pytest.raises(FileExistsError):
        write_text(tmp_path / "a.bin", "x")
    assert p.read_bytes() == b"\x00\x01"
    write_text(tmp_path / "a.bin", "héllo", force=True)
    assert p.read_text(encoding="utf-8") == "héllo"


def test_write_json_keeps_order_and_converts_numpy(tmp_path):
    obj = {"zeta": np.float32(1.5), "alpha": np.int64(3), "arr": np.arange(3), "ok": np.bool_(True), "path": tmp_path}
    p = write_json(tmp_path / "stats.json", obj)
    text = p.read_text()
    assert text.endswith("\n") and '\n  "zeta": 1.5' in text  # indent 2
    back = json.loads(text)
    assert list(back) == ["zeta", "alpha", "arr", "ok", "path"]
    assert back == {"zeta": 1.5, "alpha": 3, "arr": [0, 1, 2], "ok": True, "path": str(tmp_path)}


@pytest.mark.parametrize("bad, where", [
    ({"a": {"b": [1.0, float("nan")]}}, r"\$\.a\.b\[1\]"),
    ({"ms": np.array([[1.0, 2.0], [np.inf, 0.0]])}, r"\$\.ms\[1, 0\]"),
    ({"x": np.float64("-inf")}, r"\$\.x"),
])
def test_write_json_refuses_non_finite(tmp_path, bad, where):
    target = tmp_path / "stats.json"
    with pytest.raises(ValueError, match=rf"stats\.json.*{where}"):
        write_json(target, bad)
    assert not target.exists() and _leftovers(tmp_path) == []
