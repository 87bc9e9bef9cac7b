"""The main thread's side of handing frames to a writer thread (io.pipeline.FrameWriter and
io.render_process.RenderProcess): a ring of free slots lent by take(), the writer's error raised at the next
hand-over, and a join of the writer that an interrupt cannot cut short."""

from __future__ import annotations

import queue
import threading
import time

POLL_S = 0.05  # how often a blocked take() checks whether the writer has failed


class Handover:
    """State shared by the main thread and the writer: `_free` (the slots not in flight), `_error` (the
    writer's, raised on the main thread), `_discard` (set: drop what is still queued), `_thread` (the writer),
    `wait_s` (seconds the main thread waited in take())."""

    def __init__(self):
        self._free: queue.Queue = queue.Queue()
        self._error: BaseException | None = None
        self._discard = threading.Event()
        self._thread: threading.Thread | None = None
        self.wait_s = 0.0

    def _check(self) -> None:
        if self._error is not None:
            raise self._error

    def take(self):
        """A free slot (waits while every slot is in flight); raises the writer's error."""
        t0 = time.perf_counter()
        try:
            while True:
                self._check()
                try:
                    slot = self._free.get(timeout=POLL_S)
                except queue.Empty:
                    continue
                self._check()  # a failing writer hands its slots back to unblock this wait
                return slot
        finally:
            self.wait_s += time.perf_counter() - t0

    def _join_writer(self) -> KeyboardInterrupt | None:
        """Wait for the writer thread to end; an interrupt meanwhile sets `_discard` (the writer drops what
        is left) and is returned, to be raised once the writer has stopped."""
        interrupted = None
        while self._thread is not None and self._thread.is_alive():
            try:
                self._thread.join()
            except KeyboardInterrupt as exc:
                self._discard.set()
                interrupted = exc
        return interrupted


__all__ = ["Handover", "POLL_S"]
