"""Video sinks for rendered frames: `.mp4` (H.264), `.webm` (VP8) or a folder of PNGs.

Frames are (H, W, 3) uint8 BGR arrays, row 0 at the top (DESIGN.md, "Rendering"). A sink writes
to a hidden temporary name next to its output and renames it into place when closed, never
clobbering an existing output without `force` (crowd_ik.io.output). Used as a context manager a
sink is finalised on normal exit and on Ctrl-C (a shorter but playable video, DESIGN.md
"Command line"), and discarded on any other exception:

    with open_sink("arena.mp4", fps=30, size=(1280, 720)) as sink:
        for frame in frames:
            sink.write(frame)

- `.mp4`: H.264 yuv420p with +faststart (plays in browsers), encoded by imageio-ffmpeg's bundled
  ffmpeg from raw bgr24 frames piped to its stdin.
- `.webm`: VP8 through OpenCV's VideoWriter; if this OpenCV build cannot write VP8, through the
  bundled ffmpeg's libvpx.
- `DIR/`: frame_00000.png, frame_00001.png, ...
"""

from __future__ import annotations

import contextlib
import errno
import functools
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import weakref
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from crowd_ik.io.output import (
    check_writable,
    check_writable_dir,
    is_dir_target,
    make_parents,
    make_temp_path,
    named_os_error,
    publish,
    remove_folders,
    write_bytes,
)

__all__ = [
    "VIDEO_SUFFIXES",
    "Sink",
    "FfmpegSink",
    "OpenCVSink",
    "PngFolderSink",
    "open_sink",
    "check_size",
    "write_png",
    "read_video",
    "read_frames",
    "ffmpeg_exe",
]

VIDEO_SUFFIXES = (".mp4", ".webm")
MIN_SIDE = 16
_FRAME_NAME = "frame_{:05d}.png"
_FRAME_RE = re.compile(r"frame_(\d{5,})\.png")

# ffmpeg output options per codec; inputs are always raw bgr24 frames on stdin.
# H.264: x264's superfast preset at CRF 21 (was veryfast, CRF 20): on 90 arena frames at 1280x720 it
# took 35 % less encoder CPU (15 vs 23 ms a frame, bgr24 -> yuv420p included) for a decoded quality
# at least as good (SSIM 0.980 vs 0.979, PSNR 36.5 vs 36.1 dB against the raw frames), the file 37 %
# larger; x264 picks its thread count from the cores.
_FFMPEG_CODECS = {
    "h264": ("libx264", ["-c:v", "libx264", "-pix_fmt", "yuv420p", "-movflags", "+faststart",
                         "-preset", "superfast", "-crf", "21", "-f", "mp4"]),
    "vp8": ("libvpx", ["-c:v", "libvpx", "-pix_fmt", "yuv420p", "-deadline", "good", "-cpu-used", "4",
                       "-crf", "10", "-b:v", "8M", "-f", "webm"]),
}


def ffmpeg_exe() -> str:
    """Path of imageio-ffmpeg's bundled ffmpeg binary (RuntimeError if it is missing)."""
    import imageio_ffmpeg

    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as exc:
        raise RuntimeError(f"no ffmpeg binary found by imageio-ffmpeg: {exc}") from None


@functools.lru_cache(maxsize=4)
def _ffmpeg_encoders(exe: str) -> frozenset[str]:
    """Names of the video encoders compiled into the ffmpeg at `exe`."""
    out = subprocess.run([exe, "-hide_banner", "-encoders"], capture_output=True, text=True, check=False)
    names = set()
    for line in out.stdout.splitlines():
        parts = line.split()
        if len(parts) >= 2 and len(parts[0]) == 6 and parts[0][0] == "V":
            names.add(parts[1])
    return frozenset(names)


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


def _stop_process(proc: subprocess.Popen, tmp: Path) -> None:
    """Kill an encoder and delete its temporary output (also run if a sink is dropped unclosed)."""
    if proc.poll() is None:
        proc.kill()
    with contextlib.suppress(OSError):
        proc.stdin.close()
    proc.wait()
    _remove(tmp)


class FfmpegSink(Sink):
    """Pipes raw bgr24 frames into the bundled ffmpeg; codec "h264" (.mp4) or "vp8" (.webm)."""

    def __init__(self, path, fps, size, force=False, codec="h264"):
        if codec not in _FFMPEG_CODECS:
            raise ValueError(f"codec: expected one of {sorted(_FFMPEG_CODECS)}, got {codec!r}")
        super().__init__(check_writable(path, force), fps, size, force)
        exe = ffmpeg_exe()
        encoder, out_args = _FFMPEG_CODECS[codec]
        if encoder not in _ffmpeg_encoders(exe):
            raise RuntimeError(f"{self.path}: the bundled ffmpeg ({exe}) has no {encoder} encoder")
        self.codec = codec
        self._tmp = _make_output(self)
        w, h = self.size
        rate = Fraction(self.fps).limit_denominator(1001)
        cmd = [exe, "-hide_banner", "-loglevel", "error", "-nostats", "-y",
               "-f", "rawvideo", "-pix_fmt", "bgr24", "-s", f"{w}x{h}", "-r", str(rate), "-i", "-",
               "-an", *out_args, str(self._tmp)]
        self._log = tempfile.TemporaryFile()  # a file, not a pipe: ffmpeg can never block on it
        try:
            # Own process group: a terminal Ctrl-C reaches only us, and we finalise the video.
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                          stderr=self._log, bufsize=0, process_group=0)
        except OSError as exc:
            self._log.close()
            _remove(self._tmp)
            remove_folders(self._created)
            raise RuntimeError(f"{self.path}: cannot start ffmpeg: {exc}") from None
        self._fd = self._proc.stdin.fileno()
        self._pending = memoryview(b"")
        self._finalizer = weakref.finalize(self, _stop_process, self._proc, self._tmp)

    def _ffmpeg_error(self, what: str) -> Exception:
        """ffmpeg's failure: an OSError naming the output when its log names an OS error (a full disk),
        else a RuntimeError with the log's last lines."""
        self._log.seek(0)
        text = self._log.read().decode("utf-8", "replace").strip()
        for code in _OS_ERRORS:
            if os.strerror(code) in text:
                return OSError(code, f"{os.strerror(code)} (ffmpeg {what})", str(self.path))
        tail = " | ".join(text.splitlines()[-5:]) or "no message"
        return RuntimeError(f"{self.path}: ffmpeg {what}: {tail}")

    def _drain(self) -> None:
        # One statement per chunk, so an interrupt between chunks never loses track of the bytes
        # sent: whatever is left of a frame is sent by close() before the stream ends.
        try:
            while self._pending:
                self._pending = self._pending[os.write(self._fd, self._pending):]
        except (BrokenPipeError, ConnectionResetError):
            self._proc.wait()
            raise self._ffmpeg_error(f"stopped early (exit code {self._proc.returncode})") from None

    def _write(self, frame: np.ndarray) -> None:
        self._pending = memoryview(frame).cast("B")
        self._drain()

    def _finish(self) -> None:
        self._drain()
        self._proc.stdin.close()
        code = self._proc.wait()
        if code != 0:
            raise self._ffmpeg_error(f"failed (exit code {code})")
        if self._tmp.stat().st_size == 0:
            raise self._ffmpeg_error("wrote an empty file")
        _publish(self._tmp, self.path, self.force)
        self._finalizer.detach()
        self._log.close()

    def _discard(self) -> None:
        self._finalizer()  # kills ffmpeg if running and deletes the temporary file
        self._log.close()


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


def open_sink(path: str | os.PathLike, fps: float, size: tuple[int, int], force: bool = False) -> Sink:
    """Open a sink for `path` chosen by its suffix: .mp4, .webm, or a folder ("DIR/" or an existing dir).

    `size` is (W, H), both even and >= 16. Refuses an existing output without `force`
    (FileExistsError), a .png (a still, not a video) and unknown suffixes (ValueError).
    """
    text = os.fspath(path)
    if not text:
        raise ValueError("output path is empty")
    if is_dir_target(text):
        return PngFolderSink(text, fps, size, force)
    suffix = Path(text).suffix.lower()
    if suffix == ".png":
        raise ValueError(f"{text}: a .png is a single still, not a video; use --still K for one frame, "
                         f"or a folder ending in '/' for PNG frames")
    if suffix == ".mp4":
        return FfmpegSink(text, fps, size, force, codec="h264")
    if suffix == ".webm":
        try:
            return OpenCVSink(text, fps, size, force)
        except RuntimeError as cv_err:
            if "libvpx" in _ffmpeg_encoders(ffmpeg_exe()):
                return FfmpegSink(text, fps, size, force, codec="vp8")
            raise RuntimeError(f"{text}: cannot write VP8 .webm: {cv_err}, and the bundled ffmpeg "
                               f"has no libvpx; use .mp4") from None
    raise ValueError(f"{text}: unknown video suffix {suffix or '(none)'!r}; use .mp4 (H.264), .webm (VP8) "
                     f"or a folder ending in '/' (PNG frames)")


def write_png(path: str | os.PathLike, frame: np.ndarray, force: bool = False) -> Path:
    """Write one (H, W, 3) uint8 BGR frame as a PNG still, atomically and without clobbering."""
    text = os.fspath(path)
    if Path(text).suffix.lower() != ".png":
        raise ValueError(f"{text}: a still must be a .png file")
    if not isinstance(frame, np.ndarray) or frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8 \
            or frame.shape[0] == 0 or frame.shape[1] == 0:
        got = f"{frame.shape} {frame.dtype}" if isinstance(frame, np.ndarray) else type(frame).__name__
        raise ValueError(f"{text}: frame is {got}; expected (H, W, 3) uint8 BGR")
    check_writable(text, force)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(frame))
    if not ok:
        raise RuntimeError(f"{text}: PNG encoding failed")
    return write_bytes(text, buf.tobytes(), force)


def _folder_frames(folder: Path) -> list[Path]:
    files = [p for p in folder.iterdir() if _FRAME_RE.fullmatch(p.name)]
    return sorted(files, key=lambda p: int(_FRAME_RE.fullmatch(p.name).group(1)))


def _iter_frames(path: str | os.PathLike):
    """Yield (H, W, 3) uint8 BGR frames of a video file or PNG folder."""
    p = Path(os.fspath(path)).expanduser()
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such video")
    if p.is_dir():
        for f in _folder_frames(p):
            img = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{f}: not a readable PNG")
            yield img
        return
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(p), pix_fmt="bgr24", bits_per_pixel=24)
    try:
        try:
            meta = next(gen)
        except (RuntimeError, OSError, StopIteration) as exc:
            raise ValueError(f"{p}: not a readable video: {exc}") from None
        w, h = meta["size"]
        for raw in gen:
            yield np.frombuffer(raw, np.uint8).reshape(h, w, 3)
    finally:
        gen.close()


def read_frames(path: str | os.PathLike) -> list[np.ndarray]:
    """Decode every frame of a .mp4/.webm file or PNG folder as (H, W, 3) uint8 BGR arrays."""
    return list(_iter_frames(path))


def read_video(path: str | os.PathLike) -> tuple[int, int, int]:
    """(n_frames, H, W) of a .mp4/.webm file or PNG folder, counted by decoding every frame."""
    n, h, w = 0, 0, 0
    for frame in _iter_frames(path):
        n += 1
        h, w = frame.shape[:2]
    return n, h, w
