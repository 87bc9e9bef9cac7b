"""`crowd-ik render-many JOBS -o DIR/`: render every job of a JOBS file on Ray (crowd_ik.batch), with a
progress bar over jobs on stderr and a summary on stdout.

Order of work: check the arguments, that Ray is installed, the JOBS file (every scene loaded and
checked) and DIR (which jobs are complete, and that no other output would be overwritten without
--force) before Ray starts; then render. Exit codes: 0 every job done (rendered or complete before),
1 some job failed (after its retries; see DIR/manifest.jsonl), 2 bad input, 130 Ctrl-C, 143 SIGTERM.
"""

from __future__ import annotations

import sys

from crowd_ik.batch import jobs as batch_jobs
from crowd_ik.batch import runner

EXIT_FAILED, EXIT_INTERRUPTED, EXIT_TERMINATED = 1, 130, 143


def _positive(flag: str, value: int | None, low: int = 1) -> None:
    if value is not None and value < low:
        what = "a positive integer" if low == 1 else "zero or a positive integer"
        raise ValueError(f"{flag}: must be {what} (got {value})")


def format_report(report: runner.Report) -> str:
    """The summary: counts, failures with their errors, workers, throughput."""
    p = report.plan
    rendered, failed = report.count("ok"), report.count("failed")
    total = len(p.todo) + len(p.done)
    left = len(p.todo) - len(report.outcomes)
    lines = [f"render-many: {total} jobs -> {p.folder}/ (manifest {p.manifest.path})"]
    lines.append(f"  rendered    {rendered}" + (f" ({sum(o.record['frames'] for o in report.outcomes if o.record['status'] == 'ok')} frames)"
                                               if rendered else ""))
    lines.append(f"  complete    {len(p.done)} (from earlier runs, skipped)")
    lines.append(f"  failed      {failed}")
    for o in report.outcomes:
        if o.record["status"] == "failed":
            tries = o.record["attempts"]
            lines.append(f"    {o.job.name}: {o.record['error']} ({tries} attempt{'s' if tries != 1 else ''})")
    if report.interrupted:
        lines.append(f"  cancelled   {left} (by {report.interrupted}; run the same command again to resume)")
    if report.workers:
        per_min = 60.0 * len(report.outcomes) / report.wall_s if report.wall_s > 0 else 0.0
        lines.append(f"  workers     {report.workers} x {report.threads} thread{'s' if report.threads != 1 else ''} "
                     f"on a {report.cluster}")
        lines.append(f"  wall time   {report.wall_s:.1f} s ({per_min:.1f} jobs/min, Ray start-up included)")
    if p.manifest.skipped_lines:
        lines.append(f"  note        {p.manifest.path}: unreadable lines skipped: "
                     f"{', '.join(map(str, p.manifest.skipped_lines[:10]))}")
    return "\n".join(lines)


def run(args) -> int:
    """`crowd-ik render-many`: see the module docstring."""
    _positive("--workers", args.workers)
    _positive("--threads", args.threads)
    _positive("--retries", args.retries, low=0)
    address = runner.check_address(args.address)
    runner.import_ray()  # before anything else: say how to install it
    jobs = batch_jobs.load_jobs(args.jobs)
    plan = runner.plan(jobs, args.output, force=args.force)
    report = runner.run_jobs(plan, address=address, workers=args.workers, threads=args.threads,
                             retries=args.retries, force=args.force, arch=args.arch, progress=True)
    print(format_report(report), flush=True)
    if report.interrupted == "SIGTERM":
        print("crowd-ik: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    if report.interrupted:
        print("crowd-ik: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_FAILED if report.count("failed") else 0


__all__ = ["run", "format_report"]
