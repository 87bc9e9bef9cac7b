"""The OpenCV `.webm` (VP8) sink, checked frame by frame and by the frames it wrote, and the PNG-folder sink."""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
import weakref
from pathlib import Path

import cv2
import numpy as np

from crowd_ik.io.output import (
    check_writable,
    check_writable_dir,
    named_os_error,
    remove_folders,
)
from crowd_ik.io.sink import (
    _FRAME_NAME,
    _FRAME_RE,
    Sink,
    _make_output,
    _publish,
    _remove,
    _silent_failure,
)


@contextlib.contextmanager
def _captured_stderr(keep=lambda line: False):
    """Capture what C code prints on fd 2 (OpenCV's and FFmpeg's own messages) meanwhile; the lines for
    which `keep` is true are printed afterwards, the others dropped. Yields a list that holds the
    captured lines once the block has ended."""
    lines: list[str] = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        yield lines
        return
    with tempfile.TemporaryFile() as log:
        os.dup2(log.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            log.seek(0)
            lines += [ln for ln in log.read().decode("utf-8", "replace").splitlines() if ln.strip()]
            for line in lines:
                if keep(line):
                    print(line, file=sys.stderr)


def _quiet_opencv_tag_warning():
    """Hide OpenCV's harmless "tag 'VP80' is not supported ... webm" line (printed by C code on fd 2)."""
    return _captured_stderr(keep=lambda line: "is not supported with codec id" not in line)


@contextlib.contextmanager
def _opencv_silent():
    """OpenCV's log level at silent meanwhile: a failing VideoWriter.write reports through its return
    value (turned into our error), not through "Failed to write frame" warnings on stderr."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is None:
        yield
        return
    level = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        log.setLogLevel(level)


def _frame_count(path: Path) -> int:
    """Frames of a finished video by its container's duration (cheap: no decoding); -1 if unreadable."""
    with _captured_stderr(), _opencv_silent():
        cap = cv2.VideoCapture(str(path))
        try:
            n = cap.get(cv2.CAP_PROP_FRAME_COUNT) if cap.isOpened() else -1.0
        finally:
            cap.release()
    return int(round(n)) if math.isfinite(n) and 0 <= n < 2**62 else -1


class OpenCVSink(Sink):
    """VP8 .webm through OpenCV's VideoWriter. Raises RuntimeError if the build cannot write it.

    VideoWriter reports a failed write (a full disk) only through write()'s return value and a warning;
    the sink turns a False into an OSError naming the file, and checks after release that the file
    holds every frame written (its duration), so a truncated video is never published.
    """

    FOURCC = "VP80"

    def __init__(self, path, fps, size, force=False):
        super().__init__(check_writable(path, force), fps, size, force)
        self._tmp = _make_output(self)
        with _quiet_opencv_tag_warning():
            self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*self.FOURCC), self.fps, self.size)
        if not self._writer.isOpened():
            self._writer.release()
            _remove(self._tmp)
            remove_folders(self._created)
            raise RuntimeError(f"{self.path}: this OpenCV build cannot write {self.FOURCC} video")
        self._finalizer = weakref.finalize(self, _remove, self._tmp)

    def _write(self, frame: np.ndarray) -> None:
        with _opencv_silent():
            ok = self._writer.write(frame)
        if ok is False:  # (OpenCV before 4.9 returns None and cannot tell)
            raise _silent_failure(self.path, f"OpenCV could not write frame {self.frames_written}")

    def _finish(self) -> None:
        with _captured_stderr(), _opencv_silent():
            self._writer.release()
        size = self._tmp.stat().st_size
        if size == 0:
            raise _silent_failure(self.path, "OpenCV wrote an empty file")
        n = _frame_count(self._tmp)
        if n != self.frames_written:
            got = "an unreadable file" if n < 0 else f"{n} frames"
            raise _silent_failure(self.path, f"OpenCV wrote {got} of {self.frames_written}")
        _publish(self._tmp, self.path, self.force)
        self._finalizer.detach()

    def _discard(self) -> None:
        with _captured_stderr(), _opencv_silent():
            self._writer.release()
        self._finalizer()


class PngFolderSink(Sink):
    """A folder of frame_00000.png, frame_00001.png, ... written to a hidden folder, then moved in.

    A new folder is renamed into place whole. Into an existing folder (empty, or any with `force`)
    the frames are moved one by one; with `force`, frame_NNNNN.png files left from an earlier,
    longer run are deleted. Other files in the folder are never touched. Each frame is encoded in
    memory and written by Python, so a failed write is an OSError naming the folder and the cause.
    """

    def __init__(self, path, fps, size, force=False):
        super().__init__(check_writable_dir(path, force), fps, size, force)
        self._tmp = _make_output(self, folder=True)
        self._finalizer = weakref.finalize(self, _remove, self._tmp)

    def _write(self, frame: np.ndarray) -> None:
        name = self._tmp / _FRAME_NAME.format(self.frames_written)
        ok, buf = cv2.imencode(".png", frame)
        if not ok:
            raise RuntimeError(f"{self.path}: could not encode {name.name}")
        try:
            with open(name, "wb") as fh:
                fh.write(buf.tobytes())
        except OSError as exc:
            raise named_os_error(exc, self.path / name.name) from None

    def _finish(self) -> None:
        if not self.path.exists():
            try:
                os.rename(self._tmp, self.path)
                self._finalizer.detach()
                return
            except OSError:
                pass  # the folder appeared meanwhile: merge into it below
        self.path = check_writable_dir(self.path, self.force)
        for src in sorted(self._tmp.iterdir()):
            _publish(src, self.path / src.name, self.force)
        if self.force:
            for old in self.path.iterdir():
                m = _FRAME_RE.fullmatch(old.name)
                if m and int(m.group(1)) >= self.frames_written and old.is_file():
                    old.unlink()
        self._tmp.rmdir()
        self._finalizer.detach()

    def _discard(self) -> None:
        self._finalizer()
