"""The README's API tour runs as written (field-data line skipped without the data)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _tour() -> str:
    text = README.read_text()
    section = text[text.index("## Python API, a tour") :]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_set_up_commands() -> None:
    text = README.read_text()
    block = re.search(r"## Set up\n\n```bash\n(.*?)```", text, re.S).group(1)
    cmds = [line for line in block.splitlines() if line and not line.startswith("#")]
    assert cmds[0] == "pip install . && avll reproduce --out avll-out"
    ci = (README.parent / ".ci" / "run").read_text()
    assert cmds[1] in ci  # CI runs exactly the README's test command


@pytest.mark.slow
def test_readme_api_tour_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    code = _tour().replace("progress=True", "progress=False")
    fetch = 'avll.datasets.fetch("carma")'
    assert fetch in code  # the tour's field data comes by name
    if SHARED.is_dir():  # the shared copy is verified by hash, nothing is downloaded
        code = code.replace(fetch, f'avll.datasets.fetch("carma", dest={str(SHARED / "carma")!r})')
    else:  # no internet in the tests
        code = "\n".join(line for line in code.splitlines() if fetch not in line)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "README tour", "exec"), ns)
    assert ns["codes"].shape == (400, 151, 121)
    assert ns["th"].tg_min_overall == pytest.approx(3.5)
    assert ns["res"].cost < 0.003


def test_readme_is_a_front_page() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines (at most 250)"
    assert sum(1 for line in lines if line.startswith("![")) == 1  # one figure


def test_readme_links_and_figure_exist() -> None:
    text = README.read_text()
    targets = re.findall(r"\]\(((?:docs|benches)/[^)#\s]+)", text)
    assert targets
    missing = [t for t in targets if not (README.parent / t).is_file()]
    assert not missing, f"README.md links to missing files: {missing}"
