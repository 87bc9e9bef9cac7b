"""Taichi's compile settings per kernel: the process's defaults (crowd_ik.runtime), changed for the kernels marked here.

Two of Taichi's own IR passes were most of a big kernel's cold compile, and LLVM does the same work after them:
- the control-flow-graph passes (store-to-load forwarding and dead-store elimination across blocks): crowd_ik.runtime
  starts Taichi with cfg_optimization=False. The raster's kernels are compiled with them on
  (:func:`with_cfg_passes`): their packet and per-pixel paths give the same bits only under the passes they were
  matched with (the ground's depth differs by an ulp without them, presumably where fast math fuses a multiply-add;
  tests/test_raster_lanes.py).
- whole-kernel common-subexpression elimination, which opt_level 1 (the process's) runs on every round of Taichi's
  simplification, each replacement a walk over the whole kernel: opt_level=0 (:func:`with_opt_level0`) skips it.
  The joint-limited FABRIK lanes compile 2.3x sooner so, with the same machine code's speed and the same poses
  bit for bit (docs/ARCHITECTURE.md "Compile time"); other kernels changed their rounding (DLS), so the mark is per
  kernel.

The general DLS lanes (kernels/dls_general_lanes.py) are compiled without fast math: their sums then run in the
order written, so the zero rows a request's layout gives some lanes change no bits (docs/ARCHITECTURE.md
"Determinism"), and they ran no slower.

The settings are fields of Taichi's one compile config, which a kernel's first launch reads when it compiles it
(within a process Taichi then keeps that compile whatever the settings; the offline cache's key includes them), so
the wrapper sets them around each call. Every Taichi launch of a process is on its main thread
(crowd_ik/io/pipeline.py), so no other launch sees them. crowd_ik.prepared does the same for a wrapped kernel it binds
(its `compile_settings` attribute).
"""

import functools


class compile_settings:  # noqa: N801  (used as a function: `with compile_settings(opt_level=0):`)
    """Taichi's compile config fields set to `fields` for the launches inside the block, then restored."""

    def __init__(self, **fields):
        self.fields = fields

    def __enter__(self):
        from taichi.lang import impl

        self.cfg = impl.current_cfg()
        self.old = {name: getattr(self.cfg, name) for name in self.fields}
        for name, value in self.fields.items():
            setattr(self.cfg, name, value)

    def __exit__(self, *exc):
        for name, value in self.old.items():
            setattr(self.cfg, name, value)
        return False


def compiled_with(**fields):
    """A decorator: the @ti.kernel it wraps is compiled and launched under compile_settings(**fields)."""

    def wrap(kernel):
        @functools.wraps(kernel)  # copies the kernel's attributes (_primal, ...), so crowd_ik.prepared can bind it
        def launch(*args, **kwargs):
            with compile_settings(**fields):
                return kernel(*args, **kwargs)

        launch.compile_settings = dict(fields)
        return launch

    return wrap


with_cfg_passes = compiled_with(cfg_optimization=True)  # the raster's kernels
with_opt_level0 = compiled_with(opt_level=0)  # the joint-limited FABRIK lanes
