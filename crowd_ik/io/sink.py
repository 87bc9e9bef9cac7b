"""A video sink's common part: frame checks, the hidden temporary output renamed into place on close,
and the one-line OS errors of a failed write (crowd_ik/io/video.py explains the formats)."""

from __future__ import annotations

import contextlib
import errno
import math
import os
import re
import shutil
import sys
from pathlib import Path

import numpy as np

from crowd_ik.io.output import (
    make_parents,
    make_temp_path,
    named_os_error,
    publish,
    remove_folders,
)

VIDEO_SUFFIXES = (".mp4", ".webm")
MIN_SIDE = 16
_FRAME_NAME = "frame_{:05d}.png"
_FRAME_RE = re.compile(r"frame_(\d{5,})\.png")


def check_size(size, what: str = "size") -> tuple[int, int]:
    """Validate a frame size (W, H): two even integers >= 16 (no silent resize); return it."""
    try:
        w, h = size
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected (width, height), got {size!r}") from None
    if any(isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) for v in (w, h)):
        raise ValueError(f"{what}: width and height must be integers, got {size!r}")
    w, h = int(w), int(h)
    if w < MIN_SIDE or h < MIN_SIDE or w % 2 or h % 2:
        raise ValueError(f"{what}: {w}x{h} is not allowed; width and height must be even and >= {MIN_SIDE}")
    return w, h


def _check_fps(fps) -> float:
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise ValueError(f"fps: expected a number, got {fps!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"fps: must be a positive finite number, got {fps!r}")
    return value


# OS errors a failing encoder names in its log ("No space left on device"), reported as that error.
_OS_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO)
_FULL_BYTES = 2**20  # a file system with less than this free is taken to be full


def _one_line(err: BaseException) -> str:
    if isinstance(err, OSError) and err.errno is not None and err.strerror and err.filename is not None:
        return err.strerror
    return " | ".join(str(err).splitlines())


def _make_output(sink: Sink, folder: bool = False) -> Path:
    """Make the sink's parent folders (remembered for removal) and its temporary file or folder;
    an OSError names the output."""
    try:
        sink._created = make_parents(sink.path.parent)
        return make_temp_path(sink.path, folder=folder)
    except OSError as exc:
        remove_folders(sink._created)
        raise named_os_error(exc, sink.path) from None


def _publish(tmp: Path, final: Path, force: bool) -> None:
    try:
        publish(tmp, final, force)
    except OSError as exc:
        raise named_os_error(exc, final) from None


def _silent_failure(path: Path, what: str) -> OSError:
    """The error of a writer that reports failure without a cause (OpenCV's VideoWriter): no space
    left on device when the output's file system is full, else an I/O error."""
    try:
        st = os.statvfs(path.parent)
        full = st.f_bavail * st.f_frsize < _FULL_BYTES
    except OSError:
        full = False
    code = errno.ENOSPC if full else errno.EIO
    return OSError(code, f"{os.strerror(code)} ({what})", str(path))


def _remove(path: Path) -> None:
    """Delete a temporary file or folder if it is still there."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


class Sink:
    """Base of all sinks: frame validation, bookkeeping, close/abort, context manager.

    Subclasses implement `_write(frame)`, `_finish()` (finalise and publish the temporary output)
    and `_discard()` (release resources and delete the temporary output).
    """

    def __init__(self, path: Path, fps: float, size: tuple[int, int], force: bool):
        self.path = path
        self.fps = _check_fps(fps)
        self.size = check_size(size)
        self.force = bool(force)
        self.frames_written = 0
        self._state = "open"
        self._created: list[Path] = []  # parent folders made for the output, removed if it is discarded
        w, h = self.size
        self._shape = (h, w, 3)

    def __repr__(self) -> str:
        w, h = self.size
        return f"{type(self).__name__}({str(self.path)!r}, {w}x{h} @ {self.fps:g} fps, {self.frames_written} frames, {self._state})"

    def write(self, frame: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 BGR frame of this sink's size."""
        if self._state != "open":
            raise RuntimeError(f"{self.path}: cannot write to a {self._state} sink")
        if not isinstance(frame, np.ndarray) or frame.shape != self._shape or frame.dtype != np.uint8:
            got = f"{frame.shape} {frame.dtype}" if isinstance(frame, np.ndarray) else type(frame).__name__
            raise ValueError(f"{self.path}: frame {self.frames_written} is {got}; expected {self._shape} uint8 BGR")
        self._write(np.ascontiguousarray(frame))
        self.frames_written += 1

    def close(self) -> Path:
        """Finalise the output and rename it into place; return its path. Idempotent."""
        if self._state == "closed":
            return self.path
        if self._state == "aborted":
            raise RuntimeError(f"{self.path}: the sink was aborted; nothing to close")
        if self.frames_written == 0:
            self.abort()
            raise RuntimeError(f"{self.path}: no frames were written; nothing saved")
        try:
            self._finish()
        except BaseException:
            self._state = "aborted"
            self._discard()
            remove_folders(self._created)
            raise
        self._state = "closed"
        return self.path

    def abort(self) -> None:
        """Stop and delete the temporary output (and the folders made for it); an existing file at
        `path` is left as it was."""
        if self._state == "open":
            self._state = "aborted"
            self._discard()
            remove_folders(self._created)

    def __enter__(self) -> Sink:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.close()
        elif issubclass(exc_type, KeyboardInterrupt) and self.frames_written:
            try:
                self.close()  # Ctrl-C (or SIGTERM) keeps the frames so far as a shorter, playable video
            except Exception as err:  # the interrupt stays the reported cause; nothing is left behind
                print(f"crowd-ik: {self.path}: could not finalise the interrupted output: {_one_line(err)}",
                      file=sys.stderr)
        else:
            self.abort()
        return False

    def _write(self, frame: np.ndarray) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        raise NotImplementedError

    def _discard(self) -> None:
        raise NotImplementedError
