"""kernels/cfg_passes.py: Taichi's CFG passes are off for the process and on only inside a marked kernel's launch."""

import ast
import importlib
import os
from pathlib import Path

import numpy as np
import pytest

from crowd_ik.kernels.cfg_passes import cfg_passes, with_cfg_passes

KERNELS = Path(__file__).resolve().parents[1] / "kernels"


def _cfg():
    from taichi.lang import impl

    return impl.current_cfg()


@pytest.mark.skipif(os.environ.get("CROWD_IK_TAICHI_CFG_OPT") == "1", reason="switched on everywhere")
def test_the_process_runs_without_them_and_the_block_switches_them_on_and_back_even_on_an_error():
    assert _cfg().cfg_optimization is False
    with cfg_passes(True):
        assert _cfg().cfg_optimization is True
    assert _cfg().cfg_optimization is False
    with pytest.raises(KeyError), cfg_passes(True):
        raise KeyError("x")
    assert _cfg().cfg_optimization is False


def test_a_wrapped_kernel_sees_them_on_and_keeps_the_kernel_attributes_prepared_binds():
    seen = []

    def kernel(x, scale=1.0):
        seen.append(_cfg().cfg_optimization)
        return x * scale

    kernel._primal = "primal"
    wrapped = with_cfg_passes(kernel)
    assert wrapped(2.0, scale=3.0) == 6.0 and seen == [True]
    assert wrapped._primal == "primal" and wrapped.cfg_optimization is True and wrapped.__wrapped__ is kernel


@pytest.mark.parametrize("module", ["raster.py", "raster_shade.py"])
def test_every_raster_kernel_is_compiled_with_them(module):
    """The raster's packet and per-pixel paths agree bit for bit only under the passes (tests/test_raster_lanes.py):
    each @ti.kernel there carries the decorator, and the module's names are the wrapped launches."""
    tree = ast.parse((KERNELS / module).read_text())
    names = [f.name for f in tree.body if isinstance(f, ast.FunctionDef)
             and any(ast.unparse(d) == "ti.kernel" for d in f.decorator_list)]
    assert names
    mod = importlib.import_module(f"crowd_ik.kernels.{module[:-3]}")
    assert all(getattr(mod, name).cfg_optimization is True for name in names)


def test_prepared_binds_the_compile_the_wrapped_call_made():
    """A prepared launch of a wrapped raster kernel gives the same bits as its ordinary call."""
    from crowd_ik.kernels import raster as kr
    from crowd_ik.prepared import prepared
    from crowd_ik.view.render import Camera

    h, w = 64, 96
    cam = Camera((6.0, 4.0, -7.0), (0.0, 0.5, 0.0), 50.0, w, h).packed()
    out = []
    for launch in (kr.shade_background, prepared(kr.shade_background)):
        for _ in range(3):  # the third prepared call is a bound launch
            bg = np.zeros((h, w, 3), np.float32)
            launch(cam, bg)
        out.append(bg)
    assert np.isfinite(out[0][..., 1]).all() and np.array_equal(out[0].view(np.int32), out[1].view(np.int32))
