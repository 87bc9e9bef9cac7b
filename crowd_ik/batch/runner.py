"""render-many's orchestration on Ray: which jobs are left, the workers, retries, the manifest, cancel.

- Ray: with no address a local Ray instance is started on this machine (and stopped at the end); with
  "auto" or HOST:PORT (or ray://HOST:PORT, Ray Client) an existing cluster is joined, whose nodes have
  crowd_ik[cluster] installed. Each worker is a Ray actor (crowd_ik.batch.worker.JobRenderer) holding
  its Taichi runtime and kernels for all the jobs it is given; one job at a time per worker.
- Resume: DIR/manifest.jsonl gets one JSON line per finished job (ok or failed), appended and synced
  when the job's files are in place, so the manifest is true whenever the run stops. A job is complete
  when its last record is ok, was made from the same job (Job.key: every scene value and the labels
  flag) and its files have the recorded sizes; complete jobs are skipped unless force. An output file
  that is not a complete job's is never overwritten without force.
- Retries: a failed job (an error in the job, or its worker dying, which brings up a new worker) runs
  again up to `retries` times, then is recorded as failed with its one-line error.
- Cancel: Ctrl-C or SIGTERM stops the workers (unfinished jobs leave no files and no records), stops
  the local Ray instance, and the report says which signal ended the run.
"""

from __future__ import annotations

import collections
import datetime
import json
import os
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from crowd_ik.batch.jobs import Job
from crowd_ik.batch.worker import JobRenderer, one_line
from crowd_ik.io.output import check_writable_dir, write_bytes

MANIFEST = "manifest.jsonl"
INSTALL_HINT = "pip install 'crowd_ik[cluster]' (or: pip install ray)"
_ADDRESS = re.compile(r"(ray://)?[A-Za-z0-9_.\-\[\]:]+:\d{1,5}")

__all__ = ["MANIFEST", "Manifest", "Plan", "Outcome", "Report", "plan", "run_jobs", "import_ray", "check_address"]


class _Terminated(KeyboardInterrupt):
    """SIGTERM while jobs run: cancelled like Ctrl-C."""


def import_ray():
    """The ray module, or a ValueError saying how to install it (the command line's exit 2)."""
    try:
        import ray
    except ImportError:
        raise ValueError(f"render-many runs on Ray, which is not installed here: {INSTALL_HINT}") from None
    return ray


def check_address(address: str | None) -> str | None:
    """None, "auto", HOST:PORT or ray://HOST:PORT; anything else is refused."""
    if address is None or address == "auto" or _ADDRESS.fullmatch(address):
        return address
    raise ValueError(f"--address: expected auto, HOST:PORT or ray://HOST:PORT (got {address!r})")


class Manifest:
    """DIR/manifest.jsonl: one JSON object per line, appended; the last line of a job wins."""

    def __init__(self, folder: Path):
        self.path = folder / MANIFEST
        self.skipped_lines: list[int] = []

    def read(self) -> dict[str, dict]:
        """{job name: its last record}; unreadable lines (a line cut by a crash) are skipped and listed."""
        records: dict[str, dict] = {}
        if not self.path.exists():
            return records
        if not self.path.is_file():
            raise ValueError(f"{self.path}: exists and is not a file")
        with open(self.path, encoding="utf-8", errors="replace") as f:
            for number, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                    records[rec["job"]["name"]] = rec
                except (ValueError, KeyError, TypeError):
                    self.skipped_lines.append(number)
        return records

    def append(self, record: dict) -> None:
        """Add one line and sync it to disk (a line cut short by a crash is skipped by read)."""
        data = (json.dumps(record, separators=(",", ":"), allow_nan=False) + "\n").encode("utf-8")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        try:
            if os.fstat(fd).st_size and not self._ends_with_newline():
                data = b"\n" + data
            os.write(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)

    def _ends_with_newline(self) -> bool:
        with open(self.path, "rb") as f:
            f.seek(-1, os.SEEK_END)
            return f.read(1) == b"\n"


@dataclass
class Plan:
    """The jobs left to render and the complete ones (with their records)."""

    folder: Path
    todo: list[Job]
    done: list[tuple[Job, dict]]
    manifest: Manifest


def _size(path: Path) -> int | None:
    try:
        return path.stat().st_size if path.is_file() else None
    except OSError:
        return None


def plan(jobs: list[Job], folder: str | os.PathLike, force: bool = False) -> Plan:
    """Which jobs to render. Raises FileExistsError for an output that is not a complete job's (without
    force), NotADirectoryError when DIR is a file; creates nothing."""
    out = check_writable_dir(folder, force=True)  # a folder (or none yet) we may write in; not a file
    manifest = Manifest(out)
    records = manifest.read()
    todo, done = [], []
    for job in jobs:
        video, labels = job.outputs(out)
        rec = records.get(job.name)
        complete = (rec is not None and rec.get("status") == "ok" and rec.get("key") == job.key
                    and _size(video) == rec.get("bytes", {}).get("video")
                    and (labels is None or _size(labels) == rec.get("bytes", {}).get("labels")))
        if complete and not force:
            done.append((job, rec))
            continue
        if not force:
            for path in (video, labels):
                if path is not None and (path.exists() or path.is_symlink()):
                    ok = rec is not None and rec.get("status") == "ok"
                    why = ("is not recorded as a complete render of this job" if not ok
                           else "does not match its record (size)" if rec.get("key") == job.key
                           else "was rendered from another version of this job (its scene values changed)")
                    raise FileExistsError(f"{path} exists and {why} in {manifest.path}")
        todo.append(job)
    return Plan(out, todo, done, manifest)


@dataclass
class Outcome:
    job: Job
    record: dict


@dataclass
class Report:
    """What a run did: outcomes of the jobs it finished, in finishing order."""

    plan: Plan
    outcomes: list[Outcome] = field(default_factory=list)
    interrupted: str | None = None  # "SIGINT" or "SIGTERM"
    wall_s: float = 0.0
    workers: int = 0
    threads: int = 1
    cluster: str = ""

    def count(self, status: str) -> int:
        return sum(o.record["status"] == status for o in self.outcomes)


def _sizes(ray, address: str | None, workers: int | None, threads: int | None, jobs: int) -> tuple[int, int, float]:
    """(workers, Taichi threads per worker, CPUs reserved per worker) from the CPUs Ray offers."""
    cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
    if threads is None:
        threads = max(1, cpus // workers) if workers is not None and address is None else 1
    if workers is None:
        workers = max(1, cpus // threads)
    workers = max(1, min(workers, jobs))
    return workers, threads, min(float(threads), cpus / workers)


def _record(job: Job, attempt: int, folder: Path, result: dict) -> dict:
    video, labels = job.outputs(folder)
    ok = result["status"] == "ok"
    return {
        "job": job.describe(),
        "key": job.key,
        "status": result["status"],
        "output": video.name,
        "labels": labels.name if labels is not None else None,
        "frames": result.get("frames", 0),
        "bytes": result.get("bytes", {}),
        "stats": result.get("stats") if ok else None,
        "worker": result.get("worker"),
        "wall_s": round(float(result.get("wall_s", 0.0)), 3),
        "attempts": attempt,
        "error": None if ok else result.get("error"),
        "finished": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }


def _publish(job: Job, folder: Path, result: dict, force: bool) -> dict:
    """Write a finished job's files into DIR (atomic, no clobber without force); the result with their sizes,
    or a failed result naming the file that could not be written."""
    video, labels = job.outputs(folder)
    try:
        write_bytes(video, result["video"], force)
        sizes = {"video": len(result["video"])}
        if labels is not None:
            write_bytes(labels, result["labels"], force)
            sizes["labels"] = len(result["labels"])
    except (OSError, ValueError) as exc:
        text = one_line(exc) + (" (use --force to overwrite)" if isinstance(exc, FileExistsError) else "")
        return {"status": "failed", "error": text, "worker": result["worker"], "wall_s": result["wall_s"]}
    done = {k: v for k, v in result.items() if k not in ("video", "labels")}
    done["bytes"] = sizes
    return done


def _progress(total: int, initial: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="render-many", unit="job", file=sys.stderr, disable=not enabled,
                dynamic_ncols=True, mininterval=0.5,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} jobs [{elapsed}<{remaining}]{postfix}")


def _start_ray(ray, address: str | None) -> None:
    options = dict(include_dashboard=False, logging_level="WARNING", log_to_driver=False)
    try:
        ray.init(address="local" if address is None else address, **options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = "start a local Ray instance" if address is None else f"join the Ray cluster at {address}"
        raise RuntimeError(f"--address: could not {where}: {one_line(exc)}") from None


def _cause(ray, exc: BaseException) -> BaseException:
    """The user's exception inside a Ray error (a worker's ValueError is still bad input)."""
    cause = getattr(exc, "cause", None)
    return cause if isinstance(cause, BaseException) else exc


def run_jobs(p: Plan, *, address: str | None = None, workers: int | None = None, threads: int | None = None,
             retries: int = 1, force: bool = False, arch: str = "auto", progress: bool = True) -> Report:
    """Render the plan's todo jobs on Ray; see the module docstring."""
    ray = import_ray()
    t0 = time.perf_counter()
    report = Report(p)
    if not p.todo:
        return report
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if main_thread else None  # ray.init installs its own
    received: list[str] = []
    _start_ray(ray, address)
    if main_thread:
        def on_sigterm(signum, frame):
            signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second one must not cut the clean-up short
            received.append("SIGTERM")  # (inside ray.wait the exception arrives as a plain KeyboardInterrupt)
            raise _Terminated

        signal.signal(signal.SIGTERM, on_sigterm)
    actors: list = []
    try:
        n_workers, n_threads, cpus = _sizes(ray, address, workers, threads, len(p.todo))
        report.workers, report.threads = n_workers, n_threads
        report.cluster = "local Ray instance" if address is None else f"Ray cluster at {address}"
        remote = ray.remote(num_cpus=cpus, max_restarts=0)(JobRenderer)

        def start_worker():
            actor = remote.remote(arch, n_threads)
            actors.append(actor)
            return actor

        idle = [start_worker() for _ in range(n_workers)]
        try:
            infos = ray.get([a.info.remote() for a in idle])
        except ray.exceptions.RayError as exc:
            text = one_line(_cause(ray, exc)).splitlines()[0][:300]
            raise RuntimeError(f"render-many: the workers could not start: {text}") from None
        for info in infos:
            if info["error"] is not None:
                if info["bad_input"]:
                    raise ValueError(info["error"])
                raise RuntimeError(f"render-many: worker {info['worker']} could not start Taichi: {info['error']}")
        queue = collections.deque((job, 1) for job in p.todo)
        inflight: dict = {}
        with _progress(len(p.todo) + len(p.done), len(p.done), progress) as bar:
            while queue or inflight:
                while idle and queue:
                    job, attempt = queue.popleft()
                    actor = idle.pop()
                    ref = actor.render.remote(job, str(job.outputs(p.folder)[0]))
                    inflight[ref] = (job, attempt, actor)
                ready, _ = ray.wait(list(inflight), num_returns=1, timeout=0.5)
                for ref in ready:
                    job, attempt, actor = inflight.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayActorError as exc:
                        result = {"status": "failed", "error": f"the worker died: {one_line(exc).splitlines()[0][:200]}",
                                  "worker": None, "wall_s": 0.0}
                        actors.remove(actor)
                        actor = start_worker()
                    except ray.exceptions.RayError as exc:
                        result = {"status": "failed", "error": one_line(_cause(ray, exc))[:500], "worker": None,
                                  "wall_s": 0.0}
                    idle.append(actor)
                    if result["status"] == "ok":
                        result = _publish(job, p.folder, result, force)
                    elif attempt <= retries:
                        bar.write(f"render-many: {job.name}: attempt {attempt} failed: {result['error']}; retrying",
                                  file=sys.stderr)
                        queue.append((job, attempt + 1))
                        continue
                    record = _record(job, attempt, p.folder, result)
                    p.manifest.append(record)
                    report.outcomes.append(Outcome(job, record))
                    bar.update()
                    failed = report.count("failed")
                    if failed:
                        bar.set_postfix_str(f"{failed} failed", refresh=False)
    except KeyboardInterrupt as exc:
        terminated = received or isinstance(exc, _Terminated) or type(exc).__name__ == "Terminated"  # cli's own
        report.interrupted = "SIGTERM" if terminated else "SIGINT"
    finally:
        for actor in actors:
            try:
                ray.kill(actor, no_restart=True)
            except Exception:  # noqa: BLE001 - an actor already gone
                pass
        ray.shutdown()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        report.wall_s = time.perf_counter() - t0
    return report
