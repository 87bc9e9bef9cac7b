"""Same inputs, same N, same machine: the same bits at 1 and at 2 threads, for every solver."""

import subprocess
import sys

import numpy as np
import pytest

SCRIPT = r"""
import sys, numpy as np, crowd_ik as cik
cik.init(arch="cpu", threads=int(sys.argv[1]))
out = {}
for method in sys.argv[3].split(","):
    for name, rig in (("chain", cik.Rig.chain(16, 0.1, dim=3)), ("humanoid", cik.Rig.humanoid())):
        n = 2000
        crowd = cik.Crowd(rig, n=n, spacing=2.0)
        rng = np.random.default_rng(1)
        lo, hi = rig.angle_limits()
        lo, hi = np.clip(lo, -1, 1), np.clip(hi, -1, 1)
        crowd.set_angles((rng.uniform(lo, hi, (n, rig.n_dof)) * 0.5).astype(np.float32))
        targets = crowd.effector_positions() + rng.normal(size=(n, rig.n_effectors, 3)).astype(np.float32) * 0.1
        crowd.set_angles(np.zeros(rig.n_dof, np.float32))
        rep = crowd.solve(targets, method=method, max_iterations=30, tolerance=1e-3)
        out[f"{method}_{name}_rot"] = crowd.rotations()
        out[f"{method}_{name}_err"] = rep.error
        out[f"{method}_{name}_it"] = rep.iterations
np.savez(sys.argv[2], **out)
"""


METHODS = ("fabrik", "dls", "ccd")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every solver's results from one process at 1 thread and one at 2 (the second loads the first's kernels from
    the offline cache)."""
    folder = tmp_path_factory.mktemp("determinism")
    files = []
    for threads in (1, 2):
        path = folder / f"t{threads}.npz"
        proc = subprocess.run([sys.executable, "-c", SCRIPT, str(threads), str(path), ",".join(METHODS)],
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        files.append(np.load(path))
    return files


@pytest.mark.parametrize("method", METHODS)
def test_one_and_two_threads_give_identical_bits(runs, method):
    a, b = runs
    keys = [k for k in a.files if k.startswith(method + "_")]
    assert set(a.files) == set(b.files) and len(keys) == 6
    for key in keys:
        assert np.array_equal(a[key], b[key]), key
