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
    if SHARED.is_dir():
        code = code.replace('"../shared/data/carma"', repr(str(SHARED / "carma")))
    else:
        code = "\n".join(line for line in code.splitlines() if "shared/data" not in line)
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "README tour", "exec"), ns)
    assert ns["codes"].shape == (400, 151, 121)
    assert ns["th"].tg_min_overall == pytest.approx(3.5)
    assert ns["res"].cost < 0.003


def _numbers_script():  # benches/readme_numbers.py (benches is not a package)
    import importlib.util

    path = README.parent / "benches" / "readme_numbers.py"
    spec = importlib.util.spec_from_file_location("readme_numbers", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


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


def test_readme_cli_table_is_the_parser() -> None:
    rn = _numbers_script()
    commands = rn.cli_commands()
    assert {name for name, _ in commands} >= {"reproduce", "calibrate", "stability-map"}
    assert rn.read_block(README.read_text(), "cli") == rn.render_cli(commands), (
        "README.md's command table is stale: run python benches/readme_numbers.py"
    )


def test_readme_section_iv_numbers_match_the_code() -> None:
    rn = _numbers_script()
    numbers = rn.section_iv()
    # the paper's Section IV must come out of the code (not only the README)
    assert numbers["models"]["proposed"]["min_tg"] == pytest.approx(3.5)
    assert numbers["models"]["second"]["kv_threshold"] == pytest.approx(0.8085, abs=1e-3)
    assert rn.read_block(README.read_text(), "section-iv") == rn.render_section_iv(numbers), (
        "README.md's Section IV block is stale: run python benches/readme_numbers.py"
    )
