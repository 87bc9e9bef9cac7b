"""The layering rules that can be checked from the source: no import circles, what kernels import, who
imports the NumPy twins and the commands, and where the IK method names are spelled (once, in
crowd_ik/solvers/registry.py).

Imports are read from the source at every level (a function's deferred import is still a
dependency), and `from crowd_ik import X` resolves through the package's lazy table to the module
that defines X, so a re-export cannot hide a circle."""

import ast
from pathlib import Path

from crowd_ik.solvers import registry

ROOT = Path(__file__).resolve().parent.parent
BENCH = {"crowd_ik/bench/baseline.py", "crowd_ik/bench/peers.py"}  # the twins are the bench's baseline


def _modules(folder: str):
    for path in sorted((ROOT / folder).rglob("*.py")):
        yield path.relative_to(ROOT).as_posix(), ast.parse(path.read_text(), filename=str(path))


def _type_checking_blocks(tree) -> set[int]:
    """ids of the nodes under `if TYPE_CHECKING:` (annotations only: never imported at run time)."""
    return {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
            and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING"
            for stmt in node.body for n in ast.walk(stmt)}


def _import_nodes(tree):
    """The Import / ImportFrom nodes of a module at every level, TYPE_CHECKING blocks left out."""
    skip = _type_checking_blocks(tree)
    return [node for node in ast.walk(tree)
            if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in skip]


def _imports(tree) -> set[str]:
    out = set()
    for node in _import_nodes(tree):
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


def test_only_the_bench_imports_the_twins():
    users = {name for name, tree in _modules("crowd_ik") if not name.startswith("crowd_ik/reference/")
             and any(m.startswith("crowd_ik.reference") for m in _imports(tree))}
    assert users - BENCH == set()


def test_no_product_module_imports_the_commands():
    users = {name for name, tree in _modules("crowd_ik") if not name.startswith("crowd_ik/commands/")
             and name != "crowd_ik/__main__.py" and any(m.startswith("crowd_ik.commands") for m in _imports(tree))}
    assert users == set()


def _module_name(path: str) -> str:
    parts = Path(path).with_suffix("").parts
    if parts[0] == "kernels":
        parts = ("crowd_ik", *parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """module -> the package modules it imports (at any level), re-exports resolved."""
    import crowd_ik

    trees = {_module_name(name): tree for folder in ("crowd_ik", "kernels") for name, tree in _modules(folder)}
    lazy = {name: module for name, (module, _attr) in crowd_ik._LAZY.items()}
    graph = {}
    for mod, tree in trees.items():
        deps = set()
        for node in _import_nodes(tree):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [lazy[a.name] if node.module == "crowd_ik" and a.name in lazy else
                           f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in trees else node.module
                           for a in node.names]
            else:
                continue
            for t in targets:
                while t not in trees and "." in t:
                    t = t.rsplit(".", 1)[0]
                if t in trees and t not in (mod, "crowd_ik"):
                    deps.add(t)
        graph[mod] = deps
    return graph


def find_circles(graph: dict[str, set[str]]) -> list[str]:
    """Every circle a depth-first search closes, as "a -> b -> a" strings."""
    state, path, circles = {}, [], []

    def visit(m):  # a grey node met again closes a circle
        state[m] = "grey"
        path.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == "grey":
                circles.append(" -> ".join(path[path.index(d):] + [d]))
            elif d not in state:
                visit(d)
        path.pop()
        state[m] = "black"

    for m in sorted(graph):
        if m not in state:
            visit(m)
    return circles


def test_there_is_no_import_circle():
    assert find_circles(import_graph()) == []


def test_the_circle_check_sees_circles_deferred_imports_and_re_exports(monkeypatch):
    assert find_circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a -> b -> c -> a"]
    assert find_circles({"a": {"b"}, "b": set()}) == []
    graph = import_graph()
    assert "crowd_ik.game.world" in graph["crowd_ik.io.clip"]  # record_clip's deferred import
    assert "crowd_ik.runtime" in graph["crowd_ik.crowd"]  # `from crowd_ik import runtime`


def test_method_names_are_spelled_only_in_the_registry():
    # "follow" is also an ordinary word (the camera's follow mode): as a method name it is checked where
    # methods are chosen - the mouse demo and the command line
    names = set(registry.METHODS) | set(registry.PLANAR_METHODS) - {registry.FOLLOW}
    method_modules = ("crowd_ik/mouse/", "crowd_ik/commands/", "crowd_ik/planar.py")
    found = []
    for name, tree in _modules("crowd_ik"):
        if name.startswith("crowd_ik/reference/") or name == "crowd_ik/solvers/registry.py":
            continue
        names_here = names | ({registry.FOLLOW} if name.startswith(method_modules) else set())
        exempt = set()  # __all__ lists name functions (planar.dls), not methods
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
                exempt |= {id(c) for c in ast.walk(node.value)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and node.value in names_here and id(node) not in exempt:
                found.append(f"{name}:{node.lineno} {node.value!r}")
    assert found == []


def test_the_registry_is_what_the_command_line_and_the_scene_offer():
    from crowd_ik import scene
    from crowd_ik.bench import options as bench
    from crowd_ik.commands.cli import build_parser

    assert bench.SOLVERS == registry.METHODS
    assert scene.Solver().method == registry.DEFAULT
    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    play = next(a for a in sub.choices["play"]._actions if "--solver" in a.option_strings)
    mouse = next(a for a in sub.choices["mouse"]._actions if "--method" in a.option_strings)
    assert tuple(play.choices) == registry.METHODS and tuple(mouse.choices) == registry.PLANAR_METHODS
