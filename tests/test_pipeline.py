"""The video pipeline (crowd_ik.io.pipeline): frames in order, none dropped, each the same bit for bit as
the serial path's (at 1 and 2 Taichi threads), a writer failure raised on the main thread, and an
interrupt that writes every frame handed over before the sink finalises the shorter video."""

import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from crowd_ik.io.pipeline import FrameWriter, render_video
from crowd_ik.io.video import Sink, read_frames

# Bullets fly from the first frames (trails), the player walks (HUD changes), the camera follows.
SCENE = """
seed = 5
characters = { count = 6, spacing = 1.5 }
shooters = { count = 2, fire_rate = 6.0, radius = 6.0 }
bullets = { pool_size = 256 }
time = { floor = 0.6 }
camera = { position = [0, 3, 6], look_at = [0, 1, 0], fov_deg = 55 }
video = { width = 160, height = 96, fps = 24, frames = 18 }
"""


class ListSink(Sink):
    """Keeps a copy of every frame written; `delay` seconds per write (a slow encoder);
    `fail_at`: raise an OSError when writing that frame."""

    def __init__(self, size=(160, 96), delay=0.0, fail_at=None):
        super().__init__(Path("memory"), 24, size, force=True)
        self.frames, self.delay, self.fail_at = [], delay, fail_at
        self.writer_threads = set()

    def _write(self, frame):
        self.writer_threads.add(threading.current_thread().name)
        if self.fail_at is not None and len(self.frames) == self.fail_at:
            raise OSError(28, "No space left on device", "memory")
        time.sleep(self.delay)
        self.frames.append(frame.copy())

    def _finish(self):
        pass

    def _discard(self):
        pass


@pytest.fixture
def scene(tmp_path):
    from crowd_ik.scene import load_scene

    path = tmp_path / "pipe.toml"
    path.write_text(SCENE)
    return load_scene(path)


def _classic(scene) -> list[np.ndarray]:
    """The frames of the loop play had before the pipeline: step, render, write, one after another."""
    from crowd_ik.game.world import World
    from crowd_ik.session import frames

    world = World(scene)
    return [world.render() for _ in frames(world, scene.n_frames)]


def _run(scene, serial, sink=None, slots=4, overlay_on_writer=False):
    from crowd_ik.game.world import World
    from crowd_ik.session import frames

    world = World(scene)
    sink = sink or ListSink()
    stats = render_video(world, frames(world, scene.n_frames), sink, serial=serial, slots=slots,
                         overlay_on_writer=overlay_on_writer)
    return sink, stats, world


@pytest.mark.parametrize("slots, on_writer", [(2, False), (4, False), (3, True)])
def test_pipelined_frames_are_the_serial_frames_bit_for_bit(scene, slots, on_writer):
    classic = _classic(scene)
    pipe, stats, world = _run(scene, serial=False, slots=slots, overlay_on_writer=on_writer)
    serial, _, _ = _run(scene, serial=True)
    assert world.stats["shots"] > 0 and world.stats["bullets"] > 0  # the frames have trails to defer
    assert len(pipe.frames) == len(serial.frames) == len(classic) == scene.n_frames
    for k, (a, b, c) in enumerate(zip(pipe.frames, serial.frames, classic)):
        assert np.array_equal(a, c), f"pipelined frame {k} differs"
        assert np.array_equal(b, c), f"serial frame {k} differs"
    assert pipe.writer_threads == {"crowd-ik-writer"} and serial.writer_threads == {threading.main_thread().name}
    assert stats["frames"] == scene.n_frames and stats["mode"] == "pipelined" and pipe._state == "closed"
    assert set(stats["stages_ms"]) == {"simulate", "draw", "primitives", "raster", "overlay", "write", "wait"}
    assert all(v >= 0.0 for v in stats["stages_ms"].values()) and stats["cpu_percent"] > 0.0
    renderer = world.renderer
    assert renderer.frame_source is None and not renderer.defer_overlay  # handed back for World.render()
    assert np.array_equal(world.render(), classic[-1])  # the renderer draws the same frame again after it


@pytest.mark.parametrize("on_writer", [False, True])
def test_a_slow_writer_is_waited_for_once_in_the_stages(scene, on_writer):
    """With a slow sink the main thread waits for free buffers inside the renderer's raster step (its frame_source
    is the writer's take): the wait counts once, so the draw (its wait and overlay painting taken out) still
    splits into primitives + raster, none negative."""
    sink = ListSink(delay=0.05)
    _, stats, _ = _run(scene, serial=False, sink=sink, slots=2, overlay_on_writer=on_writer)
    st = stats["stages_ms"]
    assert st["wait"] > 5.0  # most of each 50 ms write is waited for
    assert min(st.values()) >= 0.0
    assert st["draw"] == pytest.approx(st["primitives"] + st["raster"], abs=1e-9)


def test_frames_keep_their_order_and_none_is_dropped_or_overwritten():
    # two slots and a slow sink: the main thread must wait for a buffer instead of reusing one in flight
    sink = ListSink(size=(32, 16), delay=0.004)
    writer = FrameWriter(sink, (16, 32, 3), slots=2)
    seen = set()
    for k in range(40):
        buf = writer.take()
        seen.add(id(buf))
        buf[...] = k
        writer.submit(buf)
    writer.close()
    assert [int(f[0, 0, 0]) for f in sink.frames] == list(range(40))
    assert all(np.all(f == f[0, 0, 0]) for f in sink.frames)
    assert len(seen) == 2 and writer.wait_s > 0.0 and writer.frames == 40


def test_a_writer_failure_is_raised_on_the_main_thread_and_discards_the_sink(scene):
    sink = ListSink(fail_at=3)
    with pytest.raises(OSError, match="No space left"):
        _run(scene, serial=False, sink=sink)
    assert sink._state == "aborted" and len(sink.frames) == 3


def test_an_interrupt_writes_every_frame_handed_over_then_finalises(scene):
    from crowd_ik.game.world import World
    from crowd_ik.session import frames

    world = World(scene)
    sink = ListSink(delay=0.03)  # the writer lags: frames are queued when the interrupt comes
    handed = []

    def steps():
        for k in frames(world, scene.n_frames):
            if k == 7:
                raise KeyboardInterrupt
            yield k

    with pytest.raises(KeyboardInterrupt):
        render_video(world, steps(), sink, after=handed.append)
    assert handed == list(range(7))
    assert sink._state == "closed" and sink.frames_written == len(sink.frames) == 7
    classic = _classic(scene)
    assert all(np.array_equal(a, b) for a, b in zip(sink.frames, classic))


def test_frame_writer_refuses_fewer_than_two_slots():
    with pytest.raises(ValueError, match="slots"):
        FrameWriter(ListSink(), (96, 160, 3), slots=1)


@pytest.mark.parametrize("threads", [1, 2])
def test_play_writes_the_serial_frames_at_one_and_two_threads(scene, tmp_path, threads):
    out = tmp_path / f"t{threads}/"
    scene_file = tmp_path / "pipe.toml"
    run = subprocess.run([sys.executable, "-m", "crowd_ik.commands.cli", "play", str(scene_file), "-o", f"{out}/",
                          "--threads", str(threads), "--stats", str(tmp_path / f"s{threads}.json")],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-800:]
    got = read_frames(out)
    classic = _classic(scene)
    assert len(got) == len(classic) and all(np.array_equal(a, b) for a, b in zip(got, classic))
    import json

    stats = json.loads((tmp_path / f"s{threads}.json").read_text())
    assert stats["threads"] == threads and stats["pipeline"]["mode"] == "pipelined"
    assert stats["pipeline"]["frames"] == scene.n_frames


def test_an_interrupt_while_draining_stops_the_writer_and_is_raised():
    import signal

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    sink = ListSink(size=(32, 16), delay=0.03)
    writer = FrameWriter(sink, (16, 32, 3), slots=12)
    for k in range(12):
        buf = writer.take()
        buf[...] = k
        writer.submit(buf)
    previous = signal.signal(signal.SIGALRM, interrupt)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.1)
        with pytest.raises(KeyboardInterrupt):
            writer.close()  # the end of a video: Ctrl-C while the queue drains is not swallowed
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    assert not writer._thread.is_alive()  # nobody writes into the sink while it is being finalised
    assert 1 <= len(sink.frames) < 12 and [int(f[0, 0, 0]) for f in sink.frames] == list(range(len(sink.frames)))


def test_bench_render_workload_records_compare_and_targets():
    from crowd_ik.bench.render import compare_render, format_render, render_scene, render_targets

    rec = dict(render_scene("duel", (160, 96), 4), goal_fps=30.0, arch="cpu")
    assert rec["scene"] == "duel" and rec["size"] == [160, 96] and rec["frames"] == 4 and rec["bytes"] > 0
    assert rec["fps"] > 0 and rec["mode"] == "pipelined" and set(rec["stages_ms"]) >= {"simulate", "draw", "write"}
    assert "render cpu duel 160x96" in format_render([rec], "cpu")[0]
    slow = dict(rec, fps=rec["fps"] / 2)
    lines = compare_render({"render": [slow]}, {"render": [rec]})
    assert len(lines) == 1 and "+100.0%" in lines[0]
    assert compare_render({"records": []}, {"render": [rec]}) == []  # an older JSON without renders
    [target] = render_targets([dict(rec, fps=31.0)], "cpu")
    assert target["met"] and target["unit"] == "per_s" and target["value"] == 31.0
    assert not render_targets([dict(rec, fps=29.0)], "cpu")[0]["met"]
