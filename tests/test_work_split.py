"""kernels/work_split.py: banded loops visit every item once, and a loop over few heavy items spread by
spread_stride runs on more than one thread (the Taichi behaviour the lane kernels are built around)."""

import numpy as np
import pytest


@pytest.fixture(scope="module")
def kernels():
    import taichi as ti

    from crowd_ik.kernels.work_split import banded_count, banded_item, skipped, spread_stride

    @ti.kernel
    def visit(n: ti.i32, seen: ti.types.ndarray(dtype=ti.i32, ndim=1)):
        for slot in range(banded_count(n)):
            item = banded_item(slot, n)
            if item >= n:
                continue
            ti.atomic_add(seen[item], 1)

    @ti.kernel
    def threads_of(n: ti.i32, thread: ti.types.ndarray(dtype=ti.i32, ndim=1), out: ti.types.ndarray(ndim=1)):
        stride = spread_stride(n)
        for slot in range(n * stride):
            if skipped(slot, stride):
                continue
            s = slot // stride
            thread[s] = ti.global_thread_idx()
            x = 1.0 + 1e-3 * s
            for _ in range(500000):  # (~2 ms: a second thread wakes before the first is done)
                x = ti.sqrt(x + 1.0)
            out[s] = x

    @ti.kernel
    def threads_plain(n: ti.i32, thread: ti.types.ndarray(dtype=ti.i32, ndim=1), out: ti.types.ndarray(ndim=1)):
        for s in range(n):
            thread[s] = ti.global_thread_idx()
            x = 1.0 + 1e-3 * s
            for _ in range(500000):
                x = ti.sqrt(x + 1.0)
            out[s] = x

    return visit, threads_of, threads_plain


@pytest.mark.parametrize("n", [1, 2, 15, 16, 17, 45, 360, 721, 4096])
def test_banded_loop_visits_every_item_once(kernels, n):
    visit = kernels[0]
    seen = np.zeros(n, dtype=np.int32)
    visit(n, seen)
    np.testing.assert_array_equal(seen, np.ones(n, dtype=np.int32))


def test_banded_item_interleaves_bands():
    """Each quarter of a banded loop's iterations (a thread's block on 4 threads) holds items from every
    sixteenth of the range (the pure-Python twin of banded_item, used by no product code)."""
    from crowd_ik.kernels.work_split import BANDS

    n = 720
    q = (n + BANDS - 1) // BANDS
    items = np.array([(k % BANDS) * q + k // BANDS for k in range(q * BANDS)])
    for block in np.array_split(items, 4):
        assert set(block[block < n] // q) == set(range(BANDS))


def test_few_heavy_items_spread_by_stride_use_several_threads(kernels):
    import taichi as ti

    _, threads_of, threads_plain = kernels
    if ti.lang.impl.current_cfg().cpu_max_num_threads < 2:
        pytest.skip("one CPU thread")
    n = 8
    spread, plain = np.full(n, -1, dtype=np.int32), np.full(n, -1, dtype=np.int32)
    out = np.zeros(n, dtype=np.float32)
    threads_plain(n, plain, out)
    for _ in range(5):  # (a loaded machine may wake the second thread late: it then finds no block left)
        threads_of(n, spread, out)
        if len(set(spread)) >= 2:
            break
    assert len(set(spread)) >= 2, spread
    # the reason for spread_stride: the plain loop's 8 items fall in one block, one thread (if Taichi ever hands
    # them out one by one, this fails and spread_stride can go)
    assert len(set(plain)) == 1, plain


@pytest.mark.parametrize("n", [1, 7, 100, 8191, 8192, 10000])
def test_spread_loop_visits_every_item_once(n):
    import taichi as ti

    from crowd_ik.kernels.work_split import SPREAD_ITEMS, skipped, spread_stride

    @ti.kernel
    def visit(n: ti.i32, seen: ti.types.ndarray(dtype=ti.i32, ndim=1)) -> ti.i32:
        stride = spread_stride(n)
        for slot in range(n * stride):
            if skipped(slot, stride):
                continue
            ti.atomic_add(seen[slot // stride], 1)
        return n * stride

    seen = np.zeros(n, dtype=np.int32)
    iterations = visit(n, seen)
    np.testing.assert_array_equal(seen, np.ones(n, dtype=np.int32))
    assert iterations >= SPREAD_ITEMS and (n < SPREAD_ITEMS or iterations == n) and iterations < 2 * SPREAD_ITEMS
