"""The defects the last review left listed, each with a test that fails on the code
before: the blank-line scan of CSV files, the one strict-JSON reader,
exogenous signals checked in the API, a missing file, the CLI naming its options."""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import err_line

import avll
from avll import _atomic
from avll.cli import main
from avll.io import read_runs
from avll.io._common import _has_blank_line, record_lines


def _blank_by_regex(data: bytes) -> bool:
    """The definition: an empty or white-space-only line before the last non-blank."""
    return re.search(rb"(^|\n)[ \t]*\r?(\n|$)", data.rstrip()) is not None


def test_blank_line_scan_agrees_with_the_definition_on_every_short_text() -> None:
    alphabet = [b"a", b" ", b"\t", b"\r", b"\n", b","]
    for n in range(7):
        for t in itertools.product(alphabet, repeat=n):
            data = b"".join(t)
            if data.strip():
                assert _has_blank_line(data) == _blank_by_regex(data), data


def test_blank_line_scan_finds_a_blank_line_deep_in_a_large_file(tmp_path: Path) -> None:
    body = b"".join(b"1,%d,0,0\n" % i for i in range(200_000))
    for blank in (b"\n", b"  \n", b"\t\r\n"):
        data = b"run,t,a,command\n" + body + blank + b"1,0,0,0\n"
        assert _has_blank_line(data)
        assert not _has_blank_line(b"run,t,a,command\n" + body + b"\n\n \n")  # trailing
    p = tmp_path / "late.csv"
    p.write_bytes(b"run,t,a,command\n" + body + b"\n" + b"1,9,0,0\n")
    assert record_lines(p, 200_001)[-1] == 200_003  # the last record, past the blank line


@pytest.mark.parametrize(("text", "words"), [
    ('{"a": 1, "a": 2}', "duplicated key 'a'"),
    ('{"a": NaN}', "NaN is not a JSON number"),
    ('[Infinity]', "Infinity is not a JSON number"),
    ('[-Infinity]', "-Infinity is not a JSON number"),
    ('{"a": 1' + "0" * 5000 + "}", "integer string conversion"),
    ('{"a": \n  [1, }', "not valid JSON (line 2, column"),
    ("[" * 100_000 + "]" * 100_000, "nested too deeply to parse"),
])
def test_loads_refuses_what_strict_json_does_not_allow(text: str, words: str) -> None:
    with pytest.raises(ValueError, match=re.escape(words)):
        _atomic.loads(text)


def test_loads_reads_back_what_dumps_writes_and_bounds_the_depth() -> None:
    doc = {"a": [1.5, None, {"b": "c"}], "n": float("nan")}
    assert _atomic.loads(_atomic.dumps(doc)) == json.loads(_atomic.dumps(doc))
    assert _atomic.json_depth({"a": [1, {"b": 2}]}) == 3 and _atomic.json_depth(5) == 0
    assert _atomic.loads('{"a": [[1]]}', max_depth=3) == {"a": [[1]]}
    with pytest.raises(ValueError, match="nested deeper than 2 levels"):
        _atomic.loads('{"a": [[1]]}', max_depth=2)


def test_a_manifest_with_nan_is_not_read_as_complete(tmp_path: Path) -> None:
    with _atomic.output_dir(tmp_path / "o", meta={"command": "test"}) as d:
        (d / "x.txt").write_text("x")
    mp = tmp_path / "o" / _atomic.MANIFEST
    assert _atomic.read_manifest(tmp_path / "o")["complete"] is True
    mp.write_text(mp.read_text().replace('"complete": true', '"complete": NaN'))
    with pytest.raises(ValueError, match="NaN is not a JSON number"):
        _atomic.read_manifest(tmp_path / "o")


def test_exogenous_signals_of_absurd_magnitude_are_refused_in_the_api() -> None:
    m = avll.WithEffects(avll.FirstOrderLag(0.5), (avll.Grade(0.5),))
    u = np.zeros(50)
    # any finite disturbance is accepted (the synthetic platoon's reach beyond 1)
    assert np.all(np.isfinite(avll.simulate(m, u, 0.1, exo={"grade": np.full(50, 3.0)})))
    with pytest.raises(ValueError, match=r"exo\['grade'\]: sample 7 is 1e\+300, beyond the "
                                         r"hard limit \+-1e\+12"):
        avll.simulate(m, u, 0.1, exo={"grade": np.where(np.arange(50) == 7, 1e300, 0.0)})
    with pytest.raises(avll.DataError, match=r"run 'r': column 'exo_grade': sample 0 is 1e\+13"):
        avll.Run("r", np.arange(50) * 0.1, a=u, command=u, command_kind="acceleration",
                 exo={"grade": np.full(50, 1e13)})


def test_a_missing_file_is_a_file_not_found_error_on_every_path(tmp_path: Path) -> None:
    missing = tmp_path / "nope.csv"
    for call in (lambda: read_runs(missing), lambda: avll.io.load_canonical(missing),
                 lambda: read_runs(missing, format="generic"),
                 lambda: avll.io.load_openacc_native(missing)):
        with pytest.raises(FileNotFoundError, match="nope.csv: no such file"):
            call()


def test_cli_names_the_option_a_library_message_asks_for(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "nk.csv"
    p.write_text("run,t,a,command\n1,0,0,0\n1,0.1,0,0\n1,0.2,0,0\n")
    assert main(["load", str(p)]) == 2
    line = err_line(capsys)
    assert "pass --command-kind 'acceleration' or 'speed'" in line
    assert "command_kind" not in line


def test_stability_map_refuses_a_grid_too_large_naming_its_options(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code = main(["stability-map", "--kg", "0.01", "10", "20000", "--tg", "0", "15", "20000",
                 "--kv", "-1", "2", "20000", "--out", str(tmp_path / "m.png")])
    assert code == 2
    line = err_line(capsys)
    assert "--kg x --tg x --kv: 20000 x 20000 x 20000" in line
    assert "use a smaller N in --kg, --tg or --kv" in line
    assert not (tmp_path / "m.png").exists()
