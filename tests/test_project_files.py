"""The project files a user or a packager looks for: LICENSE, CITATION.cff, CONTRIBUTING.md,
and what the README says about building and testing."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT.parent / "shared" / "paper" / "lower-level-controller-paper.md"
PAPER_ALT = Path("/work/shared/paper/lower-level-controller-paper.md")

#: CFF 1.2.0: the keys of the root object and of a reference, and the required ones
#: (from the schema at citation-file-format.github.io, schema 1.2.0).
_ROOT_KEYS = {"abstract", "authors", "cff-version", "commit", "contact", "date-released",
              "doi", "identifiers", "keywords", "license", "license-url", "message",
              "preferred-citation", "references", "repository", "repository-artifact",
              "repository-code", "title", "type", "url", "version"}
_ROOT_REQUIRED = {"authors", "cff-version", "message", "title"}
_REF_REQUIRED = {"authors", "title", "type"}
_PERSON_KEYS = {"family-names", "given-names", "name-particle", "name-suffix", "affiliation",
                "address", "alias", "city", "country", "email", "fax", "orcid", "post-code",
                "region", "tel", "website"}
_ENTITY_KEYS = {"name", "address", "alias", "city", "country", "date-end", "date-start",
                "email", "fax", "location", "orcid", "post-code", "region", "tel", "website"}


def _pyproject() -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10: the same parser as a package
        tomllib = pytest.importorskip("tomli", reason="reading pyproject.toml on 3.10")
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _cff() -> dict:
    yaml = pytest.importorskip("yaml", reason="PyYAML (the test extra) reads CITATION.cff")
    doc = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    assert isinstance(doc, dict)
    return doc


def _check_authors(authors: object, where: str) -> None:
    assert isinstance(authors, list) and authors, where
    for a in authors:
        assert isinstance(a, dict), where
        keys = set(a)
        if "name" in keys:  # an entity
            assert keys <= _ENTITY_KEYS and a["name"], (where, a)
        else:  # a person
            assert keys <= _PERSON_KEYS and a.get("family-names"), (where, a)


def test_license_is_the_mit_text_pyproject_claims() -> None:
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert _pyproject()["project"]["license"] == {"text": "MIT"}
    assert text.startswith("MIT License\n")
    assert "Copyright (c) the avll developers" in text
    assert "THE SOFTWARE IS PROVIDED \"AS IS\", WITHOUT WARRANTY OF ANY KIND" in text


def test_citation_cff_follows_the_schema_and_matches_pyproject() -> None:
    doc = _cff()
    assert _ROOT_REQUIRED <= set(doc) and set(doc) <= _ROOT_KEYS, set(doc) ^ _ROOT_KEYS
    assert doc["cff-version"] == "1.2.0" and doc["type"] == "software"
    _check_authors(doc["authors"], "authors")
    assert str(doc["version"]) == _pyproject()["project"]["version"]
    assert doc["license"] == "MIT"
    refs = doc["references"]
    assert isinstance(refs, list) and refs
    for r in refs:
        assert _REF_REQUIRED <= set(r), r
        _check_authors(r["authors"], "references")
    urls = _pyproject()["project"].get("urls", {})
    if "repository-code" in doc or urls:  # one address in both places
        assert doc.get("repository-code") in urls.values()


def test_citation_references_the_paper_as_written() -> None:
    paper = PAPER if PAPER.is_file() else PAPER_ALT
    if not paper.is_file():
        pytest.skip(f"the paper's text is not beside the checkout ({PAPER})")
    lines = paper.read_text(encoding="utf-8").splitlines()
    title = lines[0].lstrip("# ").strip()
    authors = [a.strip() for a in lines[2].split(",")]
    ref = _cff()["references"][0]
    assert ref["type"] == "article" and ref["title"] == title
    assert [f"{a['given-names']} {a['family-names']}" for a in ref["authors"]] == authors


def test_contributing_says_how_to_build_test_benchmark_and_regenerate() -> None:
    text = (ROOT / "CONTRIBUTING.md").read_text(encoding="utf-8")
    for words in ("maturin develop", 'pytest -m "not slow"', "cargo test",
                  "benches/bench_engine.py", "python -m docs.gen --check",
                  "sphinx-build -W"):
        assert words in text, words
    # the scripts and options it names exist
    for script in re.findall(r"python (benches/\w+\.py)", text):
        assert (ROOT / script).is_file(), script
    assert "--quick" in (ROOT / "benches" / "bench_engine.py").read_text(encoding="utf-8")
    assert "dev-opt" in (ROOT / "Cargo.toml").read_text(encoding="utf-8")


def test_readme_says_how_long_builds_take_and_how_to_skip_slow_tests() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert 'pytest -m "not slow"' in text
    assert re.search(r"first `pip install \.` compiles the Rust core", text)
    for f in ("LICENSE", "CITATION.cff", "CONTRIBUTING.md"):
        assert f"]({f})" in text, f
    markers = _pyproject()["tool"]["pytest"]["ini_options"]["markers"]
    assert any(m.startswith("slow:") for m in markers)


def test_no_ticket_numbers_in_code_tests_or_docs_text() -> None:
    """Code, tests and docs say what a thing does, not which ticket asked for it: no
    "issue N" outside the changelog (which is history)."""
    pat = re.compile(r"\bissues? ?#?\d+\b", re.IGNORECASE)
    hits = []
    for top in ("python", "rust", "benches", "tests", "docs"):
        for p in sorted((ROOT / top).rglob("*")):
            if (p.suffix not in {".py", ".pyi", ".rs", ".md"} or "_build" in p.parts
                    or p.name == "changelog.md" or not p.is_file()):
                continue
            for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1):
                if pat.search(line) and "no_ticket_numbers" not in line:
                    hits.append(f"{p.relative_to(ROOT)}:{n}: {line.strip()[:80]}")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    hits += [f"README.md: {m.group(0)}" for m in pat.finditer(readme)]
    assert not hits, "\n".join(hits)
