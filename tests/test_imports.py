"""The package's import structure: ``import avll`` stays light, and no module-level
import cycle exists between avll's modules."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import avll

PKG = Path(avll.__file__).resolve().parent

#: Heavy optional libraries that ``import avll`` alone must not import.
HEAVY = ("scipy", "matplotlib", "pandas", "xarray", "dask")


def test_import_avll_is_lazy() -> None:
    code = ("import sys, avll; "
            f"print(sorted(m for m in {HEAVY!r} if m in sys.modules)); "
            "print(sorted(m for m in sys.modules if m.startswith('avll')))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, check=True)
    heavy, mods = r.stdout.splitlines()
    assert heavy == "[]"
    assert "avll.calibration" not in mods  # imported on first use of avll.calibrate


def test_calibrate_is_the_function_after_importing_its_module() -> None:
    r = subprocess.run([sys.executable, "-c",
                        "import avll.calibration, avll; print(callable(avll.calibrate), "
                        "avll.calibrate is avll.calibration.calibrate)"],
                       capture_output=True, text=True, timeout=120, check=True)
    assert r.stdout.split() == ["True", "True"]


def test_every_public_submodule_is_an_attribute_on_first_access() -> None:
    """``import avll; avll.stability.plot_regions(...)`` works in a fresh process, without
    an ``import avll.stability`` first (a test passed only after another file imported it)."""
    names = sorted(p.stem for p in PKG.glob("*.py") if not p.stem.startswith("_"))
    names += sorted(p.name for p in PKG.iterdir() if (p / "__init__.py").is_file())
    code = ("import types, avll; "
            f"print(all(isinstance(getattr(avll, n), types.ModuleType) for n in {names!r})); "
            "print(hasattr(avll, 'no_such_module'), hasattr(avll, '_no_such'))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, check=True)
    assert r.stdout.split() == ["True", "False", "False"], r.stderr
    assert "stability" in names and "diagnose" in names


def _module_name(path: Path) -> str:
    parts = ["avll", *path.relative_to(PKG).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.Module, deferred: bool) -> list[ast.Import | ast.ImportFrom]:
    """Imports executed when the module is imported: the module body, including
    ``try``/``if`` blocks, but not ``if TYPE_CHECKING``; with ``deferred`` also those
    inside functions and classes (run on first use)."""
    out: list[ast.Import | ast.ImportFrom] = []

    def walk(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                out.append(node)
            elif isinstance(node, ast.If):
                if not _is_type_checking(node.test):
                    walk(node.body)
                walk(node.orelse)
            elif isinstance(node, ast.Try):
                walk(node.body)
                for h in node.handlers:
                    walk(h.body)
                walk(node.orelse)
                walk(node.finalbody)
            elif isinstance(node, (ast.With, ast.For, ast.While)) or (deferred and isinstance(
                    node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))):
                walk(node.body)

    walk(tree.body)
    return out


def import_graph(deferred: bool = False) -> dict[str, set[str]]:
    """Module -> the avll modules its imports load (module level; with ``deferred``
    also the imports inside functions). Edges to the package root ``avll`` are left
    out: it is imported before any of its submodules, and its lazy names import
    their modules on first use."""
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for node in _imports(tree, deferred):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                if node.level:
                    base = name.split(".")
                    if not is_pkg:
                        base = base[:-1]
                    base = base[:len(base) - (node.level - 1)]
                    src = ".".join(base + ([node.module] if node.module else []))
                else:
                    src = node.module or ""
                # "from pkg import sub" loads pkg.sub when sub is a module
                targets = [src] + [f"{src}.{a.name}" for a in node.names]
            for t in targets:
                if t in mods and t not in (name, "avll"):
                    graph[name].add(t)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state and (c := visit(m)):
                return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (c := visit(n)):
            return c
    return None


def test_the_graph_sees_imports() -> None:
    g = import_graph()
    assert "avll.rollout" in g["avll.calibration"]
    assert "avll.plotting" not in g["avll.calibration"]  # imported inside a method
    assert "avll.plotting" in import_graph(deferred=True)["avll.calibration"]
    assert "avll.models" in g["avll.paper"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_no_import_cycle() -> None:
    cycle = _cycle(import_graph())
    assert cycle is None, " -> ".join(cycle or [])


def test_no_import_cycle_through_deferred_imports() -> None:
    # an import inside a function still ties the two modules: maps and stability
    # once imported each other that way
    g = import_graph(deferred=True)
    assert "avll.stability" in g["avll.maps"]
    cycle = _cycle(g)
    assert cycle is None, " -> ".join(cycle or [])
