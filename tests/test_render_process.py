"""Drawing in a second process (crowd_ik.io.render_process): the same frames bit for bit as the in-process
renderer, in order and none dropped; a bad frame or a dead child raised in the main process; an interrupt
that writes every frame handed over; the automatic choice and its override."""

import dataclasses
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from crowd_ik.io.pipeline import render_video, wants_render_process
from crowd_ik.io.render_process import RenderProcess
from crowd_ik.io.video import read_frames

from test_pipeline import SCENE, ListSink, _classic


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from crowd_ik.scene import load_scene

    path = tmp_path_factory.mktemp("rp") / "pipe.toml"
    path.write_text(SCENE)
    return load_scene(path)


@pytest.fixture(scope="module")
def classic(scene):
    return _classic(scene)


def _world(scene):
    from crowd_ik.game.world import World
    from crowd_ik.session import frames

    world = World(scene)
    return world, frames(world, scene.n_frames)


def test_frames_drawn_in_the_render_process_are_the_in_process_frames_bit_for_bit(scene, classic):
    world, steps = _world(scene)
    sink = ListSink()
    stats = render_video(world, steps, sink, render_process=True, slots=3)
    assert world.stats["shots"] > 0 and world.stats["bullets"] > 0  # trails and a changing HUD are in the frames
    assert len(sink.frames) == len(classic) == scene.n_frames
    for k, (a, b) in enumerate(zip(sink.frames, classic)):
        assert np.array_equal(a, b), f"frame {k} differs"
    assert sink.writer_threads == {"crowd-ik-writer"} and sink._state == "closed"
    assert stats["mode"] == "render process" and stats["frames"] == scene.n_frames
    assert set(stats["stages_ms"]) == {"simulate", "draw", "primitives", "raster", "overlay", "write", "wait"}
    assert stats["stages_ms"]["raster"] > 0.0 and stats["render_cpu_s"] > 0.0
    assert world._renderer is None  # the main process never built a renderer
    assert world.totals["rendered"] == scene.n_frames


def test_a_bad_frame_in_the_child_is_raised_in_the_main_process_and_discards_the_sink(scene):
    world, steps = _world(scene)
    primitives = world.primitives

    def broken():
        prim = primitives()
        if world.frame >= 4:
            prim["capsules"]["a"][0, 1] = np.nan  # the renderer refuses it (in the child)
        return prim

    world.primitives = broken
    sink = ListSink()
    with pytest.raises(ValueError, match="capsules_a"):
        render_video(world, steps, sink, render_process=True)
    assert sink._state == "aborted" and 1 <= len(sink.frames) <= 4


def test_a_render_process_that_dies_is_an_error_not_a_hang(scene):
    world, steps = _world(scene)
    sink = ListSink(size=(160, 96))
    rp = RenderProcess().open(sink, world.camera, world.max_capsules, scene.bullets.pool_size, slots=2)
    try:
        next(steps)
        slot = rp.take()
        rp.submit(slot, world.primitives(), world.camera, world.hud_lines())
        os.kill(rp._proc.pid, signal.SIGKILL)
        with pytest.raises(RuntimeError, match="render process stopped"):
            for _ in range(4):  # the free slots run out, or the writer reports the end of the pipe first
                next(steps)
                slot = rp.take()
                rp.submit(slot, world.primitives(), world.camera, world.hud_lines())
    finally:
        rp.close(drain=False)
    assert not rp._thread.is_alive() and not rp._proc.is_alive()


def test_an_interrupt_writes_every_frame_handed_to_the_render_process(scene, classic):
    world, steps = _world(scene)
    sink = ListSink(delay=0.02)
    handed = []

    def interrupted():
        for k in steps:
            if k == 6:
                raise KeyboardInterrupt
            yield k

    with pytest.raises(KeyboardInterrupt):
        render_video(world, interrupted(), sink, after=handed.append, render_process=True)
    assert handed == list(range(6))
    assert sink._state == "closed" and len(sink.frames) == 6
    assert all(np.array_equal(a, b) for a, b in zip(sink.frames, classic))


def test_the_automatic_choice_and_its_override(scene, monkeypatch):
    monkeypatch.delenv("CROWD_IK_RENDER_PROCESS", raising=False)
    assert not wants_render_process(scene)  # 160x96: drawing it in-process is cheaper than starting a process
    video = dataclasses.replace(scene.video, width=1280, height=720, frames=300)
    big = dataclasses.replace(scene, video=video)
    assert wants_render_process(big)
    assert not wants_render_process(dataclasses.replace(big, video=dataclasses.replace(video, frames=20)))
    monkeypatch.setenv("CROWD_IK_RENDER_PROCESS", "0")
    assert not wants_render_process(big)
    monkeypatch.setenv("CROWD_IK_RENDER_PROCESS", "1")
    assert wants_render_process(scene)


def test_a_render_process_refuses_bad_slots_and_closes_without_opening(scene):
    from crowd_ik.game.world import World

    rp = RenderProcess()
    with pytest.raises(ValueError, match="slots"):
        rp.open(ListSink(), World(scene).camera, 10, 10, slots=1)
    rp.close()
    rp.close()  # twice is harmless
    assert not rp._proc.is_alive() and rp.child_cpu_s > 0.0  # it had started Taichi and loaded its kernels


def test_play_through_the_render_process_writes_the_in_process_frames(scene, classic, tmp_path):
    scene_file = tmp_path / "pipe.toml"
    scene_file.write_text(SCENE)
    out = tmp_path / "frames/"
    env = dict(os.environ, CROWD_IK_RENDER_PROCESS="1")
    run = subprocess.run([sys.executable, "-m", "crowd_ik.commands.cli", "play", str(scene_file), "-o", f"{out}/",
                          "--threads", "1"], capture_output=True, text=True, timeout=600, env=env)
    assert run.returncode == 0, run.stderr[-800:]
    assert "(render process)" in run.stdout
    got = read_frames(out)
    assert len(got) == len(classic) and all(np.array_equal(a, b) for a, b in zip(got, classic))


def test_play_draws_in_process_when_labels_read_the_z_buffer(scene, monkeypatch):
    from argparse import Namespace

    from crowd_ik.commands.play import _draws_in_process
    from crowd_ik.io.render_process import started_early

    monkeypatch.setenv("CROWD_IK_RENDER_PROCESS", "1")
    base = dict(still=None, serial=False, labels=None)
    for change in ({"labels": "l.jsonl"}, {"serial": True}, {"still": 3}):
        assert _draws_in_process(Namespace(**{**base, **change}), scene) is False
    assert _draws_in_process(Namespace(**base), scene) is True
    with started_early(False) as none:
        assert none is None
    with started_early(True) as rp:
        assert isinstance(rp, RenderProcess)
    assert rp._closed and not rp._proc.is_alive()  # closed on the way out, the child gone
