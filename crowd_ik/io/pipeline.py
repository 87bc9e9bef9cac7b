"""The video pipeline: simulate on the main thread, draw there or in a drawing process, while a writer thread
feeds the sink and the encoder works in its own process, so that the next frame is simulated while this one
is drawn and encoded (issue 20).

Stages of a frame and where they run:
  simulate  World.step (game logic, IK, bullets)                          main thread, Taichi + NumPy
  draw      World.primitives and the HUD lines                            main thread, NumPy
            raster kernels, trails and HUD, copy (Renderer.render)       the drawing process
                                                                          (io.render_process), or the
                                                                          main thread (render_process=False)
  write     the frame into the sink (a pipe into ffmpeg, VP8, PNG encoding) writer thread
  encode    x264 / libvpx                                                  the encoder's own process
What follows is about the in-process path. Every Taichi launch of a process stays on its main thread: Taichi's CPU runtime has one thread pool with one task
slot, so kernels cannot be launched from two threads at once (and its kernels already use every core).
Taichi 1.7 also holds the GIL for the whole of a kernel launch (measured: a Python thread got about 5 %
of its time while a 0.4 s kernel ran), so a second Python thread only runs while the main thread is
in Python code or in a call that releases the GIL. The writer is therefore kept to one call per frame
that releases the GIL for all its work (os.write into ffmpeg's pipe, cv2.imencode, VideoWriter.write)
and is otherwise idle; painting trails and HUD there (`overlay_on_writer=True`, view.overlay.Overlay:
planned from the frame's depth buffer on the main thread, painted later) costs some thirty GIL
hand-overs a frame and measured no faster, so by default they are painted on the main thread.

Frames go through a fixed ring of `slots` preallocated buffers: the renderer copies each frame into
a free slot (Renderer.frame_source), the writer gives it back once written; when all are in flight
the main thread waits (back-pressure: at most `slots` frames are ever held). Frames are written in
the order they were drawn, none is dropped, and each is the same bit for bit as the serial path's
(the same kernels and the same overlay operations on the same pixels; only where the frame waits changes).

Interrupts (Ctrl-C, or SIGTERM raised as one by the CLI) reach only the main thread: the frames
already handed over are still written, the writer is joined, and only then does the sink finalise
the shorter video. A failure in the writer (a full disk) is raised on the main thread at its next
hand-over, and the sink is discarded as before.

:func:`render_video` runs a whole video (serially with `serial=True`, for comparison) and returns
its per-stage times and CPU use, which `play --stats` reports.
"""

from __future__ import annotations

import os
import queue
import resource
import threading
import time

import numpy as np

from crowd_ik.io.handover import Handover
from crowd_ik.io.render_process import DEFAULT_SLOTS, RenderProcess

PROCESS_MIN_PIXELS = 640 * 360  # render_process=None: frames at least this big are drawn in a second process
PROCESS_MIN_FRAMES = 60  # ... in a video at least this long
PROCESS_START_S = 2.0  # about what the drawing process takes to start on the 2-core machine (warm cache)


class FrameWriter(Handover):
    """A writer thread that writes frames to `sink` in order (painting each one's overlay first, if given).

    take() lends a free (H, W, 3) uint8 buffer of the ring; submit(frame, overlay) queues it (the
    buffer returns to the ring once written); close() waits for the queue to empty. Times (seconds)
    are kept in `overlay_s`, `write_s`, `cpu_s` (the writer thread's CPU) and `wait_s` (the main
    thread waiting for a free buffer).
    """

    def __init__(self, sink, shape: tuple[int, int, int], slots: int = DEFAULT_SLOTS):
        if isinstance(slots, bool) or not isinstance(slots, int) or slots < 2:
            raise ValueError(f"FrameWriter: slots: expected an integer >= 2 (got {slots!r})")
        super().__init__()
        self.sink = sink
        for _ in range(slots):
            self._free.put(np.empty(shape, np.uint8))
        self._todo: queue.Queue = queue.Queue()
        self.frames = 0
        self.overlay_s = self.write_s = self.cpu_s = 0.0
        self._thread = threading.Thread(target=self._run, name="crowd-ik-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        cpu0 = time.thread_time()
        while True:
            item = self._todo.get()
            if item is None:
                break
            frame, overlay = item
            try:
                if self._error is None and not self._discard.is_set():
                    t0 = time.perf_counter()
                    if overlay is not None:
                        overlay.paint(frame)
                    t1 = time.perf_counter()
                    self.sink.write(frame)
                    self.overlay_s += t1 - t0
                    self.write_s += time.perf_counter() - t1
                    self.frames += 1
            except BaseException as exc:  # noqa: BLE001  (handed to the main thread)
                self._error = exc
            finally:
                self._free.put(frame)
        self.cpu_s = time.thread_time() - cpu0

    def submit(self, frame: np.ndarray, overlay=None) -> None:
        """Queue a buffer from take(), to be painted with `overlay` (view.overlay.Overlay or None) and written."""
        self._check()
        self._todo.put((frame, overlay))

    def close(self, drain: bool = True) -> None:
        """Stop the writer once it has written what is queued (drain) or right away (drain=False);
        raise the writer's error, if any, unless one is already being raised (drain=False).

        An interrupt while draining drops the frames not yet written, waits for the thread (it never
        keeps writing into a sink being finalised) and is raised then."""
        if not drain:
            self._discard.set()
        self._todo.put(None)
        interrupted = self._join_writer()
        if drain:
            self._check()
        if interrupted is not None:
            raise interrupted


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def wants_render_process(scene) -> bool:
    """The automatic choice for `scene`: draw in a second process (io.render_process) when its video is big
    enough to repay the process's start (imports, Taichi, the frame kernel: about PROCESS_START_S of CPU).
    The environment variable CROWD_IK_RENDER_PROCESS=1 or 0 overrides it (for timing one against the other)."""
    forced = os.environ.get("CROWD_IK_RENDER_PROCESS", "").strip()
    if forced in ("0", "1"):
        return forced == "1"
    video = scene.video
    return video.width * video.height >= PROCESS_MIN_PIXELS and scene.n_frames >= PROCESS_MIN_FRAMES


def render_video(world, steps, sink, *, serial: bool = False, slots: int = DEFAULT_SLOTS,
                 before=None, after=None, overlay_on_writer: bool = False,
                 render_process=None) -> dict:
    """Draw every frame `steps` yields (session.frames: it steps `world` and yields k) into `sink`,
    which is closed at the end (finalised on Ctrl-C / SIGTERM, discarded on any other error, as the
    sink's context manager does). before(k) runs before frame k is drawn, after(k) after (main
    thread: clip recording, labels, progress). serial=True draws, paints and writes one frame after
    another on the main thread (the path before the pipeline; the same frames). overlay_on_writer=True
    paints trails and HUD on the writer thread instead of the main thread (the same frames; see the
    module docstring for why that is not the default). render_process=True draws every frame in a second
    process (io.render_process: the same frames; the simulation runs meanwhile), and so does a
    RenderProcess started earlier (play starts it before building the World, to overlap their starts); False
    draws on the main thread, None (default) as wants_render_process(world.scene) decides; serial=True
    draws on the main thread whatever it says (and closes a RenderProcess given).

    Returns the run's numbers: frames, wall_s, fps, mean milliseconds per frame of each stage
    (stages_ms: simulate, draw = primitives (World.primitives and the HUD lines, main thread) + raster
    (the renderer's kernels and copy, on the main thread or in the drawing process), overlay, write, wait -
    the main thread waiting for a free buffer), cpu_s (this process, all threads), render_cpu_s (the drawing
    process), encoder_cpu_s (the other child processes reaped meanwhile: ffmpeg), writer_cpu_s,
    cpu_percent ((cpu_s + render_cpu_s + encoder_cpu_s) / wall_s) and the mode ("serial", "pipelined",
    "render process").
    """
    if render_process is None:
        render_process = wants_render_process(world.scene)
    started = render_process if isinstance(render_process, RenderProcess) else None
    if started is not None and serial:
        started.close(drain=False)
    remote = bool(render_process) and not serial
    renderer = None if remote else world.renderer
    t_start, cpu_start, child_start = time.perf_counter(), time.process_time(), _children_cpu()
    simulate = draw = raster_s = overlay_s = write_s = 0.0
    count = 0
    writer = None
    with sink:
        if remote:
            writer = (started or RenderProcess()).open(sink, world.camera, world.max_capsules,
                                                        world.scene.bullets.pool_size, slots)
        elif not serial:
            writer = FrameWriter(sink, (world.scene.video.height, world.scene.video.width, 3), slots)
            renderer.frame_source, renderer.defer_overlay = writer.take, overlay_on_writer
        try:
            it = iter(steps)
            while True:
                t0 = time.perf_counter()
                k = next(it, None)
                if k is None:
                    break
                t1 = time.perf_counter()
                simulate += t1 - t0
                if before is not None:
                    before(k)
                t2 = time.perf_counter()
                if remote:
                    slot = writer.take()
                    t_slot = time.perf_counter()
                    writer.submit(slot, world.primitives(), world.camera, world.hud_lines())
                    world.record_render(1e3 * (time.perf_counter() - t_slot))
                else:
                    frame = world.render()
                    raster_s += 1e-3 * renderer.timings["raster_ms"]
                t3 = time.perf_counter()
                draw += t3 - t2
                if not remote and (writer is None or not overlay_on_writer):
                    overlay_s += 1e-3 * renderer.timings["overlay_ms"]  # painted inside World.render
                if writer is None:
                    sink.write(frame)
                    write_s += time.perf_counter() - t3
                elif not remote:
                    writer.submit(frame, renderer.overlay if overlay_on_writer else None)
                count += 1
                if after is not None:
                    after(k)
        except KeyboardInterrupt:
            if writer is not None:
                try:
                    writer.close(drain=True)  # every frame handed over is written before the sink finalises
                except KeyboardInterrupt:
                    pass  # asked again while draining: the first interrupt stays the one reported
            raise
        except BaseException:
            if writer is not None:
                writer.close(drain=False)
            raise
        else:
            if writer is not None:
                writer.close(drain=True)
        finally:
            if renderer is not None:
                renderer.frame_source, renderer.defer_overlay, renderer.overlay = None, False, None
    wall = time.perf_counter() - t_start
    cpu = time.process_time() - cpu_start
    render_cpu = writer.child_cpu_s if remote else 0.0
    encoder = max(_children_cpu() - child_start - render_cpu, 0.0)
    n = max(count, 1)
    wait = 0.0
    if writer is not None:
        write_s, wait = writer.write_s, writer.wait_s
        draw -= wait  # the main thread waited inside draw for a free buffer
        if not remote:
            raster_s -= wait  # ... inside the renderer's raster time (its frame_source is writer.take)
    if remote:
        raster_s, overlay_s = writer.raster_s, writer.overlay_s
        primitives = draw
        draw += raster_s
    else:
        if writer is not None and overlay_on_writer:
            overlay_s = writer.overlay_s
        else:
            draw -= overlay_s  # renderer.render painted the overlay inside draw
        primitives = draw - raster_s
    return {
        "mode": "render process" if remote else "serial" if serial else "pipelined",
        "frames": count,
        "wall_s": wall,
        "fps": count / wall if wall > 0 else 0.0,
        "stages_ms": {"simulate": 1e3 * simulate / n, "draw": 1e3 * draw / n, "primitives": 1e3 * primitives / n,
                      "raster": 1e3 * raster_s / n, "overlay": 1e3 * overlay_s / n,
                      "write": 1e3 * write_s / n, "wait": 1e3 * wait / n},
        "cpu_s": cpu,
        "render_cpu_s": render_cpu,
        "encoder_cpu_s": encoder,
        "writer_cpu_s": writer.cpu_s if writer is not None and not remote else 0.0,
        "cpu_percent": 100.0 * (cpu + render_cpu + encoder) / wall if wall > 0 else 0.0,
    }


__all__ = ["DEFAULT_SLOTS", "FrameWriter", "render_video", "wants_render_process"]
