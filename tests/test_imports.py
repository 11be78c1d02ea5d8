"""The package's import structure: ``import avll`` stays light, and no module-level
import cycle exists between avll's modules."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import avll

PKG = Path(avll.__file__).resolve().parent
ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # docs/ is not installed: the repository root on the path
    sys.path.insert(0, str(ROOT))

from docs.gen.imports import import_graph  # noqa: E402  (the graph the docs pipeline uses)

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
