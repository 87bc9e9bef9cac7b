"""Batch rendering (`crowd-ik render-many`): JOBS files (jobs.py), the Ray orchestration and manifest
(runner.py) and the worker that renders one job after another in a warm Taichi process (worker.py).
Ray itself is an optional extra, imported only when jobs run: pip install 'crowd_ik[cluster]'."""
