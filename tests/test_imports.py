"""The package's modules import one another without cycles, and each imports on its own.

A cycle hidden in a function (an import moved inside it to dodge the error) is still a cycle:
the static test counts imports anywhere in a module, only not those under ``if TYPE_CHECKING:``
(type hints, never run).
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "fem_impact"
# Importing __main__ runs the command line: it is checked through `python -m fem_impact --version`.
SCRIPTS = {"fem_impact.__main__"}


def package_modules() -> dict[str, Path]:
    """Dotted module name -> source file, for every module of the package (packages by their __init__)."""
    modules = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(node: ast.AST):
    """The import statements in ``node`` at any depth, except under ``if TYPE_CHECKING:``."""
    if isinstance(node, (ast.Import, ast.ImportFrom)):
        yield node
    skip = isinstance(node, ast.If) and _is_type_checking(node)
    for child in node.orelse if skip else ast.iter_child_nodes(node):
        yield from _imports(child)


def import_graph(modules: dict[str, Path]) -> dict[str, dict[str, int]]:
    """module -> {module it imports: line of the first such import}, within the package.

    ``from . import name`` is an edge to the submodule ``name`` when there is one, else to the
    package's ``__init__`` (whose attribute it reads); ``import a.b.c`` and ``from a.b.c import x``
    are edges to ``a.b.c`` (its parent packages load first, but they are not cycles of their own).
    """
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        edges: dict[str, int] = {}

        def add(target: str | None, line: int, name=name, edges=edges):
            if target in modules and target != name:
                edges.setdefault(target, line)

        for node in _imports(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    add(alias.name, node.lineno)
                continue
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1]
                                + ([node.module] if node.module else []))
            else:
                base = node.module
            for alias in node.names:
                submodule = f"{base}.{alias.name}"
                add(submodule if submodule in modules else base, node.lineno)
        graph[name] = edges
    return graph


def find_cycle(graph: dict[str, dict[str, int]]) -> list[str] | None:
    """One cycle (a list of modules, the first repeated at the end), or None."""
    state: dict[str, int] = {}   # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for target in sorted(graph[node]):
            if state.get(target) == 1:
                return path[path.index(target):] + [target]
            if target not in state:
                found = visit(target)
                if found:
                    return found
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state:
            found = visit(start)
            if found:
                return found
    return None


def test_the_graph_sees_imports_inside_functions_and_skips_type_hints(tmp_path):
    (tmp_path / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import B\n"
                                   "def f():\n    from . import c\n    from .d import x\n    import p.e\n")
    modules = {"p": tmp_path / "__init__.py", **{f"p.{m}": tmp_path / f"{m}.py" for m in "abcde"}}
    for path in modules.values():
        path.touch()
    graph = import_graph(modules)
    assert graph["p.a"] == {"p.c": 5, "p.d": 6, "p.e": 7}
    assert find_cycle({"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b": 1}, "b": {}}) is None


def test_no_import_cycle():
    graph = import_graph(package_modules())
    cycle = find_cycle(graph)
    if cycle:
        steps = [f"{a} (line {graph[a][b]}) -> {b}" for a, b in zip(cycle, cycle[1:], strict=False)]
        pytest.fail("import cycle:\n  " + "\n  ".join(steps))


def _import_alone(module: str) -> tuple[str, subprocess.CompletedProcess]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    code = (["-m", "fem_impact", "--version"] if module in SCRIPTS else ["-c", f"import {module}"])
    return module, subprocess.run([sys.executable, *code], capture_output=True, text=True, env=env, timeout=300)


@pytest.mark.slow   # (38 s of both cores, the default tier's longest test: test_no_import_cycle finds cycles there)
def test_every_module_imports_on_its_own():
    """Each module in a fresh interpreter (a cycle or a missing import shows only there), as many at a
    time as there are cores (2 to 4)."""
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=max(2, min(4, os.cpu_count() or 2))) as pool:
        results = list(pool.map(_import_alone, sorted(package_modules())))
    failed = [f"{module}:\n{proc.stderr.strip()}" for module, proc in results if proc.returncode != 0]
    assert not failed, "\n\n".join(failed)
    print(f"{len(results)} modules imported in {time.perf_counter() - t0:.1f} s")


# The package's layers, top to bottom: a module imports its own layer or one below, never one above.
# Every module of the package belongs to one (a new folder must be placed here).
LAYERS = (
    ("entry", ("fem_impact", "fem_impact.__main__")),   # `import fem_impact`, `python -m fem_impact`
    ("app", ("fem_impact.app",)),                        # command line, runs, studies, outputs
    ("periodic", ("fem_impact.periodic",)),              # periodic orbits of the reduced model
    ("build", ("fem_impact.build",)),                    # a case becomes a system
    ("config", ("fem_impact.config",)),                  # the case file (reads the schemas below, no PETSc)
    ("rigid", ("fem_impact.rigid",)),                    # rigid bodies in large rotation and their scheme
    ("integrators", ("fem_impact.integrators",)),        # time schemes and the time loop
    ("nonsmooth", ("fem_impact.nonsmooth",)),            # contact relations, laws, one-step problems
    ("mechanics", ("fem_impact.mechanics",)),            # the system in matrices, its energy
    ("fem", ("fem_impact.fem",)),                        # dolfinx: meshes, assembly, modes, the reduced model
    ("linalg", ("fem_impact.linalg",)),                  # algebra backends, factorizations, PETSc/MUMPS calls
    ("base", ("fem_impact.errors", "fem_impact.parallel", "fem_impact.expressions", "fem_impact.cache",
              "fem_impact._version", "fem_impact.mpi_start", "fem_impact.references", "fem_impact.compiled")),
)


def _in(module: str, packages) -> bool:
    return any(module == p or module.startswith(p + ".") for p in packages)


def layer_of(module: str) -> int | None:
    """The position of ``module``'s layer in LAYERS (0: the top), or None if it is in none."""
    for k, (name, packages) in enumerate(LAYERS):
        if (module in packages) if name == "entry" else _in(module, packages):   # (the entry: those modules alone)
            return k
    return None


def upward_imports(graph: dict[str, dict[str, int]]) -> list[tuple[str, str, int]]:
    """(module, module it imports, line) for every import that points to a higher layer."""
    found = []
    for module, edges in sorted(graph.items()):
        for target, line in sorted(edges.items()):
            if layer_of(target) < layer_of(module):
                found.append((module, target, line))
    return found


def test_every_module_is_in_a_layer():
    """Each folder and module of the package, periodic/ included, has its place in LAYERS."""
    modules = package_modules()
    folders = {m for m, path in modules.items() if path.name == "__init__.py"} - {"fem_impact"}
    assert {"fem_impact.app", "fem_impact.periodic", "fem_impact.config", "fem_impact.integrators",
            "fem_impact.nonsmooth", "fem_impact.fem", "fem_impact.mechanics", "fem_impact.linalg"} <= folders
    unplaced = sorted(m for m in modules if layer_of(m) is None)
    assert not unplaced, f"modules in no layer of LAYERS (tests/test_imports.py): {unplaced}"


def test_every_import_points_down_the_layers():
    """No module imports a layer above its own, directly (imports inside functions count; type hints
    under ``if TYPE_CHECKING:`` do not)."""
    graph = import_graph(package_modules())
    found = upward_imports(graph)
    names = {k: name for k, (name, _) in enumerate(LAYERS)}
    wrong = [f"{m} (line {line}, layer {names[layer_of(m)]}) imports {t} (layer {names[layer_of(t)]})"
             for m, t, line in found]
    assert not wrong, "imports that point up a layer:\n  " + "\n  ".join(wrong)


def test_the_layer_check_sees_a_violation(tmp_path):
    (tmp_path / "fem").mkdir()
    (tmp_path / "config").mkdir()
    (tmp_path / "fem" / "m.py").write_text("def f():\n    from ..config import case\n")
    (tmp_path / "config" / "case.py").write_text("")
    modules = {"fem_impact.fem.m": tmp_path / "fem" / "m.py", "fem_impact.config.case": tmp_path / "config" / "case.py"}
    graph = import_graph(modules)
    assert graph["fem_impact.fem.m"] == {"fem_impact.config.case": 2}
    assert upward_imports(graph) == [("fem_impact.fem.m", "fem_impact.config.case", 2)]
    assert upward_imports({"fem_impact.config.case": {"fem_impact.fem.m": 1}, "fem_impact.fem.m": {}}) == []
    assert layer_of("fem_impact") == 0 and layer_of("fem_impact.linalg.factor") == layer_of("fem_impact.linalg")
    assert layer_of("fem_impact.periodic.shooting") < layer_of("fem_impact.build") < layer_of("fem_impact.config")
    assert layer_of("fem_impact.unknown") is None


def test_modules_are_of_a_size_a_reader_takes_in():
    """A module per concern: none over 700 lines, the case file's front (config/case.py) under 400."""
    sizes = {path.relative_to(ROOT).as_posix(): len(path.read_text().splitlines()) for path in PACKAGE.rglob("*.py")}
    assert {path: n for path, n in sizes.items() if n > 700} == {}
    assert sizes["fem_impact/config/case.py"] < 400
