"""Which avll modules a Python file loads.

One import graph for two users: the docs pipeline (a fragment is stale when a module its
inputs load has changed since its stamp, not only when a listed input has) and the tests
(``tests/test_imports.py``: no import cycle in the package). Read from the source with
:mod:`ast`; only ``avll`` itself is imported, for its table of lazy names.
"""

from __future__ import annotations

import ast
import functools
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "python" / "avll"


def module_name(path: Path) -> str:
    """``python/avll/io/carma.py`` -> ``avll.io.carma`` (a package: its ``__init__``)."""
    parts = ["avll", *path.relative_to(PKG).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@functools.cache
def modules() -> dict[str, Path]:
    """Every module of the package by its dotted name."""
    return {module_name(p): p for p in sorted(PKG.rglob("*.py"))}


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


@functools.cache
def _lazy_names() -> dict[str, str]:
    """``avll``'s lazy public names -> their module (``calibrate`` -> ``calibration``)."""
    import avll

    return dict(avll._LAZY_NAMES)


def _loaded(path: Path, deferred: bool) -> set[str]:
    """The avll modules the imports of the file at ``path`` load (a package module's
    relative imports resolved; ``from avll import calibrate`` is ``avll.calibration``;
    with ``deferred``, ``avll.calibrate(...)`` after ``import avll`` too)."""
    mods, lazy = modules(), _lazy_names()
    inside = path.is_relative_to(PKG)
    name = module_name(path) if inside else ""
    is_pkg = path.name == "__init__.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    out: set[str] = set()
    if deferred:  # ``import avll`` then ``avll.simulate(...)``: the lazy name's module
        out.update(f"avll.{lazy.get(n.attr, n.attr)}" for n in ast.walk(tree)
                   if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
                   and n.value.id == "avll")
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
            if src == "avll":
                targets += [f"avll.{lazy[a.name]}" for a in node.names if a.name in lazy]
        out.update(targets)
    return {t for t in out if t in mods and t not in (name, "avll")}


@functools.cache
def import_graph(deferred: bool = False) -> dict[str, set[str]]:
    """Module -> the avll modules its imports load (module level; with ``deferred``
    also the imports inside functions). Edges to the package root ``avll`` are left
    out: it is imported before any of its submodules, and its lazy names import
    their modules on first use."""
    return {name: _loaded(path, deferred) for name, path in modules().items()}


def loaded_files(paths: Iterable[Path]) -> set[Path]:
    """The avll modules (as files) that running the Python files ``paths`` loads: a
    package module's own imports at load time, transitively; for a script outside the
    package (``docs/gen/*.py``, ``benches/*.py``) also the imports inside its functions
    (they are what a generator runs), then theirs at load time."""
    mods, graph = modules(), import_graph()
    todo: list[str] = []
    for p in paths:
        p = p.resolve()
        todo += [module_name(p)] if p.is_relative_to(PKG) else sorted(_loaded(p, True))
    seen: set[str] = set()
    while todo:
        m = todo.pop()
        if m in mods and m not in seen:
            seen.add(m)
            todo += graph[m]
    return {mods[m] for m in seen}
