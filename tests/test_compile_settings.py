"""kernels/compile_settings.py: Taichi's CFG passes are off for the process and on only inside a marked kernel's launch;
the joint-limited FABRIK lanes compile at opt_level 0."""

import ast
import importlib
import os
from pathlib import Path

import numpy as np
import pytest

from crowd_ik.kernels.compile_settings import compile_settings, with_cfg_passes, with_opt_level0

KERNELS = Path(__file__).resolve().parents[1] / "kernels"


def _cfg():
    from taichi.lang import impl

    return impl.current_cfg()


@pytest.mark.skipif(os.environ.get("CROWD_IK_TAICHI_CFG_OPT") == "1", reason="switched on everywhere")
def test_the_process_runs_without_them_and_the_block_switches_them_on_and_back_even_on_an_error():
    assert _cfg().cfg_optimization is False
    level = _cfg().opt_level
    with compile_settings(cfg_optimization=True, opt_level=0):
        assert _cfg().cfg_optimization is True and _cfg().opt_level == 0
    assert _cfg().cfg_optimization is False and _cfg().opt_level == level
    with pytest.raises(KeyError), compile_settings(cfg_optimization=True):
        raise KeyError("x")
    assert _cfg().cfg_optimization is False


def test_a_wrapped_kernel_sees_its_settings_and_keeps_the_kernel_attributes_prepared_binds():
    seen = []

    def kernel(x, scale=1.0):
        seen.append((_cfg().cfg_optimization, _cfg().opt_level))
        return x * scale

    kernel._primal = "primal"
    level = _cfg().opt_level
    wrapped = with_cfg_passes(kernel)
    assert wrapped(2.0, scale=3.0) == 6.0 and seen == [(True, level)]
    assert wrapped._primal == "primal" and wrapped.compile_settings == {"cfg_optimization": True}
    assert wrapped.__wrapped__ is kernel
    assert with_opt_level0(kernel)(1.0) == 1.0 and seen[-1] == (_cfg().cfg_optimization, 0)


@pytest.mark.parametrize("module", ["raster.py", "raster_shade.py"])
def test_every_raster_kernel_is_compiled_with_them(module):
    """The raster's packet and per-pixel paths agree bit for bit only under the passes (tests/test_raster_lanes.py):
    each @ti.kernel there carries the decorator, and the module's names are the wrapped launches."""
    tree = ast.parse((KERNELS / module).read_text())
    names = [f.name for f in tree.body if isinstance(f, ast.FunctionDef)
             and any(ast.unparse(d) == "ti.kernel" for d in f.decorator_list)]
    assert names
    mod = importlib.import_module(f"crowd_ik.kernels.{module[:-3]}")
    assert all(getattr(mod, name).compile_settings == {"cfg_optimization": True} for name in names)


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


def test_the_joint_limited_fabrik_lanes_compile_at_opt_level_0():
    """Their whole-kernel CSE is most of their cold compile (kernels/compile_settings.py); the mark stays on."""
    from crowd_ik.kernels import fabrik_limited_lanes, lane_plan
    from crowd_ik.solvers import settings

    import crowd_ik as cik

    cik.init(arch="cpu")
    rig = cik.Rig.humanoid()
    kernel = fabrik_limited_lanes.limited_solver(max(settings.limited_lanes(), 1), lane_plan.capacity(rig.n_joints),
                                                 lane_plan.capacity(rig.n_effectors))
    assert kernel.compile_settings == {"opt_level": 0} and hasattr(kernel, "_primal")
