"""kernels/bullet_hits.py's swept sphere-capsule test (cutting planes, then Newton) against the analytic float64
twin (crowd_ik.geometry.sweep.sweep_toi), on random, near-parallel, degenerate and grazing cases."""

import numpy as np
import pytest

from crowd_ik.geometry.sweep import sweep_toi
from crowd_ik.runtime import ensure_init


def _kernel_toi(p0, p1, a, b, r):
    import taichi as ti

    from crowd_ik.kernels.bullet_hits import sweep_sphere_capsule

    ensure_init()
    vec3 = ti.math.vec3

    @ti.kernel
    def sweep(p0: ti.types.ndarray(dtype=vec3, ndim=1), p1: ti.types.ndarray(dtype=vec3, ndim=1),
              a: ti.types.ndarray(dtype=vec3, ndim=1), b: ti.types.ndarray(dtype=vec3, ndim=1),
              r: ti.types.ndarray(ndim=1), out: ti.types.ndarray(ndim=1)):
        for i in range(out.shape[0]):
            out[i] = sweep_sphere_capsule(p0[i], p1[i], a[i], b[i], r[i])

    f32 = [np.ascontiguousarray(x, np.float32) for x in (p0, p1, a, b, r)]
    out = np.zeros(len(r), np.float32)
    sweep(*f32, out)
    return out, f32


def _cases(rng, n):
    """(p0, p1, a, b, r) for n random segment pairs of each kind, concatenated."""
    rnd = lambda *s: rng.uniform(-1, 1, s)  # noqa: E731
    r = rng.uniform(0.05, 0.15, n)
    kinds = []
    kinds.append((rnd(n, 3), rnd(n, 3), rnd(n, 3) * 0.5, rnd(n, 3) * 0.5, r))  # random
    # near-parallel: the bullet flies along the limb's axis, offset about r sideways
    a = rnd(n, 3) * 0.5
    axis = rnd(n, 3)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    side = np.cross(axis, rnd(n, 3))
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    lift = (r * rng.uniform(0.9, 1.1, n))[:, None] * side + rng.normal(0, 1e-3, (n, 3))
    p0 = a - axis * rng.uniform(0.2, 1.0, (n, 1)) + lift
    kinds.append((p0, p0 + axis * rng.uniform(0.3, 2.0, (n, 1)) + rng.normal(0, 1e-3, (n, 3)), a, a + 0.4 * axis, r))
    # degenerate: a point limb (a sphere), and a bullet standing still inside or outside
    c = rnd(n, 3) * 0.5
    kinds.append((rnd(n, 3), rnd(n, 3), c, c, r))
    q = c + rnd(n, 3) * 0.2
    kinds.append((q, q, c, c + rnd(n, 3) * 0.3, r))
    # grazing: the bullet's closest approach to a long limb within 1 % of r either side
    a = np.zeros((n, 3)) + [-1.0, 0.0, 0.0]
    miss = r * rng.uniform(0.99, 1.01, n)
    p0 = np.stack([rng.uniform(-0.5, 0.5, n), miss, -np.ones(n)], axis=1)
    kinds.append((p0, p0 + [0.0, 0.0, 2.0], a, a + [2.0, 0.0, 0.0], r))
    return [np.concatenate(x) for x in zip(*kinds)]


@pytest.mark.parametrize("seed", [0, 1])
def test_sweep_matches_the_analytic_twin(seed):
    got, (p0, p1, a, b, r) = _kernel_toi(*_cases(np.random.default_rng(seed), 400))
    want = sweep_toi(p0, p1, a, b, r)
    # where the answer turns within 1e-5 m of r (a graze float32 cannot settle), either answer is right
    lo, hi = sweep_toi(p0, p1, a, b, r - 1e-5), sweep_toi(p0, p1, a, b, r + 1e-5)
    clear = (lo >= 0) == (hi >= 0)
    assert clear.mean() > 0.98 and (want[clear] >= 0).sum() > 300 and (want[clear] < 0).sum() > 1000
    np.testing.assert_array_equal(got[clear] >= 0, want[clear] >= 0)
    hit = clear & (want >= 0)
    # toi: the entry is within the time it takes to move 1e-5 m there (the entry of r + 1e-5 m, r - 1e-5 m)
    assert np.all((got[hit] >= hi[hit] - 1e-6) & (got[hit] <= np.where(lo[hit] >= 0, lo[hit], 1.0) + 1e-6))
    assert np.all(got[~clear] <= 1.0)  # a graze still gives -1 or a time within the step
