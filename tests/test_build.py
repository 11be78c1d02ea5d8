"""How avll is built and released: the extension in use comes from these sources, the
wheel is abi3, the build comparison refuses builds of different sources, and the
release workflow builds what it should."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import yaml
from build_helpers import ROOT, source_digest

from avll import _core

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - CPython 3.10
    import tomli as tomllib

WORKFLOW = ROOT / ".github" / "workflows" / "release.yml"


def _load_identity() -> ModuleType:
    path = ROOT / ".ci" / "build_identity.py"
    spec = importlib.util.spec_from_file_location("build_identity", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_extension_was_built_from_these_sources() -> None:
    # A test run (or a comparison of builds) against an extension compiled from other
    # sources measures those sources: rebuild after changing the Rust code.
    want = source_digest()
    got = getattr(_core, "SOURCE_DIGEST", "none: built before build.rs recorded it")
    assert got == want, (
        f"avll._core ({_core.__file__}) was built from other sources (digest "
        f"{got}; this checkout's is {want}): rebuild it (pip install ., or "
        f"cargo build --profile dev-opt --features python and copy target/dev-opt/libavll.so "
        f"over the extension)"
    )


def test_source_digest_follows_every_source_file(tmp_path: Path) -> None:
    for rel in ("rust/lib.rs", "rust/sim/kernel.rs", "build.rs", "Cargo.toml", "Cargo.lock"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes((ROOT / rel).read_bytes())
    base = source_digest(tmp_path)
    for rel in ("rust/sim/kernel.rs", "build.rs", "Cargo.lock"):
        f = tmp_path / rel
        old = f.read_bytes()
        f.write_bytes(old + b"\n")
        assert source_digest(tmp_path) != base, rel
        f.write_bytes(old)
    (tmp_path / "rust" / "sim" / "kernel.rs").rename(tmp_path / "rust" / "sim" / "kernel2.rs")
    assert source_digest(tmp_path) != base
    (tmp_path / "rust" / "notes.txt").write_text("not a source")
    (tmp_path / "rust" / "sim" / "kernel2.rs").rename(tmp_path / "rust" / "sim" / "kernel.rs")
    assert source_digest(tmp_path) == base


def test_wheels_are_abi3_for_every_cpython_from_3_10() -> None:
    cargo = tomllib.loads((ROOT / "Cargo.toml").read_text(encoding="utf-8"))
    py = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    features = cargo["features"]
    assert "pyo3/abi3-py310" not in features["python"]  # version-specific: the dev build
    assert set(features["abi3"]) == {"python", "pyo3/abi3-py310"}
    assert py["tool"]["maturin"]["features"] == ["abi3"]  # what pip and maturin build
    assert py["project"]["requires-python"] == ">=3.10"  # abi3-py310's floor


def _dump(path: Path, digest: str | None, cases: dict[str, Any]) -> str:
    path.write_text(json.dumps({"extension": str(path), "source_digest": digest,
                                "cases": cases}))  # fmt: skip
    return str(path)


def test_build_comparison_refuses_builds_of_different_sources(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bi = _load_identity()
    case = {"t1": {"evaluations": 10628, "cost": "0x1.4d3p-9"}}
    other = {"t1": {"evaluations": 10861, "cost": "0x1.4d3p-9"}}
    a = _dump(tmp_path / "a.json", "00000000000000aa", {"full": case})
    b = _dump(tmp_path / "b.json", "00000000000000aa", {"full": case})
    assert bi.compare(a, b) == 0
    c = _dump(tmp_path / "c.json", "00000000000000aa", {"full": other})
    assert bi.compare(a, c) == 1
    assert "DIFFERS full: evaluations 10628 vs 10861" in capsys.readouterr().out
    # The abi3 finding of 2026-11-23: the two extensions came from two source trees.
    d = _dump(tmp_path / "d.json", "00000000000000bb", {"full": other})
    assert bi.compare(a, d) == 1
    assert "REFUSED" in capsys.readouterr().out
    e = _dump(tmp_path / "e.json", None, {"full": case})
    assert bi.compare(e, b) == 1


def _workflow() -> dict[Any, Any]:
    doc = yaml.safe_load(WORKFLOW.read_text(encoding="utf-8"))
    assert isinstance(doc, dict)
    return doc


def _steps(job: dict[str, Any], action: str) -> list[dict[str, Any]]:
    steps = job["steps"]
    assert isinstance(steps, list)
    return [s for s in steps if str(s.get("uses", "")).startswith(action)]


def test_release_workflow_builds_abi3_wheels_for_three_platforms_and_an_sdist() -> None:
    wf = _workflow()
    # PyYAML reads the key `on` as True (YAML 1.1).
    on = wf.get("on", wf.get(True))
    assert isinstance(on, dict) and on["push"]["tags"] == ["v*"]
    jobs = wf["jobs"]
    assert isinstance(jobs, dict)
    assert {"linux", "macos", "windows", "sdist", "publish"} <= set(jobs)
    targets: dict[str, set[str]] = {}
    for name in ("linux", "macos", "windows"):
        job = jobs[name]
        (build,) = _steps(job, "PyO3/maturin-action@")
        args = str(build["with"]["args"])
        assert "--release" in args and "--out dist" in args
        # One wheel per platform: no interpreter list, no version-specific builds.
        assert "--find-interpreter" not in args and "-i " not in args
        matrix = job["strategy"]["matrix"]
        targets[name] = {str(t["target"]) for t in matrix.get("include", [])} | {
            str(t) for t in matrix.get("target", [])}  # fmt: skip
        checks = " ".join(str(s.get("run", "")) for s in job["steps"])
        assert "cp310-abi3" in checks, name
    assert {"x86_64", "aarch64"} <= targets["linux"]
    assert {"x86_64", "aarch64"} <= targets["macos"]
    assert "x64" in targets["windows"]
    (linux,) = _steps(jobs["linux"], "PyO3/maturin-action@")
    assert str(linux["with"]["manylinux"]) == "2_28"
    assert "--compatibility manylinux_2_28" in str(linux["with"]["args"])
    (sdist,) = _steps(jobs["sdist"], "PyO3/maturin-action@")
    assert sdist["with"]["command"] == "sdist"


def test_release_workflow_publishes_tags_by_trusted_publishing() -> None:
    jobs = _workflow()["jobs"]
    assert isinstance(jobs, dict)
    pub = jobs["publish"]
    assert "refs/tags/" in pub["if"]
    assert set(pub["needs"]) >= {"linux", "macos", "windows", "sdist"}
    assert pub["permissions"] == {"id-token": "write"}  # OIDC, no stored token
    assert pub["environment"]["name"] == "pypi"
    (step,) = _steps(pub, "pypa/gh-action-pypi-publish@")
    assert "password" not in step.get("with", {})
    # No other job can publish or write.
    for name, job in jobs.items():
        if name != "publish":
            assert "permissions" not in job, name
            assert not _steps(job, "pypa/gh-action-pypi-publish@"), name
    assert _workflow()["permissions"] == {"contents": "read"}


def test_build_identity_script_runs_on_this_build(tmp_path: Path) -> None:
    # .ci/build_identity.py runs only in CI's wheel step: here it dumps this build's
    # seeded cases and compares them with themselves, so a renamed API breaks it here
    import subprocess

    script = ROOT / ".ci" / "build_identity.py"
    out = tmp_path / "this.json"
    r = subprocess.run([sys.executable, str(script), "dump", str(out)], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    r = subprocess.run([sys.executable, str(script), "compare", str(out), str(out)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "identical bit for bit" in r.stdout, r.stdout + r.stderr
