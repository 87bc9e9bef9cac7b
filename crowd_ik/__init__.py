"""crowd_ik: batched inverse kinematics for crowds of characters, in Taichi.

The public names are imported lazily, so `import crowd_ik` creates no Taichi state and stays fast;
see docs/DESIGN.md for the contract.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_LAZY = {
    "init": ("crowd_ik.runtime", "init"),
    "Rig": ("crowd_ik.rig", "Rig"),
    "Joint": ("crowd_ik.rig", "Joint"),
    "Effector": ("crowd_ik.rig", "Effector"),
    "Crowd": ("crowd_ik.crowd", "Crowd"),
    "SolveReport": ("crowd_ik.crowd", "SolveReport"),
    "Status": ("crowd_ik.crowd", "Status"),
    "two_bone": ("crowd_ik.analytic", "two_bone"),
    "load_scene": ("crowd_ik.scene", "load_scene"),
    "Scene": ("crowd_ik.scene", "Scene"),
    "World": ("crowd_ik.game.world", "World"),
    "planar": ("crowd_ik.planar", None),
    "load_bvh": ("crowd_ik.io.bvh", "load_bvh"),
    "animate": ("crowd_ik.animation", "animate"),
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    try:
        module, attr = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'crowd_ik' has no attribute {name!r}") from None
    mod = importlib.import_module(module)
    value = mod if attr is None else getattr(mod, attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(__all__)
