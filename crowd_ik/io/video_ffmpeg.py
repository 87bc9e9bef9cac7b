"""The `.mp4` (H.264) sink and the bundled ffmpeg: frames piped to its stdin as raw yuv420p, its exit status and
OS errors checked; also the `.webm` fallback when OpenCV cannot write VP8."""

from __future__ import annotations

import contextlib
import functools
import os
import subprocess
import tempfile
import weakref
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from crowd_ik.io.output import (
    check_writable,
    remove_folders,
)
from crowd_ik.io.sink import _OS_ERRORS, Sink, _make_output, _publish, _remove

# ffmpeg output options per codec. The input on stdin is raw yuv420p (a sink's sides are even): OpenCV's
# BGR -> I420 (BT.601, limited range, as ffmpeg's default for yuv420p) takes 0.3 ms a 1280x720 frame,
# ffmpeg's own bgr24 -> yuv420p conversion ~7 ms of the encoder's CPU. On 90
# arena frames at 1280x720: encoder CPU 21.9 -> 14.6 ms a frame, PSNR of the decoded frames against the raw
# ones 36.9 -> 38.5 dB (OpenCV averages each 2x2 block's chroma), the file 3 % smaller.
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


def _stop_process(proc: subprocess.Popen, tmp: Path) -> None:
    """Kill an encoder and delete its temporary output (also run if a sink is dropped unclosed)."""
    if proc.poll() is None:
        proc.kill()
    with contextlib.suppress(OSError):
        proc.stdin.close()
    proc.wait()
    _remove(tmp)


class FfmpegSink(Sink):
    """Pipes frames (BGR, converted to yuv420p here) into the bundled ffmpeg; codec "h264" (.mp4) or "vp8" (.webm)."""

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
               "-f", "rawvideo", "-pix_fmt", "yuv420p", "-s", f"{w}x{h}", "-r", str(rate), "-i", "-",
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
        self._pending = memoryview(cv2.cvtColor(frame, cv2.COLOR_BGR2YUV_I420)).cast("B")
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
