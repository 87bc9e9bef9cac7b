"""How a parallel loop's iterations reach Taichi's CPU threads, and two ways around it.

Taichi 1.7.4's CPU backend cuts a top-level loop of n iterations into blocks of max(512, n / threads)
consecutive iterations, whatever ti.loop_config's block_dim says, and its threads take the blocks in turn
(so in effect one block per thread). Measured with
ti.global_thread_idx() on 2 threads: 16 or 600 iterations of 10 ms each ran on one thread and on 512 + 88;
4,000 on 2,000 + 2,000; and a 65,536-iteration loop whose first half held all the work took as long on two
threads as on one. So:

- a loop over few heavy items (the lane kernels' streams, a small crowd's characters) runs on one
  thread: it loops over n * spread_stride(n) iterations and works on every stride-th;
- a loop whose work is uneven along its index (image rows: sky at the top, the crowd lower down) leaves
  a thread idle: it visits its items in BANDS interleaved bands (banded_count, banded_item), so every
  thread's block holds the same share of each band of the image.
Neither changes what an item computes, so results stay the same bit for bit.
"""

import taichi as ti

SPREAD_ITEMS = 8192  # a loop over fewer heavy items is spread to this many iterations (16 threads' blocks)
BANDS = 16  # bands a banded loop interleaves (a thread's block holds 1/threads of each)


@ti.func
def banded_count(n):
    """The iterations of a banded loop over n items (n rounded up to a multiple of BANDS)."""
    return (n + BANDS - 1) // BANDS * BANDS


@ti.func
def banded_item(k, n):
    """The item that iteration k of a banded loop over n items works on; n or more means none (skip it).
    Iteration k visits band k % BANDS, at position k // BANDS in it."""
    return (k % BANDS) * ((n + BANDS - 1) // BANDS) + k // BANDS


@ti.func
def spread_stride(n):
    """Iterations per item of a loop over n heavy items (a stream, a character): the least power of two that gives
    the loop at least SPREAD_ITEMS iterations, so a few items still reach every thread; 1 from SPREAD_ITEMS items up
    (no cost for big crowds). Iteration k works on item k // stride unless skipped(k, stride)."""
    stride = 1
    while stride * n < SPREAD_ITEMS:
        stride *= 2
    return stride


@ti.func
def skipped(slot, stride):
    """Whether iteration `slot` of a spread loop skips (it is not the first of its item's stride): a mask, where the
    modulo of any stride was an integer division in each of the ~8,192 iterations, most of which skip (chain16
    FABRIK on one thread, 100 characters: its two kernels 216 -> 162 us with one stream, kernels/lane_plan.py)."""
    return (slot & (stride - 1)) != 0
