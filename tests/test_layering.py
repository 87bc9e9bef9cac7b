"""The layering rules that can be checked from the source: what kernels import, who imports the NumPy
twins, and where the IK method names are spelled (crowd_ik/solvers/registry.py, once)."""

import ast
from pathlib import Path

from crowd_ik.solvers import registry

ROOT = Path(__file__).resolve().parent.parent
# Product modules that still use twin code for real work (host FK, counter RNG, the segment sweep): the
# architecture issue moves that into a geometry/ package. A new entry fails this test, and so does a fixed one.
STILL_ON_THE_TWINS = {"crowd_ik/game/world.py", "crowd_ik/io/clip.py"}
BENCH = {"crowd_ik/bench/run.py", "crowd_ik/bench/peers.py"}  # the twins are the bench's baseline


def _modules(folder: str):
    for path in sorted((ROOT / folder).rglob("*.py")):
        yield path.relative_to(ROOT).as_posix(), ast.parse(path.read_text(), filename=str(path))


def _imports(tree) -> set[str]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
    return out


def test_kernels_import_only_kernels_taichi_and_the_solver_settings():
    allowed_roots = {"taichi", "functools", "math"}
    for name, tree in _modules("kernels"):
        for mod in _imports(tree):
            ok = (mod.split(".")[0] in allowed_roots or mod.startswith("crowd_ik.kernels")
                  or mod.startswith("crowd_ik.solvers.settings"))
            assert ok, f"{name} imports {mod}"


def test_only_the_bench_and_the_listed_modules_import_the_twins():
    users = {name for name, tree in _modules("crowd_ik") if not name.startswith("crowd_ik/reference/")
             and any(m.startswith("crowd_ik.reference") for m in _imports(tree))}
    assert users - BENCH == STILL_ON_THE_TWINS


def test_method_names_are_spelled_only_in_the_registry():
    names = set(registry.METHODS) | set(registry.PLANAR_METHODS)
    found = []
    for name, tree in _modules("crowd_ik"):
        if name.startswith("crowd_ik/reference/") or name == "crowd_ik/solvers/registry.py":
            continue
        exempt = set()  # __all__ lists name functions (planar.dls), not methods
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
                exempt |= {id(c) for c in ast.walk(node.value)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and node.value in names and id(node) not in exempt:
                found.append(f"{name}:{node.lineno} {node.value!r}")
    assert found == []


def test_the_registry_is_what_the_command_line_and_the_scene_offer():
    from crowd_ik import scene
    from crowd_ik.bench import run as bench
    from crowd_ik.commands.cli import build_parser

    assert bench.SOLVERS == registry.METHODS
    assert scene.Solver().method == registry.DEFAULT
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    play = next(a for a in sub.choices["play"]._actions if "--solver" in a.option_strings)
    mouse = next(a for a in sub.choices["mouse"]._actions if "--method" in a.option_strings)
    assert tuple(play.choices) == registry.METHODS and tuple(mouse.choices) == registry.PLANAR_METHODS
