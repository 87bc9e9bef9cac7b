"""`crowd-ik bench`: option checks, seeded workloads, the NumPy baseline, and a tiny end-to-end run (JSON, PNG, --compare)."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from crowd_ik.bench import baseline, options, report, workloads
from crowd_ik.commands.cli import main

TINY = ["bench", "--quick", "--chars", "50,200", "--rig", "chain16,humanoid", "--solver", "fabrik", "--repeats", "1",
        "--baseline-budget", "0.5", "--game-chars", "32"]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """One small full run through the CLI (a child process on the CPU), shared by the tests below."""
    folder = tmp_path_factory.mktemp("bench")
    out_json, out_png = folder / "run.json", folder / "run.png"
    code = main(TINY + ["--json", str(out_json), "--plot", str(out_png)])
    assert code == 0
    return folder, json.loads(out_json.read_text()), out_png


def _err_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    return err[-1] if err else ""


# ------------------------------------------------------------------------------------------------ options

@pytest.mark.parametrize("flag,value,expect", [
    ("--chars", "abc", "--chars: expected comma-separated positive integers (got 'abc')"),
    ("--chars", "0", "--chars: expected positive integers (got 0)"),
    ("--chars", "10,-5", "(got -5)"), ("--chars", "10,,20", "(got '10,,20')"), ("--chars", "", "--chars"),
    ("--chars", "1000000000", "GiB"), ("--solver", "fabrik,newton", "--solver: expected some of fabrik,dls,ccd (got 'newton')"),
    ("--solver", "", "--solver"), ("--rig", "spider", "--rig: expected some of chain16,humanoid (got 'spider')"),
    ("--arch", "tpu", "--arch"), ("--threads", "0", "--threads"), ("--repeats", "0", "--repeats"),
    ("--baseline-budget", "-1", "--baseline-budget"), ("--game-chars", "-3", "--game-chars"),
])
def test_bad_values_exit_2_with_one_line(capsys, tmp_path, flag, value, expect):
    out = tmp_path / "never.json"
    assert main(["bench", "--quick", flag, value, "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("crowd-ik: ") and expect in err
    assert not out.exists()


def test_quick_changes_only_defaults():
    args = type("A", (), dict(quick=True, chars="7,3,7", solver=None, rig="humanoid", arch=None, threads=None,
                              repeats=None, baseline_budget=None, game_chars=None))()
    opts = options.resolve_options(args)
    assert opts.chars == (3, 7) and opts.rigs == ("humanoid",)  # explicit flags win, sorted and deduplicated
    assert opts.solvers == options.QUICK["solvers"] and opts.repeats == 1 and opts.budget == options.QUICK["budget"]
    args.quick, args.chars, args.rig = False, None, None
    full = options.resolve_options(args)
    assert full.chars == (100, 1000, 10000, 100000) and full.solvers == ("fabrik", "dls", "ccd")
    assert full.rigs == ("chain16", "humanoid") and full.repeats >= 3


def test_cuda_refused_without_gpu(tmp_path):
    if options.cuda_available():
        pytest.skip("this machine has a CUDA GPU")
    out = tmp_path / "x.json"
    proc = subprocess.run([sys.executable, "-m", "crowd_ik", "bench", "--quick", "--arch", "cuda", "--json", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == "" and not out.exists()
    assert proc.stderr.splitlines() == ["crowd-ik: --arch cuda: no CUDA GPU is available to Taichi on this machine"]
    assert options.resolve_arches(()) == ("cpu",)


def test_cuda_default_sweep_adds_a_million_chain16_characters():
    args = type("A", (), dict(quick=False, chars=None, solver="fabrik", rig=None, arch=None, threads=None,
                              repeats=None, baseline_budget=None, game_chars=None))()
    opts = options.resolve_options(args)
    cuda = options.cells_for(opts, "cuda")
    assert ("chain16", "fabrik", 1_000_000) in cuda and ("humanoid", "fabrik", 1_000_000) not in cuda
    assert all(n <= 100_000 for _, _, n in options.cells_for(opts, "cpu"))


def test_existing_outputs_are_not_clobbered(capsys, tmp_path):
    old = tmp_path / "old.json"
    old.write_text("keep me")
    assert main(["bench", "--quick", "--json", str(old)]) == 2
    assert "exists" in _err_line(capsys) and old.read_text() == "keep me"
    png = tmp_path / "old.png"
    png.write_bytes(b"keep")
    assert main(["bench", "--quick", "--json", str(tmp_path / "new.json"), "--plot", str(png)]) == 2
    assert png.read_bytes() == b"keep" and not (tmp_path / "new.json").exists()
    assert main(["bench", "--quick", "--plot", str(tmp_path / "chart.jpg")]) == 2
    assert "--plot" in _err_line(capsys)


def test_compare_file_is_checked_before_running(capsys, tmp_path):
    assert main(["bench", "--quick", "--compare", str(tmp_path / "missing.json")]) == 2
    assert "missing.json" in _err_line(capsys)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"records": [{"rig": "chain16"}]}))
    assert main(["bench", "--quick", "--compare", str(bad)]) == 2
    assert "not a crowd-ik bench JSON" in _err_line(capsys)


# ------------------------------------------------------------------------------------------------ workloads

@pytest.mark.parametrize("name", options.RIGS)
def test_workload_prefix_is_the_smaller_workload(name):
    big, small = workloads.make_workload(name, 300, 40), workloads.make_workload(name, 40)
    assert big.n == small.n == 40
    np.testing.assert_array_equal(big.angles, small.angles)
    np.testing.assert_allclose(big.targets - big.roots[:, None], small.targets - small.roots[:, None], atol=2e-5)
    again = workloads.make_workload(name, 300, 40)
    np.testing.assert_array_equal(big.targets, again.targets)


def test_chain16_workload_targets_fill_the_ball():
    wl = workloads.make_workload("chain16", 4000)
    reach = wl.rig.reach[0]
    r = np.linalg.norm(wl.targets[:, 0] - wl.roots, axis=1)
    assert reach == pytest.approx(1.6) and wl.tolerance == pytest.approx(1.6e-3)
    assert r.max() <= 0.9 * reach + 1e-5 and r.max() > 0.85 * reach
    # uniform in a ball: the fraction inside half the radius is 1/8
    assert np.mean(r < 0.45 * reach) == pytest.approx(0.125, abs=0.02)
    assert np.all(wl.angles == 0)


def test_humanoid_workload_starts_in_limits_with_nearby_targets():
    from crowd_ik.geometry.fk import forward_kinematics

    wl = workloads.make_workload("humanoid", 500)
    lo, hi = wl.rig.angle_limits()
    assert np.all(wl.angles >= lo - 1e-6) and np.all(wl.angles <= hi + 1e-6)
    pos, _ = forward_kinematics(wl.rig, wl.roots.astype(np.float64), np.zeros(wl.n), wl.rotations())
    moved = np.linalg.norm(wl.targets - pos[:, wl.rig.arrays["eff_joint"]], axis=-1)
    assert moved.max() <= 0.3 + 1e-5 and moved.mean() > 0.15
    assert wl.tolerance == pytest.approx(5e-3) and wl.targets.shape == (500, 5, 3)


@pytest.mark.parametrize("name", ["chain16", "humanoid"])
def test_reachable_flags_match_the_crowds_unreachable_status(name):
    from crowd_ik import Crowd, Status

    wl = workloads.make_workload(name, 200)
    crowd = Crowd(wl.rig, wl.n, spacing=options.SPACING)
    positions, yaw = crowd.roots()
    assert np.allclose(positions, wl.roots) and not np.any(yaw)
    crowd.set_angles(wl.angles)
    report = crowd.solve(wl.targets, method="fabrik", max_iterations=1, tolerance=wl.tolerance)
    reachable = workloads._reachable(wl)
    assert 0 < reachable.sum() < wl.n or name == "chain16"
    # a converged character is reachable too, so compare against "not UNREACHABLE"
    assert np.array_equal(reachable, report.status != Status.UNREACHABLE)


def test_crowd_bytes_grow_per_character():
    from crowd_ik import Crowd, Rig

    rig = Rig.chain(16, 0.1, dim=3)
    one, two = workloads.crowd_bytes(Crowd(rig, 10)), workloads.crowd_bytes(Crowd(rig, 20))
    assert two == 2 * one
    assert one >= 10 * rig.n_joints * (3 + 4 + 4 + 3) * 4  # root, local/world rotations, positions at least


def test_crowd_bytes_count_each_array_once():
    """The free FABRIK lanes keep their plan (solvers/fabrik_free.py), which holds the crowd's scratch arrays:
    the measured memory is the same with or without it."""
    from crowd_ik import Crowd, Rig

    rig = Rig.chain(16, 0.1, dim=3)
    crowd = Crowd(rig, 40, spacing=2.0)
    crowd.solve(crowd.effector_positions() + np.float32([0.3, -0.2, 0.1]), method="fabrik")
    total = workloads.crowd_bytes(crowd)
    assert crowd.__dict__.pop("_fabrik_free_plans")
    assert workloads.crowd_bytes(crowd) == total


def test_baseline_full_cell_and_budget():
    base = baseline.Baseline(repeats=2, budget=30.0)
    assert base.measure("chain16", "fabrik", 30) == 30
    got = base.summary("chain16", "fabrik", 30)
    assert got["numpy_reachable_rate"] == 1.0 and got["numpy_success_rate_reachable"] == 1.0
    assert got["numpy_n"] == 30 and got["numpy_repeats"] == 2
    assert got["numpy_success_rate"] == 1.0 and got["numpy_solves_per_s"] == pytest.approx(30 / got["numpy_time_s"])
    starved = baseline.Baseline(repeats=3, budget=1e-6)
    assert starved.measure("chain16", "fabrik", 5000) == options.BASELINE_PROBE
    assert starved.summary("chain16", "fabrik", options.BASELINE_PROBE)["numpy_repeats"] == 1
    # a later cell on the same subset reuses the earlier run
    assert starved.measure("chain16", "fabrik", 7000) == options.BASELINE_PROBE
    assert starved.summary("chain16", "fabrik", options.BASELINE_PROBE)["numpy_repeats"] == 1
    assert baseline.Baseline(repeats=1, budget=0.0).measure("chain16", "fabrik", 30) is None


def test_baseline_counts_reachable_humanoids_from_the_pelvis():
    # the humanoid's root joint is ~1 m above its root: measured from the root, none of them was reachable
    base = baseline.Baseline(repeats=1, budget=1e-6)
    m = base.measure("humanoid", "fabrik", 1000)
    got = base.summary("humanoid", "fabrik", m)
    reachable = workloads._reachable(workloads.make_workload("humanoid", 1000, m))
    assert 0.1 < got["numpy_reachable_rate"] == np.mean(reachable) < 0.9  # measured 0.28 of the first 100
    # the converged reachable ones are some of the converged (a target past reach by under the tolerance converges)
    assert 0 < got["numpy_reachable_rate"] * got["numpy_success_rate_reachable"] <= got["numpy_success_rate"] + 1e-12


# ------------------------------------------------------------------------------------------------ end to end

def test_run_writes_json_with_meta_and_records(tiny_run):
    _, data, _ = tiny_run
    meta = data["meta"]
    for key in ("cpu_model", "cores", "threads", "python", "numpy", "taichi", "arches", "settings", "command"):
        assert key in meta
    assert [a["resolved"] for a in meta["arches"]] == ["cpu"] and meta["arches"][0]["taichi_threads"] >= 1
    from crowd_ik.solvers import settings

    arch = meta["arches"][0]  # the lane widths the cells ran with (the bench's child process chose them alike)
    assert (arch["lanes"], arch["limited_lanes"], arch["general_lanes"]) == (
        settings.lanes(), settings.limited_lanes(), settings.general_lanes())
    cells = {(r["arch"], r["rig"], r["solver"], r["n"]) for r in data["records"]}
    assert cells == {("cpu", rig, "fabrik", n) for rig in ("chain16", "humanoid") for n in (50, 200)}
    for r in data["records"]:
        assert 0.0 <= r["success_rate"] <= 1.0 and 0.0 <= r["numpy_success_rate"] <= 1.0
        assert r["solves_per_s"] == pytest.approx(r["n"] / r["time_s"])
        assert r["chain_iterations_per_s"] == pytest.approx(r["solves_per_s"] * r["mean_iterations"], rel=1e-6)
        assert r["speedup"] > 0 and r["speedup"] == pytest.approx(r["solves_per_s"] / r["numpy_solves_per_s"])
        assert 1 <= r["numpy_n"] <= r["n"] and r["repeats"] == 1 and len(r["times_s"]) == 1
        assert r["mean_error"] >= 0 and r["median_error"] <= r["max_error"] and r["compile_s"] >= 0
        assert r["measured_bytes_per_character"] > 0 and sum(r["status_counts"].values()) == r["n"]
    chain = [r for r in data["records"] if r["rig"] == "chain16"]
    for r in chain:  # the same problems on both sides: the twin and the kernel agree on the outcome
        assert r["success_rate"] == r["numpy_success_rate"] == 1.0
        assert abs(r["mean_iterations"] - r["numpy_mean_iterations"]) < 1.0


def test_run_reports_the_game_and_targets(tiny_run):
    _, data, _ = tiny_run
    (game,) = data["game"]
    assert game["n"] == 32 and game["pool_size"] == options.GAME_POOL and game["warm"]["max_iterations"] == 4
    assert game["warm"]["mean_iterations"] <= 4
    # a frame is its solve, capsules and bullets (per frame, so the means add up exactly; medians need not)
    assert game["frame_ms"]["mean"] == pytest.approx(
        game["warm"]["solve_ms"]["mean"] + game["capsules_ms"]["mean"] + game["bullets_ms"]["mean"], rel=1e-9)
    for k in ("frame_ms", "capsules_ms", "bullets_ms"):
        assert 0 < game[k]["median"] <= game[k]["p95"] <= game[k]["max"]
    assert game["fits"] == (game["frame_ms"]["p95"] <= options.FRAME_MS) and game["bullets_alive"] > 0
    assert 0.0 <= game["substepped_share"] <= 1.0 and game["mean_substeps"] >= 1
    names = {t["name"] for t in data["targets"]}
    assert "chain16 fabrik speed-up vs NumPy" in names and any(n.startswith("game frame") for n in names)


def test_game_frames_repeat_from_the_same_start_and_keep_the_lowest_median():
    """Each run does the same work (the same seeds and solves, so the same iterations and hits); the run with the lowest
    median frame is kept, and every run's medians are listed in order."""
    got = workloads.best_game_frames(24, 3, repeats=2)
    assert len(got["runs"]) == 2 and got["frame_ms"]["median"] == min(r["frame_ms"]["median"] for r in got["runs"])
    again = workloads.game_frames(24, 3)
    assert (got["hits"], got["warm"]["mean_iterations"], got["warm"]["mean_error"]) == (
        again["hits"], again["warm"]["mean_iterations"], again["warm"]["mean_error"])
    line = report.format_runs(got["runs"])
    assert "2 runs" in line and all(f"{r['frame_ms']['median']:.2f}" in line for r in got["runs"])
    assert report.format_runs(got["runs"][:1]) == ""


def test_game_scene_times_the_world_as_played():
    sc = workloads.game_scene(6, name="duel", warmup=30)
    assert sc["scene"] == "duel" and sc["steps"] == 6 and sc["warmup_steps"] == 30 and sc["max_iterations"] == 4
    assert 0 < sc["ik_ms"]["median"] and 0 <= sc["bullets_ms"]["median"]
    assert sc["frame_ms"]["max"] <= sc["ik_ms"]["max"] + sc["bullets_ms"]["max"] + 1e-9
    assert sc["step_ms"]["median"] >= sc["ik_ms"]["median"]  # the whole step holds both phases
    assert 0.0 < sc["solving"] <= 1.0 and 0.0 < sc["mean_iterations"] <= 4.0
    assert sc["fits"] == (sc["frame_ms"]["p95"] <= options.FRAME_MS)
    line = report.format_scene(sc)
    assert "as played, duel scene" in line and ("fits" in line or "does NOT fit" in line)
    names = [t["name"] for t in report.evaluate_targets([], [dict(arch="cpu", n=4, frame_ms=dict(p95=1.0), fits=True,
                                                                 scene=sc)])]
    assert any(n.startswith("game step as played, duel scene") for n in names)
    # the median frame (issue 13's target) and the p95 (the frame budget) each get a row, judged on their own value
    rows = report.evaluate_targets([], [dict(arch="cpu", n=4, frame_ms=dict(median=10.0, p95=20.0), fits=False)])
    met = {t["name"].rsplit(", ", 1)[1]: t["met"] for t in rows}
    assert met == {"median ms": True, "p95 ms": False}


def test_plot_is_a_valid_png(tiny_run):
    _, _, png = tiny_run
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] >= 300 and img.shape[1] >= 600
    assert img.std() > 10  # something was drawn
    assert not [p for p in png.parent.iterdir() if ".tmp-" in p.name]


def test_compare_prints_changes(tiny_run, capsys):
    folder, _, _ = tiny_run
    capsys.readouterr()
    code = main(["bench", "--quick", "--chars", "50", "--rig", "chain16", "--solver", "fabrik", "--game-chars", "0",
                 "--baseline-budget", "0", "--compare", str(folder / "run.json")])
    assert code == 0
    out = capsys.readouterr().out
    assert "change against" in out and "only in" in out
    section = out[out.index("change against"):].splitlines()
    row = [line for line in section if line.strip().startswith("cpu") and "%" in line]
    assert len(row) == 1 and "chain16" in row[0] and "fabrik" in row[0] and " 50 " in row[0]


def test_compare_lines_compute_the_change():
    rec = dict(arch="cpu", rig="chain16", solver="dls", n=1000)
    old = dict(records=[dict(rec, solves_per_s=100.0, speedup=10.0), dict(rec, n=10, solves_per_s=5.0)],
               game=[dict(arch="cpu", n=10, frame_ms=dict(median=20.0),
                          scene=dict(scene="stress_10k", frame_ms=dict(p95=20.0)))])
    new = dict(records=[dict(rec, solves_per_s=150.0, speedup=12.0)],
               game=[dict(arch="cpu", n=10, frame_ms=dict(median=10.0),
                          scene=dict(scene="stress_10k", frame_ms=dict(p95=15.0)))])
    text = "\n".join(report.compare_lines(old, new))
    assert "+50.0%" in text and "10.0x -> 12.0x" in text and "only in OLD: cpu chain16 dls N=10" in text
    assert "20.00 ms -> 10.00 ms (-50.0%)" in text
    assert "stress_10k as played: IK + bullets p95 20.00 ms -> 15.00 ms (-25.0%)" in text
