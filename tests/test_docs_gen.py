"""The docs pipeline (``docs/gen``, ``python -m docs.gen``): its registry covers every
generated file, the cheap fragments are current (regenerated and compared), the
benchmark tables are their JSON's rendering, and the writer and ``--check`` do what they
say (stamp, atomic write, strict-JSON sidecar; a differing body and a changed input are
caught)."""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]
GEN_DIR = ROOT / "docs" / "_generated"


def _load() -> ModuleType:
    """``docs.gen`` (the repository root on the path: ``docs`` is not installed)."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    return importlib.import_module("docs.gen")


gen = _load()
CHEAP = [f.name for f in gen.REGISTRY.values() if f.cheap]


def _ns(**kw: object) -> argparse.Namespace:
    return argparse.Namespace(data_root=str(gen.DATA), **kw)


@functools.cache
def _fresh(name: str):  # one generation per cheap fragment for all the tests here
    return gen.REGISTRY[name].generate(_ns())


def _has_git_history() -> bool:
    try:
        n = subprocess.run(["git", "-C", str(ROOT), "rev-list", "--count", "HEAD"],
                           capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return False
    return int(n) > 1


def test_registry_covers_every_generated_file() -> None:
    outputs = {f.path for f in gen.REGISTRY.values() if f.block is None}
    md = set(GEN_DIR.glob("*.md"))
    assert md <= outputs, f"generated files no registry entry writes: {sorted(md - outputs)}"
    missing = [f.output for f in gen.REGISTRY.values() if gen.current_text(f) is None]
    assert not missing, f"registered fragments missing: {missing}"
    sidecars = {ROOT / s for f in gen.REGISTRY.values() for s in f.sidecars}
    sidecars |= {f.sidecar for f in gen.REGISTRY.values()}
    js = set(GEN_DIR.glob("*.json"))
    assert js <= sidecars, f"JSON files no registry entry writes: {sorted(js - sidecars)}"
    blocks = gen.readme_blocks(gen.README.read_text(encoding="utf-8"))
    assert set(blocks) >= {"section-iv", "cli"}
    registered = {f.block for f in gen.REGISTRY.values() if f.path == gen.README}
    assert set(blocks) == registered, (blocks, registered)
    for f in gen.REGISTRY.values():  # inputs name real files (a typo never goes stale)
        assert f.inputs, f.name
        assert all((ROOT / p).exists() for p in f.inputs), (f.name, f.inputs)


def test_generated_fragments_are_included() -> None:
    docs = ROOT / "docs"
    included = set()
    for page in docs.rglob("*.md"):
        if {"_build", "_generated"} & set(page.relative_to(docs).parts):
            continue
        included |= {Path(m).name for m in re.findall(r"```\{include\} (\S+)",
                                                       page.read_text(encoding="utf-8"))}
    frags = {f.path.name for f in gen.REGISTRY.values() if f.path.parent == GEN_DIR}
    assert frags - included == set(), f"fragments no page includes: {sorted(frags - included)}"


def test_every_fragment_is_stamped() -> None:
    """Every fragment carries a stamp with the commit it was generated at."""
    unstamped = {f.name for f in gen.REGISTRY.values()
                 if gen.stamp_commit(gen.current_text(f) or "") is None}
    assert not unstamped, f"unstamped: {sorted(unstamped)}: regenerate with docs.gen --only"


@pytest.mark.parametrize("name", CHEAP)
def test_cheap_fragment_is_current(name: str) -> None:
    frag = gen.REGISTRY[name]
    st = gen.check(frag, _ns(), _fresh(name))
    assert st.compared == "regenerated"
    assert st.ok, (f"{frag.output} is stale: run python -m docs.gen --only {name}\n"
                   f"{st.mismatch}")
    assert st.stamp is not None, f"{frag.output}: no stamp"


@pytest.mark.parametrize("name", [f.name for f in gen.REGISTRY.values() if f.rerender])
def test_benchmark_table_is_its_json(name: str) -> None:
    st = gen.check(gen.REGISTRY[name], _ns())
    assert st.compared == "re-rendered from JSON" and st.ok, st.mismatch


def test_cheap_fragments_have_tables() -> None:  # what test_docs asserted of the instant ones
    for name in ("bounds", "ga-options", "effects", "datasets", "readme-cli",
                 "readme-section-iv"):
        body = _fresh(name).body
        assert any(line.startswith("|") for line in body.splitlines()), name


def test_readme_section_iv_numbers_are_the_papers() -> None:
    """What tests/test_readme.py asserted: the Section IV numbers come out of the code."""
    numbers = _fresh("readme-section-iv").numbers
    assert numbers["models"]["proposed"]["min_tg"] == pytest.approx(3.5)
    assert numbers["models"]["second"]["kv_threshold"] == pytest.approx(0.8085, abs=1e-3)
    side = json.loads(gen.REGISTRY["readme-section-iv"].sidecar.read_text(encoding="utf-8"))
    assert side["models"]["proposed"]["min_tg"] == pytest.approx(3.5)


def test_readme_cli_table_is_the_parser() -> None:
    from docs.gen import fragments

    names = {n for n, _ in fragments.cli_commands()}
    assert names >= {"reproduce", "calibrate", "stability-map"}
    body = _fresh("readme-cli").body
    for n in names:
        assert f"| `avll {n}` |" in body, n


def test_writer_stamps_atomically_with_a_strict_json_sidecar(tmp_path: Path) -> None:
    frag = gen.Fragment("t", str(tmp_path / "t.md"),
                        lambda _: gen.Generated("| a |\n|---|\n| 1 |"), ("README.md",),
                        cheap=True)
    paths = gen.write(frag, gen.Generated("| a |\n|---|\n| 1 |",
                                          {"x": float("nan"), "y": [1.0, float("inf")]}))
    text = (tmp_path / "t.md").read_text(encoding="utf-8")
    assert text.startswith("<!-- generated by `python -m docs.gen --only t` with avll ")
    assert gen.body(text) == "| a |\n|---|\n| 1 |"
    assert gen.stamp_commit(text) == gen.head_commit() or gen.head_commit() == "unknown"
    side = (tmp_path / "t.json").read_text(encoding="utf-8")
    assert "NaN" not in side and "Infinity" not in side
    d = json.loads(side)
    assert d["x"] is None and "not finite" in d["x_note"] and d["y"] == [1.0, None]
    assert sorted(p.name for p in paths) == ["t.json", "t.md"]
    assert [p.name for p in tmp_path.iterdir() if p.name not in ("t.md", "t.json")] == []
    # a body that differs from a fresh generation is a mismatch; the stamp is not compared
    assert gen.check(frag, _ns()).ok  # the same body: current, whatever the stamp says
    other = gen.Fragment("t", str(tmp_path / "t.md"), lambda _: gen.Generated("| b |"),
                         ("README.md",), cheap=True)
    assert "| b |" in gen.check(other, _ns()).mismatch


@pytest.mark.skipif(not _has_git_history(), reason="needs the git history (not a shallow copy)")
def test_staleness_is_the_commits_touching_the_inputs() -> None:
    first = subprocess.run(["git", "-C", str(ROOT), "rev-list", "--max-parents=0", "HEAD"],
                           capture_output=True, text=True, check=True).stdout.split()[0]
    frag = gen.REGISTRY["bounds"]
    assert gen.staleness(frag, first)  # every input changed since the first commit
    head = gen.head_commit()
    assert gen.staleness(frag, head) == []
    assert "not in this repository" in gen.staleness(frag, "0123456789abc")[0]


def test_inputs_include_the_modules_they_load(tmp_path: Path) -> None:
    """A fragment is stale when a module its inputs load changes, not only a listed one:
    ``calibration.py`` loads ``rollout.py`` at import; a script's imports inside its
    functions and its ``avll.NAME`` uses count; the progress display does not."""
    frag = gen.Fragment("t", "docs/_generated/t.md", lambda _: None,
                        ("python/avll/calibration.py", "rust/optimize"), cheap=False)
    ins = gen.inputs_of(frag)
    assert ins[:2] == ["python/avll/calibration.py", "rust/optimize"]
    assert {"python/avll/rollout.py", "python/avll/models.py"} <= set(ins)
    assert not set(gen.NO_OUTPUT) & set(ins)
    assert "python/avll/_sigint.py" in {str(p.relative_to(ROOT)) for p in
                                        gen_imports().loaded_files([ROOT / ins[0]])}
    script = tmp_path / "bench_x.py"
    script.write_text("import avll\nfrom avll import calibrate\n\n\ndef run():\n"
                      "    import avll.maps\n    return avll.simulate, avll.stability\n")
    got = {p.name for p in gen_imports().loaded_files([script])}
    assert {"calibration.py", "maps.py", "rollout.py", "stability.py", "runs.py"} <= got
    assert "plotting.py" not in got  # imported inside a function of the package: not followed


def gen_imports() -> ModuleType:
    return importlib.import_module("docs.gen.imports")


@pytest.mark.skipif(not _has_git_history(), reason="needs the git history (not a shallow copy)")
def test_a_commit_on_a_loaded_module_makes_the_fragment_stale() -> None:
    frag = gen.Fragment("t", "docs/_generated/t.md", lambda _: None,
                        ("python/avll/calibration.py",), cheap=False)

    def git(*a: str) -> str:
        return subprocess.run(["git", "-C", str(ROOT), *a], capture_output=True, text=True,
                              check=True).stdout

    # the newest commit on rollout.py that left calibration.py alone
    commit = next(c for c in git("log", "--format=%H", "--", "python/avll/rollout.py").split()
                  if "python/avll/calibration.py" not in git("show", "--name-only",
                                                             "--format=", c).split())
    stale = [line.split()[0] for line in gen.staleness(frag, f"{commit}^")]
    assert git("rev-parse", "--short", commit).strip() in stale
    assert git("log", "--format=%h", f"{commit}^..HEAD", "--", "python/avll/calibration.py"
               ).split() != stale  # the listed input alone would not see it


@pytest.mark.slow
def test_check_command_passes() -> None:
    """``python -m docs.gen --check`` (what CI runs) exits 0 and says what it found."""
    import avll

    path = os.pathsep.join([str(ROOT), str(Path(avll.__file__).resolve().parents[1]),
                            os.environ.get("PYTHONPATH", "")])
    r = subprocess.run([sys.executable, "-m", "docs.gen", "--check"], cwd=ROOT, text=True,
                       capture_output=True, env=os.environ | {"PYTHONPATH": path}, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert re.search(r"docs\.gen --check: \d+ fragment\(s\), 0 mismatch\(es\)", r.stdout), r.stdout
    assert ", 0 unstamped," in r.stdout, r.stdout


def test_restamp_replaces_a_scripts_own_stamp(tmp_path: Path) -> None:
    """A script that writes its fragment itself (generate returns None): the writer
    replaces the script's stamp by its own and keeps the body."""
    out = tmp_path / "s.md"

    def script(_: argparse.Namespace) -> None:
        out.write_text("<!-- generated by `python benches/x.py`; do not edit by hand -->\n"
                       "*Generated by `python benches/x.py` with avll 0.1.0 (git abcdef1).*\n"
                       "\n| a |\n|---|\n| 2 |\n", encoding="utf-8")

    frag = gen.Fragment("s", str(out), script, ("README.md",), cheap=False)
    assert frag.generate(_ns()) is None
    assert gen.stamp_commit(out.read_text(encoding="utf-8")) == "abcdef1"
    gen.restamp(frag)
    text = out.read_text(encoding="utf-8")
    assert text.count("generated by") == 1 and "python -m docs.gen --only s" in text
    assert gen.body(text) == "| a |\n|---|\n| 2 |"
    assert not (tmp_path / "s.json").exists()  # no numbers: no sidecar
