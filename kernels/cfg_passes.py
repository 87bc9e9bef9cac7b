"""Taichi's control-flow-graph passes, per kernel: off for every kernel (crowd_ik.runtime), on for the few marked here.

Taichi's CFG passes (store-to-load forwarding and dead-store elimination across blocks) were most of a big
kernel's cold compile, and LLVM does the same work after them: with them off the solver kernels run as fast and
compile 2.5-4x sooner (docs/ARCHITECTURE.md "Compile time"). So crowd_ik.runtime starts Taichi with
cfg_optimization=False. A kernel decorated with :func:`with_cfg_passes` is compiled with them on: the raster's,
whose packet and per-pixel paths give the same bits only under the passes they were matched with (the ground's
depth differs by an ulp without them, presumably where fast math fuses a multiply-add; tests/test_raster_lanes.py).

The setting is a field of Taichi's one compile config, which a kernel's first launch reads when it compiles it
(within a process Taichi then keeps that compile whatever the setting; the offline cache's key includes it), so
the wrapper sets it around each call. Every Taichi launch of a process is on
its main thread (crowd_ik/io/pipeline.py), so no other launch sees it. crowd_ik.prepared does the same for a
wrapped kernel it binds (`cfg_optimization` attribute).
"""

import functools


class cfg_passes:  # noqa: N801  (used as a function: `with cfg_passes(True):`)
    """Taichi's CFG passes switched on (or off) for the launches inside the block."""

    def __init__(self, on: bool):
        self.on = bool(on)

    def __enter__(self):
        from taichi.lang import impl

        self.cfg = impl.current_cfg()
        self.old = self.cfg.cfg_optimization
        self.cfg.cfg_optimization = self.on

    def __exit__(self, *exc):
        self.cfg.cfg_optimization = self.old
        return False


def with_cfg_passes(kernel):
    """`kernel` (a @ti.kernel), compiled and launched with Taichi's CFG passes on."""

    @functools.wraps(kernel)  # copies the kernel's attributes (_primal, ...), so crowd_ik.prepared can bind it
    def launch(*args, **kwargs):
        with cfg_passes(True):
            return kernel(*args, **kwargs)

    launch.cfg_optimization = True
    return launch
