"""Drawing in a second process: the renderer's kernels, trails and HUD run beside the simulation (issue 20).

Why a process and not a thread: Taichi 1.7 holds the GIL for the whole of a kernel launch and has one
launch slot per process (crowd_ik.io.pipeline), so in one process the simulation of frame k+1 waits for
frame k's raster kernel, and the second core idles through every small simulation kernel and every line
of Python. A child process has its own Taichi runtime: the main process simulates frame k+1 and assembles
its primitives while the child draws frame k.

Data path (no big array is pickled): `slots` shared-memory slots, each with room for one frame's
primitives (capsule ends, radii and colours, the scene's maximum counts; bullets as spheres) and for its
finished (H, W, 3) uint8 frame.
  main    take() a free slot, fill it with the frame's primitives, send (slot, counts, camera, trails,
          HUD lines) down a pipe
  child   view.render.Renderer.render on the slot's arrays into the slot's frame, answer (slot, timings)
  writer  (a thread of the main process) reads the answers in order, writes each frame into the sink,
          frees its slot
The child runs the same Renderer with the same kernels on the same float32 inputs, initialised with the
same arch, threads and precision, so every frame is the same bit for bit as the in-process renderer's.

Failures: an exception in the child (bad primitives, a failed start) comes back as a one-line message and
is raised in the main process at its next hand-over (ValueError for bad input, else RuntimeError); a child
that dies shows as the end of its pipe and is raised the same way. The child ignores SIGINT and SIGTERM:
on Ctrl-C the main process still has every frame it handed over drawn and written, then closes the pipe,
and the child exits when it reads the end of it.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
import threading
import time
from multiprocessing import shared_memory

import numpy as np

from crowd_ik.io.handover import Handover

DEFAULT_SLOTS = 4  # frames in flight: one being drawn, up to three waiting for or in the writer (io.pipeline too)
_START_TIMEOUT_S = 600.0  # the child's first answer (imports, Taichi start, kernel load or a cold compile)
_CAPSULE_FLOATS = 10  # a (3), b (3), radius, colour (3)
_SPHERE_FLOATS = 7  # centre (3), radius, colour (3)


class _Layout:
    """Where slot s's arrays lie in the shared block: float32 capsules (max_capsules, 10), spheres
    (max_spheres, 7), then the uint8 frame (H, W, 3), each slot 64-byte aligned."""

    def __init__(self, max_capsules: int, max_spheres: int, height: int, width: int, slots: int):
        self.max_capsules, self.max_spheres = max_capsules, max_spheres
        self.height, self.width, self.slots = height, width, slots
        self.caps_bytes = 4 * _CAPSULE_FLOATS * max(max_capsules, 1)
        self.sph_bytes = 4 * _SPHERE_FLOATS * max(max_spheres, 1)
        self.frame_bytes = 3 * height * width
        self.stride = -(-(self.caps_bytes + self.sph_bytes + self.frame_bytes) // 64) * 64
        self.size = self.stride * slots

    def views(self, buf, s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(capsules (C, 10) float32, spheres (S, 7) float32, frame (H, W, 3) uint8) of slot s."""
        base = s * self.stride
        caps = np.ndarray((max(self.max_capsules, 1), _CAPSULE_FLOATS), np.float32, buf, base)
        sph = np.ndarray((max(self.max_spheres, 1), _SPHERE_FLOATS), np.float32, buf, base + self.caps_bytes)
        frame = np.ndarray((self.height, self.width, 3), np.uint8, buf, base + self.caps_bytes + self.sph_bytes)
        return caps, sph, frame


def _serve(init_kwargs: dict, inbox, outbox) -> None:
    """The child: start Taichi and load the renderer's kernels, then draw each frame it is sent into its
    slot and answer in order; stop at None or at the end of the pipe."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        _draw_loop(init_kwargs, inbox, outbox)
    finally:
        outbox.send(("cpu", time.process_time()))
        outbox.close()


def _draw_loop(init_kwargs: dict, inbox, outbox) -> None:
    try:
        from crowd_ik import runtime
        from crowd_ik.view.render import Renderer, warm_kernels

        runtime.init(**init_kwargs)
        warm_kernels()  # while the main process builds its World
    except BaseException as exc:  # noqa: BLE001  (reported to the main process)
        outbox.send(("error", -1, type(exc).__name__, _one_line(exc)))
        return
    outbox.send(("ready",))
    msg = _next_message(inbox)
    if msg is None:
        return
    _, shm_name, layout, camera = msg
    shm = shared_memory.SharedMemory(name=shm_name)
    try:
        renderer = Renderer(camera, layout.max_capsules, layout.max_spheres)
        _draw_frames(renderer, [layout.views(shm.buf, s) for s in range(layout.slots)], inbox, outbox)
    except BaseException as exc:  # noqa: BLE001  (reported to the main process)
        outbox.send(("error", -1, type(exc).__name__, _one_line(exc)))
    finally:
        renderer = None
        try:
            shm.close()
        except BufferError:
            pass  # a view is still exported; the process ends here anyway


def _draw_frames(renderer, slots: list, inbox, outbox) -> None:
    while True:
        msg = _next_message(inbox)
        if msg is None:
            return
        s, m, k, camera, trails, hud_lines = msg
        caps, sph, frame = slots[s]
        try:
            renderer.camera = camera
            renderer.frame_source = lambda out=frame: out
            renderer.render(caps[:m, 0:3], caps[:m, 3:6], caps[:m, 6], caps[:m, 7:10],
                            sph[:k, 0:3], sph[:k, 3], sph[:k, 4:7], trails=trails, hud_lines=hud_lines)
            outbox.send(("done", s, renderer.timings["raster_ms"], renderer.timings["overlay_ms"]))
        except Exception as exc:  # noqa: BLE001  (reported to the main process)
            outbox.send(("error", s, type(exc).__name__, _one_line(exc)))
        finally:
            renderer.frame_source = None


def _next_message(inbox):
    """The main process's next message; None for its stop (None) or the end of the pipe."""
    try:
        return inbox.recv()
    except EOFError:
        return None


def _one_line(exc: BaseException) -> str:
    return " | ".join(str(exc).splitlines()) or type(exc).__name__


class RenderProcess(Handover):
    """A drawing child process and the writer thread that puts its frames into a sink, in order.

    RenderProcess() starts the child at once (imports, Taichi, the frame kernel loaded), so that it can get
    ready while the main process builds its World; open(sink, camera, max_capsules, max_spheres, slots)
    then allocates the shared slots and starts the writer. take() lends a free slot (waits while all are in
    flight); submit(slot, prim, camera, hud_lines) fills it with World.primitives()' capsules, spheres and
    trails and hands it to the child; close() waits until every frame handed over is written (drain) or
    drops the rest (drain=False), then stops the child (also without open()). Times (seconds): `raster_s`
    and `overlay_s` (the child's), `write_s` (the writer's), `wait_s` (the main thread waiting for a free
    slot); `child_cpu_s` the child's CPU time once closed.

    The child is started with multiprocessing's "spawn" (a fork would copy this process's Taichi runtime),
    so a script that uses it must guard its entry point with `if __name__ == "__main__":`.
    """

    def __init__(self):
        from crowd_ik import runtime

        super().__init__()
        ctx = multiprocessing.get_context("spawn")
        self._inbox_r, self._inbox = ctx.Pipe(duplex=False)
        self._outbox, self._outbox_w = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_serve, name="crowd-ik-render", daemon=True,
                                 args=(runtime.settings_for_child(), self._inbox_r, self._outbox_w))
        self._proc.start()
        self._inbox_r.close()
        self._outbox_w.close()
        self._shm = self._views = None
        self._sent = 0
        self._closed = False
        self.frames = 0
        self.raster_s = self.overlay_s = self.write_s = self.child_cpu_s = 0.0

    def open(self, sink, camera, max_capsules: int, max_spheres: int, slots: int = DEFAULT_SLOTS) -> RenderProcess:
        """Allocate `slots` shared slots for frames of camera's size and these maxima, and start writing into
        sink; returns self."""
        if isinstance(slots, bool) or not isinstance(slots, int) or slots < 2:
            raise ValueError(f"RenderProcess: slots: expected an integer >= 2 (got {slots!r})")
        if self._shm is not None:
            raise RuntimeError("RenderProcess: already open")
        self.sink = sink
        self.layout = _Layout(int(max_capsules), int(max_spheres), camera.height, camera.width, slots)
        self._shm = shared_memory.SharedMemory(create=True, size=self.layout.size)
        self._views = [self.layout.views(self._shm.buf, s) for s in range(slots)]
        for s in range(slots):
            self._free.put(s)
        try:
            self._inbox.send(("open", self._shm.name, self.layout, camera))
        except OSError:
            pass  # the child is gone: the writer reports it at the first hand-over
        self._thread = threading.Thread(target=self._run, name="crowd-ik-writer", daemon=True)
        self._thread.start()
        return self

    # ---------------------------------------------------------------- writer thread
    def _run(self) -> None:
        started = False
        while True:
            try:
                if self._outbox.poll(None if started else _START_TIMEOUT_S):
                    msg = self._outbox.recv()
                else:
                    msg = ("error", -1, "RuntimeError", f"the render process gave no sign in {_START_TIMEOUT_S:.0f} s")
            except (EOFError, OSError):
                if self._error is None and (self._sent > self.frames or not started):
                    self._error = RuntimeError("the render process stopped unexpectedly")
                self._release_all()
                return
            kind = msg[0]
            if kind == "ready":
                started = True
            elif kind == "cpu":
                self.child_cpu_s = msg[1]
            elif kind == "error":
                _, s, name, text = msg
                if self._error is None:
                    self._error = (ValueError if name == "ValueError" else RuntimeError)(text)
                if s >= 0:
                    self._free.put(s)
                else:
                    self._release_all()
                    return
            else:
                _, s, raster_ms, overlay_ms = msg
                self._write(s, raster_ms, overlay_ms)

    def _write(self, s: int, raster_ms: float, overlay_ms: float) -> None:
        try:
            if self._error is None and not self._discard.is_set():
                t0 = time.perf_counter()
                self.sink.write(self._views[s][2])
                self.write_s += time.perf_counter() - t0
                self.raster_s += 1e-3 * raster_ms
                self.overlay_s += 1e-3 * overlay_ms
                self.frames += 1
        except BaseException as exc:  # noqa: BLE001  (handed to the main thread)
            self._error = exc
        finally:
            self._free.put(s)

    def _release_all(self) -> None:
        for s in range(self.layout.slots):  # unblocks a waiting take(), which then raises the error
            self._free.put(s)

    # ---------------------------------------------------------------- main thread (take(): Handover)
    def submit(self, s: int, prim: dict, camera, hud_lines) -> None:
        """Hand slot s to the child: prim is World.primitives()' dict (capsules, spheres, trails)."""
        self._check()
        caps, sph = prim["capsules"], prim["spheres"]
        m, k = len(caps["radius"]), len(sph["radius"])
        if m > self.layout.max_capsules or k > self.layout.max_spheres:
            raise ValueError(f"RenderProcess: {m} capsules and {k} spheres exceed the maxima "
                             f"{self.layout.max_capsules} and {self.layout.max_spheres}")
        c, p, _ = self._views[s]
        c[:m, 0:3], c[:m, 3:6], c[:m, 6], c[:m, 7:10] = caps["a"], caps["b"], caps["radius"], caps["color"]
        p[:k, 0:3], p[:k, 3], p[:k, 4:7] = sph["center"], sph["radius"], sph["color"]
        trails = prim["trails"] if len(prim["trails"]) else None
        try:
            self._inbox.send((s, m, k, camera, trails, list(hud_lines) if hud_lines else None))
        except OSError:  # the child is gone: its pipe is closed
            self._check()
            raise RuntimeError("the render process stopped unexpectedly") from None
        self._sent += 1

    def close(self, drain: bool = True) -> None:
        """Stop after every frame handed over is written (drain) or at once (drain=False); raise the child's
        or writer's error, if any, when draining. An interrupt while draining drops the frames not yet written
        and is raised once the child has stopped."""
        if self._closed:
            return
        self._closed = True
        if not drain:
            self._discard.set()
        try:
            self._inbox.send(None)
        except OSError:
            pass  # the child is gone; the writer has seen it
        interrupted = self._join_writer()
        if self._thread is None:  # never opened: the child's last word is its CPU time
            while self._outbox.poll(10):
                try:
                    msg = self._outbox.recv()
                except (EOFError, OSError):
                    break
                if msg[0] == "cpu":
                    self.child_cpu_s = msg[1]
        self._inbox.close()
        self._outbox.close()
        self._proc.join(timeout=10)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        if self._shm is not None:
            self._views = None  # the slot views export the shared block: drop them before closing it
            self._shm.close()
            self._shm.unlink()
        if drain:
            self._check()
        if interrupted is not None:
            raise interrupted


__all__ = ["RenderProcess"]


@contextlib.contextmanager
def started_early(wanted: bool):
    """A RenderProcess started now, so that it gets ready while the caller builds its World (None when not
    wanted); on the way out it is closed without draining: render_video closes it when the video is done, so
    this only stops a child that something failed to hand over to."""
    proc = RenderProcess() if wanted else None
    try:
        yield proc
    finally:
        if proc is not None:
            proc.close(drain=False)
