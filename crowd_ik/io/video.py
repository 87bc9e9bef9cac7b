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

import os
from pathlib import Path

import cv2
import numpy as np

from crowd_ik.io.output import check_writable, is_dir_target, write_bytes
from crowd_ik.io.sink import _FRAME_RE, VIDEO_SUFFIXES, Sink, check_size  # noqa: F401  (the sinks' API)
from crowd_ik.io.video_ffmpeg import FfmpegSink, _ffmpeg_encoders, ffmpeg_exe
from crowd_ik.io.video_sinks import OpenCVSink, PngFolderSink

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
