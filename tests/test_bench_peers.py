"""The numba peers of `crowd-ik bench --peers numba`: correct solvers, filled records, the ratio targets."""

import numpy as np
import pytest

pytest.importorskip("numba")

from crowd_ik.bench import peers as bench_peers, workloads  # noqa: E402


def _chain_start(n, J=17, bone=0.1):
    start = np.zeros((n, J, 3))
    start[:, :, 0] = np.arange(J) * bone
    return start


@pytest.mark.parametrize("method", ["fabrik", "dls"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_peers_reach_reachable_targets_and_keep_bone_lengths(method, dtype):
    rng = np.random.default_rng(3)
    n = 64
    d = rng.normal(size=(n, 3))
    targets = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.2, 1.4, (n, 1))
    out = bench_peers.solve(method, _chain_start(n), targets, 1.6e-3, 100, dtype)
    tip = out["positions"][:, -1]
    err = np.linalg.norm(tip - targets, axis=1)
    assert np.mean(out["error"] <= 1.6e-3) >= 0.95
    np.testing.assert_allclose(out["error"], err, atol=1e-4)  # the error it reports is the tip's
    bones = np.linalg.norm(np.diff(out["positions"], axis=1), axis=-1)
    np.testing.assert_allclose(bones, 0.1, atol=1e-4 if dtype == np.float32 else 1e-9)
    np.testing.assert_allclose(out["positions"][:, 0], 0.0, atol=1e-12)  # the root stays
    assert out["iterations"].max() > 1


def test_peer_leaves_the_start_array_alone():
    start = _chain_start(4)
    before = start.copy()
    bench_peers.solve("fabrik", start, np.full((4, 3), 0.5), 1e-3, 10)
    np.testing.assert_array_equal(start, before)


def test_measure_fills_chain16_records_and_targets():
    records = [dict(arch="cpu", rig="chain16", solver="fabrik", n=64, solves_per_s=1e6, success_rate=1.0),
               dict(arch="cpu", rig="chain16", solver="ccd", n=64, solves_per_s=1e6, success_rate=1.0),
               dict(arch="cpu", rig="humanoid", solver="fabrik", n=64, solves_per_s=1e6, success_rate=1.0)]
    filled = bench_peers.measure(records, workloads.make_workload, repeats=1, threads=1)
    assert filled == [records[0]]
    r = records[0]
    assert r["numba_f64_success_rate"] >= 0.95 and r["numba_f64_mean_iterations"] > 1
    assert r["vs_numba_f64"] == pytest.approx(1e6 / r["numba_f64_solves_per_s"])
    assert "numba_f64_solves_per_s" not in records[1] and "numba_f64_solves_per_s" not in records[2]
    text = bench_peers.format_table(records)
    assert "numba f64/s" in text and f"{r['vs_numba_f64']:.2f}x" in text
    (t,) = bench_peers.targets(records, "avx512")
    assert t["goal"] == ">= 3x" and t["met"] == (r["vs_numba_f64"] >= 3.0)
    (t,) = bench_peers.targets(records, "avx2")
    assert t["goal"] == ">= 2x"


def test_peers_flag_is_checked(capsys):
    from crowd_ik.commands.cli import main

    assert main(["bench", "--peers", "julia", "--quick"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--peers" in err[0] and "julia" in err[0]


def test_interleaved_peers_fill_a_cell_and_measure_keeps_them():
    """peers.Interleaved times one run of each peer per call (bench: after each of crowd_ik's timed repeats), fills
    the record from the best of them, and the parent's measure() does not time that record again."""
    wl = workloads.make_workload("chain16", 64)
    peer = bench_peers.Interleaved(wl, "fabrik", threads=1)
    for _ in range(2):
        peer.run_once()
    assert [len(v) for v in peer.runs.values()] == [2, 2]
    r = dict(arch="cpu", rig="chain16", solver="fabrik", n=64, solves_per_s=1e6, success_rate=1.0)
    peer.fill(r)
    best = min(x["time_s"] for x in peer.runs["f64"])
    assert r["numba_interleaved"] and r["numba_f64_solves_per_s"] == pytest.approx(64 / best)
    assert r["vs_numba_f64"] == pytest.approx(1e6 / r["numba_f64_solves_per_s"])
    assert r["numba_f32_success_rate"] >= 0.95
    before = dict(r)
    assert bench_peers.measure([r], workloads.make_workload, repeats=1, threads=1) == [r] and r == before
    assert bench_peers.qualifies("cpu", "chain16", "dls") and not bench_peers.qualifies("cuda", "chain16", "fabrik")
    assert not bench_peers.qualifies("cpu", "humanoid", "fabrik")
