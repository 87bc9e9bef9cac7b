"""The render-many worker: one process that starts Taichi once and renders job after job, so every job
after the first finds the runtime up and the kernels compiled (crowd_ik.batch.runner runs it as a Ray
actor; it is a plain class, usable without Ray).

A job is rendered exactly as `crowd-ik play SCENE -o OUT.mp4` renders it (a World without HUD timings,
frame k shown after k steps, the same sink), so the decoded frames are the same. The video (and the
labels) are written to a private temporary folder on the worker's machine and returned as bytes: the
driver writes them into DIR atomically, so workers need no shared file system.
"""

from __future__ import annotations

import gc
import os
import shutil
import socket
import tempfile
import time
from pathlib import Path

from crowd_ik import runtime

__all__ = ["JobRenderer", "JobTimeout", "one_line", "TEMP_PREFIX"]

TEMP_PREFIX = "crowd-ik-job-"


class JobTimeout(RuntimeError):
    """A job ran past its timeout_s."""


def one_line(exc: BaseException) -> str:
    """An exception as one line: its type where the text alone would not say what happened."""
    text = " ".join(str(exc).split())
    if not text:
        return type(exc).__name__
    return text if isinstance(exc, (ValueError, RuntimeError, OSError)) else f"{type(exc).__name__}: {text}"


def _remove_stale_folders() -> None:
    """Delete job folders left by killed workers of this machine (their pid is gone)."""
    root = Path(tempfile.gettempdir())
    for folder in root.glob(f"{TEMP_PREFIX}*-*"):
        try:
            pid = int(folder.name[len(TEMP_PREFIX):].split("-")[0])
        except ValueError:
            continue
        if pid == os.getpid():
            continue
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            shutil.rmtree(folder, ignore_errors=True)
        except PermissionError:
            pass


class JobRenderer:
    """Renders Jobs (crowd_ik.batch.jobs) one at a time in this process.

    arch, threads: crowd_ik.init's; Taichi starts here, once for all the jobs this worker renders. A
    failure to start (e.g. arch "cuda" on a machine without a GPU) is kept and reported by info() and
    every render(), so the driver can say it in one line instead of a dead actor's traceback.
    """

    def __init__(self, arch: str = "auto", threads: int | None = None):
        self.name = f"{socket.gethostname()}:{os.getpid()}"
        self.error: str | None = None
        self.bad_input = False
        try:
            self.arch = runtime.init(arch=arch, threads=threads)
        except (ValueError, RuntimeError) as exc:
            self.arch, self.error, self.bad_input = None, one_line(exc), isinstance(exc, ValueError)
        self.jobs = 0
        _remove_stale_folders()

    def info(self) -> dict:
        """Who this worker is: name (host:pid), arch, threads, jobs rendered so far, and why Taichi could
        not start (error, bad_input) or None."""
        return {"worker": self.name, "arch": self.arch, "threads": runtime.current().get("threads"),
                "jobs": self.jobs, "error": self.error, "bad_input": self.bad_input}

    def render(self, job, output: str) -> dict:
        """Render `job`; `output` is its path on the driver (recorded in the stats).

        Returns {"status": "ok", "video": bytes, "labels": bytes or None, "frames", "stats", "worker",
        "wall_s"}, or {"status": "failed", "error": one line, "worker", "wall_s"}: a job's failure is
        an answer, not an exception, so the worker stays up for the next job.
        """
        t0 = time.perf_counter()
        if self.error is not None:
            return {"status": "failed", "error": f"the worker could not start Taichi: {self.error}",
                    "worker": self.name, "wall_s": 0.0}
        folder = Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{os.getpid()}-"))
        self.jobs += 1
        try:
            return self._render(job, output, folder, t0)
        except Exception as exc:  # noqa: BLE001 - any failure of one job is reported, the worker goes on
            return {"status": "failed", "error": one_line(exc), "worker": self.name,
                    "wall_s": time.perf_counter() - t0}
        finally:
            shutil.rmtree(folder, ignore_errors=True)
            gc.collect()  # the World's Taichi arrays go now, not at some later job

    def _render(self, job, output: str, folder: Path, t0: float) -> dict:
        from crowd_ik.game.world import World
        from crowd_ik.io.labels import LabelsWriter
        from crowd_ik.io.stats import summary
        from crowd_ik.io.video import open_sink
        from crowd_ik.session import frames

        scene = job.scene
        video_path = folder / "video.mp4"
        labels_path = folder / "labels.jsonl" if job.labels else None
        world = World(scene, hud_timings=False)
        n = scene.n_frames
        size = (scene.video.width, scene.video.height)
        with open_sink(video_path, scene.video.fps, size) as sink:
            labels = LabelsWriter(labels_path) if labels_path is not None else None
            try:
                for k in frames(world, n):  # frame k shows the world after k steps, as in play
                    sink.write(world.render())
                    if labels is not None:
                        labels.add(world, k)
                    if job.timeout_s is not None and time.perf_counter() - t0 > job.timeout_s:
                        raise JobTimeout(f"ran past timeout_s = {job.timeout_s:g} s "
                                         f"({time.perf_counter() - t0:.2f} s, at frame {k + 1} of {n})")
            except BaseException:
                if labels is not None:
                    labels.abort()
                raise
            if labels is not None:
                labels.close()
        wall = time.perf_counter() - t0
        stats = summary(world, scene, output, wall, self.arch, n)
        del world
        return {
            "status": "ok",
            "video": video_path.read_bytes(),
            "labels": labels_path.read_bytes() if labels_path is not None else None,
            "frames": n,
            "stats": stats,
            "worker": self.name,
            "wall_s": wall,
        }
