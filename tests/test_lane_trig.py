"""kernels/lane_trig.py against NumPy in float64: dense grids and edge cases, on 8-lane vectors and on scalars."""

import numpy as np
import pytest

L = 8
TINY = np.float32(1.17549435e-38)  # the smallest normal float32


@pytest.fixture(scope="module")
def trig():
    return make_runner()


def make_runner():
    """run(x, y) -> dict of the functions on float32 inputs: 8-lane vector code, and scalar code for a check."""
    import taichi as ti

    from crowd_ik.kernels import lane_trig as lt

    V = ti.types.vector(L, ti.f32)

    @ti.func
    def every_function(x, y, out: ti.template(), i):
        s, c = lt.sin_cos(x)
        out[i, 0], out[i, 1] = s, c
        out[i, 2], out[i, 3] = lt.sin(x), lt.cos(x)
        out[i, 4], out[i, 5] = lt.asin(x), lt.acos(x)
        out[i, 6] = lt.atan2(y, x)

    @ti.kernel
    def lanes(x: ti.types.ndarray(dtype=V, ndim=1), y: ti.types.ndarray(dtype=V, ndim=1),
              out: ti.types.ndarray(dtype=V, ndim=2)):
        for i in range(x.shape[0]):
            every_function(x[i], y[i], out, i)

    @ti.kernel
    def scalars(x: ti.types.ndarray(ndim=1), y: ti.types.ndarray(ndim=1), out: ti.types.ndarray(ndim=2)):
        for i in range(x.shape[0]):
            every_function(x[i], y[i], out, i)

    names = ("sin_cos.sin", "sin_cos.cos", "sin", "cos", "asin", "acos", "atan2")

    def run(x, y=None, scalar=False):
        x = np.asarray(x, np.float32).ravel()
        y = np.zeros_like(x) if y is None else np.asarray(y, np.float32).ravel()
        n = len(x)
        if scalar:
            out = np.zeros((n, len(names)), np.float32)
            scalars(x, y, out)
            return dict(zip(names, out.T))
        m = -(-n // L) * L
        xp, yp = np.zeros(m, np.float32), np.zeros(m, np.float32)
        xp[:n], yp[:n] = x, y
        out = np.zeros((m // L, len(names), L), np.float32)
        lanes(xp.reshape(-1, L), yp.reshape(-1, L), out)
        return {k: out[:, j, :].ravel()[:n] for j, k in enumerate(names)}

    return run


def ulps(got, true):
    """|got - true| in float32 ulps of the true value (of the smallest normal for results below it)."""
    _m, e = np.frexp(np.maximum(np.abs(true), float(TINY)))  # in float64: Taichi's threads flush float32 denormals
    unit = np.ldexp(1.0, e - 24)
    return np.abs(got.astype(np.float64) - true) / unit


def test_sin_cos_within_3_ulp_over_the_exact_range(trig):
    from crowd_ik.kernels.lane_trig import TRIG_RANGE

    kk = np.concatenate([np.arange(-3000, 3001), np.linspace(-2**17 + 1, 2**17 - 1, 6001).round()])
    x = np.concatenate([np.linspace(-4.0, 4.0, 300_001), np.linspace(-TRIG_RANGE, TRIG_RANGE, 300_001),
                        np.pi / 2 * kk]).astype(np.float32)  # the float32 nearest k pi/2: tiny results
    got = trig(x)
    x64 = x.astype(np.float64)
    for name, f in (("sin", np.sin), ("cos", np.cos)):
        assert ulps(got[name], f(x64)).max() <= 3.0, name
        np.testing.assert_array_equal(got[name], got[f"sin_cos.{name}"])


def test_sin_cos_far_out_stays_close_and_bounded(trig):
    x = np.concatenate([np.linspace(-1e6, 1e6, 200_001), np.pi / 2 * np.arange(2**19, 2**19 + 1000), [1e20, -3e38,
                        3.4e38, 1e9]]).astype(np.float32)
    got = trig(x)
    x64 = x.astype(np.float64)
    near = np.abs(x64) <= 1e6
    for name, f in (("sin", np.sin), ("cos", np.cos)):
        true = f(x64[near])
        # the float64 reduction's rounding, about |x| 1e-16, on top of 3 ulp
        assert np.all(np.abs(got[name][near] - true) <= 3 * np.abs(true) * 2.0**-23 + 2e-16 * np.abs(x64[near])), name
        assert np.all(np.isfinite(got[name])) and np.all(np.abs(got[name]) <= 1.0), name


def test_sin_cos_edges(trig):
    x = np.array([0.0, -0.0, 1e-30, -1e-30, 1e-40, -1e-45, np.pi, -np.pi, np.pi / 2, -np.pi / 2, 2 * np.pi,
                  np.pi / 4, -np.pi / 4, 1.0, -1.0], np.float32)
    got = trig(x)
    x64 = x.astype(np.float64)
    for name, f in (("sin", np.sin), ("cos", np.cos)):
        err = np.abs(got[name] - f(x64))
        assert np.all((ulps(got[name], f(x64)) <= 3.0) | (err <= TINY)), (name, got[name], f(x64))
    assert got["cos"][0] == 1.0 and got["sin"][0] == 0.0


def test_asin_acos_within_3_ulp(trig):
    x = np.concatenate([np.linspace(-1.0, 1.0, 800_001), 1.0 - np.logspace(-7.5, -1, 2001), [0.5, -0.5, 1.0, -1.0, 0.0,
                        1e-30, -1e-40]]).astype(np.float32)
    x = np.concatenate([x, -x])
    got = trig(x)
    x64 = x.astype(np.float64)
    for name, f in (("asin", np.arcsin), ("acos", np.arccos)):
        err = np.abs(got[name] - f(x64))
        assert np.all((ulps(got[name], f(x64)) <= 3.0) | (err <= TINY)), name
    assert got["acos"][x == 1.0].max() == 0.0 and got["asin"][x == 0.0].max() == 0.0


def test_asin_acos_outside_the_domain_are_nan(trig):
    got = trig([1.0001, -1.5, 7.0])
    assert np.all(np.isnan(got["asin"])) and np.all(np.isnan(got["acos"]))


def test_atan2_within_3_ulp_in_every_quadrant(trig):
    rng = np.random.default_rng(0)
    t = rng.uniform(-np.pi, np.pi, 400_000)
    r = np.exp(rng.uniform(-20, 20, t.shape))
    angles = np.pi / 8 * np.arange(-8, 9)  # octant borders: tan(pi/8) reduction, |x| = |y|, axes
    t = np.concatenate([t, angles, angles + 1e-6, angles - 1e-6])
    r = np.concatenate([r, np.ones(3 * len(angles))])
    x, y = (r * np.cos(t)).astype(np.float32), (r * np.sin(t)).astype(np.float32)
    got = trig(x, y)["atan2"]
    true = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    assert ulps(got, true).max() <= 3.0


def test_atan2_axes_zero_and_extremes(trig):
    x = np.array([0, 1, -1, 0, 0, 3e38, -3e38, 1e-40, 1e-38, 2.0, -2.0, 1e-30, 5.0], np.float32)
    y = np.array([0, 0, 0, 1, -1, 3e38, 1e-38, 1e-40, -1e-40, 1e30, -1e30, 1e30, -5.0], np.float32)
    got = trig(x, y)["atan2"]
    true = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    err = np.abs(got - true)
    assert np.all((ulps(got, true) <= 3.0) | (err <= 2 * TINY)), (got, true)
    assert got[0] == 0.0 and got[2] == np.float32(np.pi)  # (0, 0) -> 0; the sign of a zero is ignored


def test_scalar_code_gives_the_vector_code_results(trig):
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.uniform(-20, 20, 4000), rng.uniform(-1, 1, 4000)]).astype(np.float32)
    y = rng.normal(size=x.shape).astype(np.float32)
    vec, one = trig(x, y), trig(x, y, scalar=True)
    for name in vec:
        np.testing.assert_allclose(vec[name], one[name], rtol=3e-7, atol=1e-37, err_msg=name)


CACHE_KEY_SCRIPT = '''
import sys
import crowd_ik
crowd_ik.init(arch="cpu", cache_dir=sys.argv[1])
import taichi as ti
from crowd_ik.kernels import lane_trig as lt
V = ti.types.vector(4, ti.f32)

@ti.kernel
def every_function(x: ti.types.ndarray(dtype=V, ndim=1), out: ti.types.ndarray(dtype=V, ndim=1)):
    for i in range(x.shape[0]):
        s, c = lt.sin_cos(x[i])
        out[i] = s + c + lt.atan2(s, c) + lt.asin(0.5 * s) + lt.acos(0.5 * c)

x = ti.ndarray(V, 2)
out = ti.ndarray(V, 2)
every_function(x, out)
'''


def test_a_kernel_calling_every_lane_function_gets_the_same_cache_key_in_every_process(tmp_path):
    """Fresh processes with fresh offline caches write the same cache file names for the same kernel: Taichi 1.7.4
    serialises a kernel's real functions in address order, so with one per operation the key changed from run to
    run (lane_trig's note) and a warm cache missed."""
    import subprocess
    import sys

    script = tmp_path / "every_function.py"
    script.write_text(CACHE_KEY_SCRIPT)
    names = []
    for run in range(4):
        cache = tmp_path / f"cache{run}"
        done = subprocess.run([sys.executable, str(script), str(cache)], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        names.append(sorted(p.name for p in cache.rglob("*.tic")))
    assert names[0], "the kernel wrote nothing to its offline cache"
    assert all(n == names[0] for n in names), names
