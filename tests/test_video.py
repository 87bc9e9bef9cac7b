"""crowd_ik.io.video: .mp4 / .webm / PNG-folder sinks round-trip, never clobber, and finalise on Ctrl-C."""

from __future__ import annotations

import gc
import os
import struct
import subprocess

import cv2
import numpy as np
import pytest

from crowd_ik.io.video import FfmpegSink, PngFolderSink, ffmpeg_exe, open_sink, read_frames, read_video, write_png

W, H, N = 64, 48, 12


def _frames(n=N, w=W, h=H):
    """n flat frames of distinct colours (BGR), with a white top-left square to pin orientation."""
    out = []
    for i in range(n):
        f = np.empty((h, w, 3), np.uint8)
        f[:] = (20 * i % 256, 255 - 15 * i, (60 + 37 * i) % 256)
        f[:16, :16] = 255
        out.append(f)
    return out


def _write(path, frames, **kw):
    with open_sink(path, 24, (frames[0].shape[1], frames[0].shape[0]), **kw) as sink:
        for f in frames:
            sink.write(f)
    return sink


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name)


def _ffmpeg_info(path):
    res = subprocess.run([ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True, text=True)
    return next(line for line in res.stderr.splitlines() if "Video:" in line)


def _top_level_atoms(data: bytes) -> list[str]:
    atoms, pos = [], 0
    while pos + 8 <= len(data):
        size, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if size == 1:
            size = struct.unpack(">Q", data[pos + 8:pos + 16])[0]
        elif size == 0:
            size = len(data) - pos
        assert size >= 8, f"corrupt atom at {pos}"
        atoms.append(kind.decode("latin-1"))
        pos += size
    assert pos == len(data)
    return atoms


def _assert_colours(decoded, frames, tol):
    for got, want in zip(decoded, frames):
        body = (slice(24, None), slice(24, None))  # away from the white square and chroma bleed
        assert np.abs(got[body].astype(int).mean((0, 1)) - want[body].astype(int).mean((0, 1))).max() <= tol
        assert got[:12, :12].min() > 225  # the white square stays top-left: row 0 is the top


def test_mp4_round_trip_is_h264_yuv420p_faststart(tmp_path):
    path = tmp_path / "clip.mp4"
    frames = _frames()
    sink = _write(path, frames)
    assert sink.frames_written == N and path.is_file()
    assert read_video(path) == (N, H, W)
    _assert_colours(read_frames(path), frames, tol=8)
    info = _ffmpeg_info(path)
    assert "h264" in info and "yuv420p" in info and f"{W}x{H}" in info
    atoms = _top_level_atoms(path.read_bytes())
    assert atoms.index("moov") < atoms.index("mdat"), atoms
    assert _leftovers(tmp_path) == []


def test_webm_round_trip_is_vp8(tmp_path):
    path = tmp_path / "clip.webm"
    frames = _frames()
    _write(path, frames)
    assert read_video(path) == (N, H, W)
    _assert_colours(read_frames(path), frames, tol=12)
    assert "vp8" in _ffmpeg_info(path)
    assert _leftovers(tmp_path) == []


def test_ffmpeg_vp8_fallback_writes_webm(tmp_path):
    path = tmp_path / "clip.webm"
    frames = _frames(6)
    with FfmpegSink(path, 24, (W, H), codec="vp8") as sink:
        for f in frames:
            sink.write(f)
    assert read_video(path) == (6, H, W) and "vp8" in _ffmpeg_info(path)
    _assert_colours(read_frames(path), frames, tol=12)


def test_png_folder_round_trip_is_exact(tmp_path):
    folder = tmp_path / "frames"
    frames = _frames(5)
    sink = _write(str(folder) + "/", frames)
    assert isinstance(sink, PngFolderSink)
    assert sorted(os.listdir(folder)) == [f"frame_{i:05d}.png" for i in range(5)]
    for got, want in zip(read_frames(folder), frames):
        np.testing.assert_array_equal(got, want)
    assert read_video(folder) == (5, H, W) and _leftovers(tmp_path) == []


def test_png_folder_no_clobber_and_force_replaces_only_frames(tmp_path):
    folder = tmp_path / "frames"
    _write(f"{folder}/", _frames(4))
    with pytest.raises(FileExistsError):
        open_sink(folder, 24, (W, H))  # an existing folder is a PNG target even without "/"
    (folder / "notes.txt").write_text("keep me")
    new = _frames(2)[::-1]
    _write(f"{folder}/", new, force=True)
    assert sorted(os.listdir(folder)) == ["frame_00000.png", "frame_00001.png", "notes.txt"]
    np.testing.assert_array_equal(read_frames(folder)[0], new[0])
    assert (folder / "notes.txt").read_text() == "keep me" and _leftovers(tmp_path) == []


@pytest.mark.parametrize("name", ["clip.mp4", "clip.webm"])
def test_existing_video_is_not_clobbered_without_force(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="exists"):
        open_sink(path, 24, (W, H))
    assert path.read_bytes() == b"precious" and _leftovers(tmp_path) == []
    _write(path, _frames(3), force=True)
    assert read_video(path) == (3, H, W)


@pytest.mark.parametrize("name", ["clip.mp4", "clip.webm", "frames/"])
def test_exception_mid_write_leaves_old_output_and_no_temp(tmp_path, name):
    path = tmp_path / name
    old = _frames(2)
    _write(str(path) + ("/" if name.endswith("/") else ""), old)
    before = read_frames(path)
    with pytest.raises(ZeroDivisionError):
        with open_sink(str(path) + ("/" if name.endswith("/") else ""), 24, (W, H), force=True) as sink:
            for i, f in enumerate(_frames(6)[::-1]):
                sink.write(f)
                if i == 3:
                    1 / 0
    after = read_frames(path)
    assert len(after) == 2
    for a, b in zip(after, before):
        np.testing.assert_array_equal(a, b)
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("name", ["clip.mp4", "clip.webm", "frames/"])
def test_keyboard_interrupt_finalises_a_shorter_playable_video(tmp_path, name):
    path = tmp_path / name
    frames = _frames(10)
    with pytest.raises(KeyboardInterrupt):
        with open_sink(path if not name.endswith("/") else f"{path}/", 24, (W, H)) as sink:
            for i, f in enumerate(frames):
                if i == 4:
                    raise KeyboardInterrupt
                sink.write(f)
    assert sink.frames_written == 4
    assert read_video(path) == (4, H, W)
    _assert_colours(read_frames(path), frames[:4], tol=12)
    assert _leftovers(tmp_path) == []


def test_keyboard_interrupt_before_any_frame_leaves_nothing(tmp_path):
    path = tmp_path / "clip.mp4"
    with pytest.raises(KeyboardInterrupt):
        with open_sink(path, 24, (W, H)):
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_close_without_frames_and_abort_leave_nothing(tmp_path):
    sink = open_sink(tmp_path / "a.mp4", 24, (W, H))
    with pytest.raises(RuntimeError, match="no frames"):
        sink.close()
    sink = open_sink(tmp_path / "b.webm", 24, (W, H))
    sink.write(_frames(1)[0])
    sink.abort()
    with pytest.raises(RuntimeError, match="aborted"):
        sink.write(_frames(1)[0])
    assert list(tmp_path.iterdir()) == []


def test_unclosed_sink_is_cleaned_up_when_dropped(tmp_path):
    sink = open_sink(tmp_path / "a.mp4", 24, (W, H))
    sink.write(_frames(1)[0])
    proc = sink._proc
    del sink
    gc.collect()
    assert proc.poll() is not None and list(tmp_path.iterdir()) == []


def test_ffmpeg_runs_in_its_own_process_group(tmp_path):
    # A terminal Ctrl-C must reach only crowd-ik, which then finalises the video itself.
    with open_sink(tmp_path / "a.mp4", 24, (W, H)) as sink:
        assert os.getpgid(sink._proc.pid) != os.getpgid(0)
        sink.write(_frames(1)[0])


@pytest.mark.parametrize("size", [(63, 48), (64, 47), (14, 48), (64, 0), (64.0, 48), (True, 48), (64,)])
def test_bad_sizes_are_rejected(tmp_path, size):
    with pytest.raises(ValueError, match="size"):
        open_sink(tmp_path / "a.mp4", 24, size)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("fps", [0, -5, float("nan"), float("inf"), "fast"])
def test_bad_fps_is_rejected(tmp_path, fps):
    with pytest.raises(ValueError, match="fps"):
        open_sink(tmp_path / "a.webm", fps, (W, H))


def test_bad_frames_are_rejected(tmp_path):
    with open_sink(tmp_path / "a.mp4", 24, (W, H)) as sink:
        for bad in (np.zeros((W, H, 3), np.uint8), np.zeros((H, W, 3), np.float32),
                    np.zeros((H, W), np.uint8), np.zeros((H, W, 4), np.uint8), [[0]]):
            with pytest.raises(ValueError, match=r"expected \(48, 64, 3\) uint8"):
                sink.write(bad)
        sink.write(np.asfortranarray(_frames(1)[0]))  # any memory layout is accepted
    assert read_video(tmp_path / "a.mp4") == (1, H, W)


@pytest.mark.parametrize("name, match", [
    ("clip.avi", r"clip\.avi.*\.mp4.*\.webm"),
    ("clip", r"\(none\)"),
    ("still.png", r"--still"),
])
def test_bad_suffixes_are_rejected(tmp_path, name, match):
    with pytest.raises(ValueError, match=match):
        open_sink(tmp_path / name, 24, (W, H))
    assert list(tmp_path.iterdir()) == []


def test_write_png_round_trip_and_no_clobber(tmp_path):
    frame = _frames(3, w=33, h=17)[2]  # stills need not be even-sized
    path = write_png(tmp_path / "still.png", frame)
    np.testing.assert_array_equal(cv2.imread(str(path)), frame)
    with pytest.raises(FileExistsError):
        write_png(path, frame[::-1])
    np.testing.assert_array_equal(cv2.imread(str(path)), frame)
    write_png(path, np.ascontiguousarray(frame[::-1]), force=True)
    np.testing.assert_array_equal(cv2.imread(str(path)), frame[::-1])
    with pytest.raises(ValueError, match=r"\.png"):
        write_png(tmp_path / "still.jpg", frame)
    with pytest.raises(ValueError, match="uint8"):
        write_png(tmp_path / "f.png", frame.astype(np.float32))
    assert sorted(os.listdir(tmp_path)) == ["still.png"]


def test_read_video_refuses_missing_and_garbage(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_video(tmp_path / "none.mp4")
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all")
    with pytest.raises(ValueError, match="junk"):
        read_video(tmp_path / "junk.mp4")


def test_real_ctrl_c_on_the_process_group_finalises_the_video(tmp_path):
    # Like a terminal's Ctrl-C: SIGINT to the whole foreground group, ffmpeg included if it were there.
    import signal
    import sys

    script = (
        "import signal, sys, numpy as np\n"
        # a pytest started with SIGINT ignored (a background job, nohup) passes that on to its children
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "from crowd_ik.io.video import open_sink\n"
        f"with open_sink(sys.argv[1], 24, ({W}, {H})) as sink:\n"
        "    i = 0\n"
        "    while True:\n"
        f"        sink.write(np.full(({H}, {W}, 3), i % 256, np.uint8))\n"
        "        i += 1\n"
        "        if i == 5:\n"
        "            print('ready', flush=True)\n"
    )
    path = tmp_path / "clip.mp4"
    proc = subprocess.Popen([sys.executable, "-c", script, str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, process_group=0)
    try:
        assert proc.stdout.readline().strip() == "ready"
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode in (-signal.SIGINT, 130, 1) and "KeyboardInterrupt" in err, err
    n, h, w = read_video(path)
    assert n >= 5 and (h, w) == (H, W)
    assert _leftovers(tmp_path) == []
