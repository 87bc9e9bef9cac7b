"""crowd_ik.prepared: a prepared launch gives what the ordinary launch gives, follows new arrays and scalars,
and drops the contexts of arrays that died."""

import gc

import numpy as np

from crowd_ik import runtime
from crowd_ik.prepared import Prepared


def _separate_inputs(rng, m=60):
    pts = rng.uniform(-4.0, 4.0, (m, 2)).astype(np.float32)
    radius = rng.uniform(0.2, 0.4, m).astype(np.float32)
    kind = rng.choice([0, 1, 1, 2], m).astype(np.int32)
    order = np.arange(m, dtype=np.int32)
    start = np.array([0, m], np.int32)  # one cell holds everybody
    return pts, radius, kind, order, start


def test_prepared_launch_matches_the_ordinary_one_as_inputs_change():
    runtime.ensure_init()
    from crowd_ik.kernels import gait_kernels as gk

    rng = np.random.default_rng(0)
    pts, radius, kind, order, start = _separate_inputs(rng)
    steer, push = np.zeros_like(pts), np.zeros_like(pts)
    launch = Prepared(gk.separate)
    for k in range(5):
        pts[:] = rng.uniform(-4.0, 4.0, pts.shape)  # the same buffers, new values; the scalar reach changes too
        reach = 0.8 + 0.1 * k
        launch(pts, radius, kind, order, start, -4.0, -4.0, 8.0, 1, 1, reach, steer, push, True)
        got = steer.copy(), push.copy()
        steer[:] = push[:] = np.nan
        gk.separate(pts, radius, kind, order, start, -4.0, -4.0, 8.0, 1, 1, reach, steer, push, True)
        np.testing.assert_array_equal(got[0], steer)
        np.testing.assert_array_equal(got[1], push)
    assert len(launch._contexts) == 1  # bound on the second call, launched prepared from then on


def test_prepared_launch_follows_other_arrays_and_forgets_dead_ones():
    runtime.ensure_init()
    from crowd_ik.kernels import gait_kernels as gk

    rng = np.random.default_rng(1)
    launch = Prepared(gk.separate)
    alive = []  # both array sets stay alive until they are deleted below
    for _ in range(2):
        pts, radius, kind, order, start = _separate_inputs(rng)
        steer, push = np.zeros_like(pts), np.zeros_like(pts)
        alive.append((pts, radius, kind, order, start, steer, push))
        want_s, want_p = np.zeros_like(pts), np.zeros_like(pts)
        for _ in range(3):
            launch(pts, radius, kind, order, start, -4.0, -4.0, 8.0, 1, 1, 1.1, steer, push, False)
        gk.separate(pts, radius, kind, order, start, -4.0, -4.0, 8.0, 1, 1, 1.1, want_s, want_p, False)
        np.testing.assert_array_equal(steer, want_s)
        np.testing.assert_array_equal(push, want_p)
    assert len(launch._contexts) == 2
    del pts, steer, push, alive
    gc.collect()
    # a context is dropped as soon as one of its arrays dies (both sets are gone by now), and a
    # fresh array set still works
    assert not launch._contexts
    pts = rng.uniform(-4.0, 4.0, (len(radius), 2)).astype(np.float32)
    steer, push = np.zeros_like(pts), np.zeros_like(pts)
    for _ in range(3):
        launch(pts, radius, kind, order, start, -4.0, -4.0, 8.0, 1, 1, 1.1, steer, push, False)
    want_s, want_p = np.zeros_like(pts), np.zeros_like(pts)
    gk.separate(pts, radius, kind, order, start, -4.0, -4.0, 8.0, 1, 1, 1.1, want_s, want_p, False)
    np.testing.assert_array_equal(push, want_p)


def test_prepared_launch_on_taichi_ndarrays_sees_their_new_values():
    """ti.ndarray arguments are bound by their host address once: launches after other kernels wrote the ndarrays
    (from_numpy, an ordinary launch of another kernel) read and write the same memory as ordinary launches."""
    runtime.ensure_init()
    import taichi as ti

    from crowd_ik.kernels import gait_kernels as gk

    rng = np.random.default_rng(2)
    pts, radius, kind, order, start = _separate_inputs(rng)
    m = len(pts)
    pts_nd = ti.ndarray(ti.math.vec2, m)
    push_nd = ti.ndarray(ti.math.vec2, m)
    steer = np.zeros_like(pts)
    launch = Prepared(gk.separate)
    for k in range(4):
        pts_nd.from_numpy(rng.uniform(-4.0, 4.0, pts.shape).astype(np.float32))
        push_nd.fill(7.0)  # stale values the launch must overwrite
        launch(pts_nd, radius, kind, order, start, -4.0, -4.0, 8.0, 1, 1, 1.0, steer, push_nd, False)
        got_s, got_p = steer.copy(), push_nd.to_numpy()
        want_s, want_p = np.zeros_like(pts), np.zeros_like(pts)
        gk.separate(pts_nd.to_numpy(), radius, kind, order, start, -4.0, -4.0, 8.0, 1, 1, 1.0, want_s, want_p, False)
        np.testing.assert_array_equal(got_s, want_s)
        np.testing.assert_array_equal(got_p, want_p)
        assert np.any(got_p != 7.0)
    assert len(launch._contexts) == 1
