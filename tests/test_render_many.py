"""`crowd-ik render-many`: JOBS files refused like scenes, resume from the manifest, and - on a local Ray
instance with two workers, at tiny sizes - a 4-job sweep with one job already done and one failing on
purpose, whose videos and labels equal `crowd-ik play`'s, and a SIGTERM that cancels cleanly."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from crowd_ik.batch import jobs as batch_jobs
from crowd_ik.batch import runner
from crowd_ik.commands.cli import main
from crowd_ik.io.video import read_frames
from tiny_scenes import tiny_scene

TINY = tiny_scene(frames=8, size=None)
OVERRIDES = """
labels = true
[overrides]
video = { width = 96, height = 64 }
"""


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.fixture
def folder(tmp_path):
    write(tmp_path / "tiny.toml", TINY)
    write(tmp_path / "long.toml", TINY.replace("frames = 8", "frames = 20000"))
    return tmp_path


def load(tmp_path, text):
    return batch_jobs.load_jobs(write(tmp_path / "jobs.toml", text))


# --------------------------------------------------------------------------- JOBS files (no Ray)

def test_a_sweep_is_every_combination(folder):
    jobs = load(folder, 'scenes = ["tiny.toml", "duel"]\nseeds = "4..6"\nsolvers = ["fabrik", "dls"]\n'
                        "[overrides]\nvideo = { width = 64, height = 48, frames = 3 }\n")
    assert len(jobs) == 12
    assert jobs[0].name == "tiny_s4_fabrik" and jobs[-1].name == "duel_s6_dls"
    assert {j.scene.video.width for j in jobs} == {64} and {j.scene.n_frames for j in jobs} == {3}
    assert jobs[1].scene.solver.method == "dls" and jobs[2].scene.seed == 5
    assert len({j.key for j in jobs}) == 12
    explicit = load(folder, '[[job]]\nscene = "tiny.toml"\n[[job]]\nscene = "tiny.toml"\nseed = 9\nsolver = "ccd"\n')
    assert [j.name for j in explicit] == ["tiny_s3", "tiny_s9_ccd"]  # the scene's own seed when none is given


@pytest.mark.parametrize("text, message", [
    ('scenes = ["tiny.toml"]\nseeds = "5..2"\n', 'jobs.toml: seeds: range 5..2 is empty (A..B needs A <= B) (got "5..2")'),
    ('scenes = ["tiny.toml"]\nseeds = [1, true]\n', "jobs.toml: seeds[1]: must be an integer from 0 to 2147483647 (got true)"),
    ('scenes = ["nowhere"]\n', 'jobs.toml: scenes[0]: no such scene file'),
    ('scenes = ["tiny.toml"]\nsolvers = ["fabrk"]\n', 'jobs.toml: solvers[0]: must be one of'),
    ('scene = ["tiny.toml"]\n', "jobs.toml: scene: unknown key; did you mean scenes? (got"),
    ('seeds = [1]\n', "jobs.toml: seeds: a sweep needs scenes = [...] too"),
    ("", "jobs.toml: no jobs"),
    ('[[job]]\nseed = 1\n', "jobs.toml: job[0].scene: missing"),
    ('[[job]]\nscene = "tiny.toml"\ncolor = 1\n', "jobs.toml: job[0].color: unknown key"),
    ('scenes = ["tiny.toml"]\nseeds = [1]\n[[job]]\nscene = "tiny.toml"\nseed = 1\n',
     "jobs.toml: job[0]: renders tiny_s1.mp4, as scenes[0] does"),
    ('scenes = ["tiny.toml"]\ntimeout_s = -1\n', "jobs.toml: timeout_s: must be a positive number of seconds (got -1)"),
    ('scenes = ["tiny.toml"]\n[overrides]\nvideo = { width = 161 }\n',
     "jobs.toml: overrides.video.width: must be even (H.264 with yuv420p needs even sizes) (got 161)"),
    ('scenes = ["tiny.toml"]\n[overrides]\nvideo = { widht = 160 }\n', "jobs.toml: overrides.video.widht: unknown key; did you mean video.width?"),
    ('scenes = ["tiny.toml"]\n[overrides]\nbullets = { pool_size = 1 }\n',
     "tiny.toml with override bullets.pool_size=1 from"),
    ('labels = yes\n', "jobs.toml: line 1, column 10: invalid TOML: Invalid value"),
])
def test_bad_jobs_files_are_refused_like_scenes(folder, capsys, text, message):
    path = write(folder / "jobs.toml", text)
    assert main(["render-many", str(path), "-o", str(folder / "out") + "/"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0].replace(str(folder) + "/", ""), err
    assert not (folder / "out").exists()


def test_bad_arguments_and_missing_ray(folder, capsys, monkeypatch):
    jobs = write(folder / "jobs.toml", 'scenes = ["tiny.toml"]\n')
    for flags, message in ((["--workers", "0"], "--workers: must be a positive integer (got 0)"),
                           (["--retries", "-1"], "--retries: must be zero or a positive integer (got -1)"),
                           (["--address", "nowhere"], "--address: expected auto, HOST:PORT")):
        assert main(["render-many", str(jobs), "-o", str(folder / "out"), *flags]) == 2
        assert message in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed
    assert main(["render-many", str(jobs), "-o", str(folder / "out")]) == 2
    assert "pip install 'crowd_ik[cluster]'" in capsys.readouterr().err


def test_outputs_not_recorded_in_the_manifest_are_not_clobbered(folder, capsys):
    jobs = write(folder / "jobs.toml", 'scenes = ["tiny.toml"]\nseeds = [1, 2]\n')
    out = folder / "out"
    out.mkdir()
    write(out / "tiny_s2.mp4", "precious")
    assert main(["render-many", str(jobs), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "tiny_s2.mp4 exists and is not recorded as a complete render" in err and "--force" in err
    assert (out / "tiny_s2.mp4").read_text() == "precious" and sorted(os.listdir(out)) == ["tiny_s2.mp4"]
    assert [j.name for j in runner.plan(batch_jobs.load_jobs(jobs), out, force=True).todo] == ["tiny_s1", "tiny_s2"]


def test_a_job_is_complete_only_as_recorded(folder):
    job = load(folder, 'scenes = ["tiny.toml"]\nseeds = [1]\n')[0]
    out = folder / "out"
    out.mkdir()
    record = {"job": job.describe(), "key": job.key, "status": "ok", "bytes": {"video": 5}}
    write(out / "tiny_s1.mp4", "12345")
    write(out / "manifest.jsonl", json.dumps(record) + "\n" + '{"job": {"na')  # a line cut by a crash
    p = runner.plan([job], out)
    assert not p.todo and p.manifest.skipped_lines == [2]
    write(out / "tiny_s1.mp4", "1234")  # not the recorded size
    with pytest.raises(FileExistsError, match="does not match its record"):
        runner.plan([job], out)
    other = load(folder, 'scenes = ["tiny.toml"]\nseeds = [1]\nsolvers = ["dls"]\n[[job]]\nscene="tiny.toml"\n')
    write(out / "tiny_s1.mp4", "12345")
    changed = batch_jobs.Job(job.name, other[0].scene, job.source)  # same name, other scene values
    with pytest.raises(FileExistsError, match="rendered from another version of this job"):
        runner.plan([changed], out)
    p.manifest.append({"job": job.describe(), "key": job.key, "status": "failed", "error": "x"})
    lines = (out / "manifest.jsonl").read_text().splitlines()
    assert json.loads(lines[-1])["status"] == "failed"  # appended on a line of its own after the cut one
    with pytest.raises(FileExistsError, match="is not recorded as a complete render"):
        runner.plan([job], out)  # the last record of a job wins


# --------------------------------------------------------------------------- on a local Ray instance

SWEEP = 'scenes = ["tiny.toml"]\nseeds = "0..2"\n' + OVERRIDES + \
    '[[job]]\nscene = "tiny.toml"\nseed = 9\ntimeout_s = 0.000001  # fails on purpose: past its time at frame 1\n'
FIRST = OVERRIDES + '[[job]]\nscene = "tiny.toml"\nseed = 0\n[[job]]\nscene = "long.toml"\nseed = 0\n'


def _manifest(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_sweep_on_local_ray_resumes_retries_and_matches_play(folder, capsys):
    pytest.importorskip("ray")
    out = folder / "out"
    # a first run, cancelled by SIGTERM while its second (long) job renders: the first job stays done
    first = write(folder / "first.toml", FIRST)
    proc = subprocess.Popen([sys.executable, "-m", "crowd_ik", "render-many", str(first), "-o", str(out),
                             "--workers", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not ((out / "manifest.jsonl").exists() and (out / "manifest.jsonl").read_text().endswith("\n")):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.2)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143, stderr[-2000:]
    assert "cancelled   1 (by SIGTERM" in stdout
    assert [(r["job"]["name"], r["status"]) for r in _manifest(out)] == [("tiny_s0", "ok")]
    assert sorted(os.listdir(out)) == ["manifest.jsonl", "tiny_s0.labels.jsonl", "tiny_s0.mp4"]  # no partial files

    # the sweep: tiny_s0 done, tiny_s1 and tiny_s2 rendered by two workers, tiny_s9 failing twice
    sweep = write(folder / "sweep.toml", SWEEP)
    assert main(["render-many", str(sweep), "-o", str(out), "--workers", "2"]) == 1
    text = capsys.readouterr().out
    assert "rendered    2" in text and "complete    1" in text and "failed      1" in text
    assert "tiny_s9: ran past timeout_s = 1e-06 s" in text and "(2 attempts)" in text
    records = {r["job"]["name"]: r for r in _manifest(out)}
    assert len(_manifest(out)) == 4 and set(records) == {"tiny_s0", "tiny_s1", "tiny_s2", "tiny_s9"}
    assert records["tiny_s9"]["status"] == "failed" and records["tiny_s9"]["attempts"] == 2
    for name in ("tiny_s1", "tiny_s2"):
        r = records[name]
        assert r["status"] == "ok" and r["frames"] == 8 and r["attempts"] == 1 and r["worker"]
        assert r["stats"]["seed"] == int(name[-1]) and r["stats"]["size"] == [96, 64]
        assert r["bytes"]["video"] == (out / f"{name}.mp4").stat().st_size
    assert not (out / "tiny_s9.mp4").exists()
    assert [j.name for j in runner.plan(batch_jobs.load_jobs(sweep), out).todo] == ["tiny_s9"]

    # same job, same frames: play of tiny at seed 1 with the overrides
    video, labels = folder / "play.mp4", folder / "play.jsonl"
    assert main(["play", str(folder / "tiny.toml"), "--seed", "1", "--size", "96x64", "-o", str(video),
                 "--labels", str(labels)]) == 0
    ours, theirs = read_frames(out / "tiny_s1.mp4"), read_frames(video)
    assert len(ours) == len(theirs) == 8
    assert all(np.array_equal(a, b) for a, b in zip(ours, theirs))
    assert (out / "tiny_s1.labels.jsonl").read_text() == labels.read_text()
    assert not np.array_equal(read_frames(out / "tiny_s2.mp4")[-1], theirs[-1])  # another seed, other frames
