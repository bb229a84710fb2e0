"""The package's layering, checked from the source: one folder per layer, imports only pointing down,
no learner importing another, no import cycle, imports at module level. A change that breaks the
architecture the README describes fails here, naming the import."""

from __future__ import annotations

import ast
import pathlib

import pytest

SOURCE = pathlib.Path(__file__).resolve().parents[1] / "src" / "bimgame"
#: Bottom to top; a module may import its own layer and the ones before it.
LAYERS = ("util", "sim", "envs", "expert", "learn", "experiments", "play", "cli")
#: Each learner is a module or a package of modules (all of them belong to it).
LEARNERS = {"bimgame.learn.a3c", "bimgame.learn.ppo", "bimgame.learn.pretrain", "bimgame.learn.dagger", "bimgame.learn.model_based"}
#: Imports allowed inside functions: heavy optional or slow dependencies, each with its reason in the code.
LAZY_ALLOWED = {"ray", "torch.utils.tensorboard", "matplotlib.figure"}
#: Modules allowed over 500 lines (none: every module stays under the rule).
LONG_ALLOWED: set[str] = set()


def _module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(SOURCE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, ast.Module]:
    return {_module_name(p): ast.parse(p.read_text(), filename=str(p)) for p in sorted(SOURCE.rglob("*.py"))}


def _imports(tree: ast.Module) -> list[tuple[str, int, bool]]:
    """(imported module, line, inside a function) for every import of the package or another library."""
    found = []
    functions = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
    nested = {id(sub) for f in functions for sub in ast.walk(f)}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno, id(node) in nested) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names]
            found += [(name, node.lineno, id(node) in nested) for name in names]
    return found


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def _package_edges(modules: dict[str, ast.Module]) -> dict[str, set[str]]:
    """module → the package modules it imports (``from bimgame.x import y`` counts as bimgame.x.y when
    that is a module, else bimgame.x)."""
    edges: dict[str, set[str]] = {}
    for name, tree in modules.items():
        targets = set()
        for imported, _, _ in _imports(tree):
            if imported.startswith("bimgame"):
                while imported not in modules and "." in imported:
                    imported = imported.rsplit(".", 1)[0]
                if imported != name and imported in modules:
                    targets.add(imported)
        edges[name] = targets
    return edges


def test_every_module_is_in_a_layer_folder():
    stray = [m for m in _modules() if m != "bimgame" and _layer(m) is None]
    assert not stray, f"modules outside the layer folders {LAYERS}: {stray}"


def test_imports_only_point_down():
    upward = []
    for module, targets in _package_edges(_modules()).items():
        for target in targets:
            if module != "bimgame" and target != "bimgame" and _layer(target) > _layer(module):
                upward.append(f"{module} imports {target}")
    assert not upward, "imports from a lower layer to a higher one:\n" + "\n".join(sorted(upward))


def test_the_package_root_imports_only_the_lowest_layers():
    edges = _package_edges(_modules())["bimgame"]
    assert all(_layer(t) <= LAYERS.index("sim") for t in edges), edges


def _learner_of(module: str) -> str | None:
    """The learner a module belongs to (its own module, or a module of its package), or None."""
    return next((learner for learner in LEARNERS if module == learner or module.startswith(learner + ".")), None)


def test_no_learner_imports_another():
    edges = _package_edges(_modules())
    crossed = [f"{a} imports {b}" for a, targets in edges.items() for b in targets
               if _learner_of(a) is not None and _learner_of(b) not in (None, _learner_of(a))]
    assert not crossed, crossed
    assert {_learner_of(m) for m in edges} >= LEARNERS, "a learner named here no longer exists"


def test_no_import_cycle():
    edges = _package_edges(_modules())
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for target in sorted(edges.get(node, ())):
            if state.get(target) == 1:
                return path[path.index(target):] + [target]
            if target not in state and (cycle := visit(target)):
                return cycle
        state[node] = 2
        path.pop()
        return None

    for module in sorted(edges):
        if module not in state and (cycle := visit(module)):
            pytest.fail("import cycle: " + " -> ".join(cycle))


def test_imports_are_at_module_level():
    lazy = [f"{module}:{line} imports {name}" for module, tree in _modules().items()
            for name, line, inside in _imports(tree)
            if inside and not any(name == a or name.startswith(a + ".") for a in LAZY_ALLOWED)]
    assert not lazy, "imports inside functions (move them to the top, or justify them here):\n" + "\n".join(lazy)


def test_modules_stay_small():
    long = [f"{_module_name(p)}: {n} lines" for p in sorted(SOURCE.rglob("*.py"))
            if (n := len(p.read_text().splitlines())) > 500 and _module_name(p) not in LONG_ALLOWED]
    assert not long, long


def test_the_checks_see_a_real_upward_import(tmp_path):
    """The import reader finds what these tests look for (so that they can fail)."""
    tree = ast.parse("from bimgame.cli.main import main\n\ndef f():\n    import ray\n")
    assert _imports(tree) == [("bimgame.cli.main.main", 1, False), ("ray", 4, True)]
    assert _layer("bimgame.cli.main") > _layer("bimgame.sim.maze")


def test_a_learners_package_modules_belong_to_it():
    """The learner check sees the modules inside a learner's package (and not a look-alike name)."""
    assert _learner_of("bimgame.learn.a3c.workers") == "bimgame.learn.a3c"
    assert _learner_of("bimgame.learn.dagger") == "bimgame.learn.dagger"
    assert _learner_of("bimgame.learn.a3c_extra") is None and _learner_of("bimgame.learn.nets") is None
