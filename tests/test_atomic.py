"""Atomic outputs, output folders as a unit, outputs that would overwrite inputs, and
escaped HTML."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from loader_helpers import carma_frame, sha
from signal_helpers import SIGINT_DEFAULT, interrupt_once_staged

import avll
from avll import _atomic
from avll import reproduce as R
from avll.cli import main
from avll.io import read_runs, write_runs
from avll.report import Report

TINY = replace(R.SETTINGS["quick"], duration=30.0, max_generations=3, kg_n=16, tg_step=1.0,
               kv_step=0.2, kv_tg_step=1.0, kv_tol=0.05, diagnosis=False)


def _leftovers(folder: Path) -> list[str]:
    """Temporary files or staging folders left behind anywhere below ``folder``."""
    return [p.name for p in folder.rglob("*")
            if ".tmp-" in p.name or p.name.startswith(_atomic.STAGING_PREFIX)]


# ------------------------------------------------------------------ files


def test_write_helpers_replace_whole_files(tmp_path: Path) -> None:
    p = tmp_path / "sub" / "a.json"
    _atomic.write_json(p, {"x": 1})
    assert json.loads(p.read_text()) == {"x": 1}
    _atomic.write_text(p, "two")
    assert p.read_text() == "two"
    assert _leftovers(p.parent) == []
    assert oct(p.stat().st_mode & 0o777) != oct(0o600)  # not the mkstemp mode


def test_strict_json_nulls_nan_with_a_note(tmp_path: Path) -> None:
    """write_json goes through json_safe: a non-finite number is written as null with a
    note beside it (never a NaN/Infinity token); the text is strict JSON."""
    p = _atomic.write_json(tmp_path / "n.json", {"cost": math.inf})
    assert json.loads(p.read_text(), parse_constant=lambda t: 1 / 0) == {
        "cost": None, "cost_note": "inf (not finite)"}
    assert _leftovers(tmp_path) == []
    doc = _atomic.json_safe({"cost": math.inf, "xs": [1.0, float("nan")], "n": np.int64(3)})
    assert doc == {"cost": None, "cost_note": "inf (not finite)", "xs": [1.0, None],
                   "xs_note": "null at 1 position(s) (1): not finite (nan or inf)", "n": 3}


class _HalfThenCtrlC:
    """Stands for a DataFrame or a Figure whose writer is interrupted half way."""

    def _half(self, path: object, *_a: object, **_k: object) -> None:
        Path(str(path)).write_bytes(b"half of the new")
        raise KeyboardInterrupt

    to_csv = to_parquet = savefig = _half


@pytest.mark.parametrize("writer", ["atomic_path", "to_csv", "to_parquet", "savefig",
                                    "write_runs"])
def test_interrupted_write_keeps_the_old_file(tmp_path: Path, writer: str,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    p = tmp_path / "out.csv"
    p.write_bytes(b"old complete content")
    side = Path(str(p) + ".meta.json")
    side.write_bytes(b"old sidecar")
    obj = _HalfThenCtrlC()
    with pytest.raises(KeyboardInterrupt):
        if writer == "atomic_path":
            with _atomic.atomic_path(p) as tmp:
                obj._half(tmp)
        elif writer == "write_runs":
            monkeypatch.setattr(pd.DataFrame, "to_csv", _HalfThenCtrlC._half)
            write_runs(avll.synth.paper_experiment(runs=(1,), duration=5.0), p)
        else:
            getattr(_atomic, writer)(obj, p)
    assert p.read_bytes() == b"old complete content"
    assert side.read_bytes() == b"old sidecar"
    assert _leftovers(tmp_path) == []


_SLOW_WRITER = textwrap.dedent("""
    import sys, time
    from avll import _atomic
    with _atomic.atomic_path(sys.argv[1]) as tmp:
        with open(tmp, "w") as f:
            f.write("run,t,a\\n1,0,0\\n")
            f.flush()
            print("writing", flush=True)
            time.sleep(60)
            f.write("1,0.1,0\\n")
""")


@pytest.mark.skipif(os.name != "posix", reason="needs SIGINT delivery")
def test_sigint_during_a_write_leaves_nothing(tmp_path: Path) -> None:
    """A real Ctrl-C while a file is half written: no file appears under the final
    name, the temporary file is removed."""
    dest = tmp_path / "o.csv"
    p = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, str(dest)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         **SIGINT_DEFAULT)
    assert p.stdout is not None
    assert p.stdout.readline().strip() == "writing"
    assert any(".tmp-" in n for n in os.listdir(tmp_path))  # the half-written temp file
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=30)
    assert p.returncode != 0 and "KeyboardInterrupt" in err
    assert not dest.exists() and _leftovers(tmp_path) == []


def test_cli_load_interrupted_during_the_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C while ``avll load ... --out o.csv`` writes: exit 130, and o.csv is either
    absent or the previous complete file, never a truncated CSV."""
    src = tmp_path / "c.csv"
    carma_frame().to_csv(src, index=False)
    out = tmp_path / "o.csv"
    real = pd.DataFrame.to_csv

    def half_then_interrupt(self: pd.DataFrame, path: object, **kw: object) -> None:
        real(self.iloc[: len(self) // 2], path, **kw)
        raise KeyboardInterrupt

    monkeypatch.setattr(pd.DataFrame, "to_csv", half_then_interrupt)
    assert main(["load", str(src), "--format", "carma", "--min-duration", "1",
                 "--out", str(out)]) == 130
    assert not out.exists() and not Path(str(out) + ".meta.json").exists()
    assert _leftovers(tmp_path) == []
    monkeypatch.setattr(pd.DataFrame, "to_csv", real)
    assert main(["load", str(src), "--format", "carma", "--min-duration", "1",
                 "--out", str(out)]) == 0
    good = sha(out)
    monkeypatch.setattr(pd.DataFrame, "to_csv", half_then_interrupt)
    assert main(["load", str(src), "--format", "carma", "--min-duration", "1",
                 "--out", str(out)]) == 130
    assert sha(out) == good and len(read_runs(out)) == 2
    assert "interrupted" in capsys.readouterr().err


# ------------------------------------------------------------------ folders


def test_output_dir_commits_as_a_unit(tmp_path: Path) -> None:
    d = tmp_path / "out"
    d.mkdir()
    (d / "notes.txt").write_text("the user's own file")
    with _atomic.output_dir(d, meta={"run": 1}) as st:
        (st / "a.txt").write_text("a1")
        (st / "b.txt").write_text("b1")
        assert not (d / "a.txt").exists()  # nothing visible before the commit
    doc = _atomic.read_manifest(d)
    assert set(doc["files"]) == {"a.txt", "b.txt"} and doc["run"] == 1
    # a second run that writes only a.txt: b.txt (written by the first run) goes
    with _atomic.output_dir(d, meta={"run": 2}) as st:
        (st / "a.txt").write_text("a2")
    assert (d / "a.txt").read_text() == "a2" and not (d / "b.txt").exists()
    assert (d / "notes.txt").read_text() == "the user's own file"
    assert _atomic.read_manifest(d)["run"] == 2
    # an interrupted third run changes nothing
    with pytest.raises(KeyboardInterrupt):
        with _atomic.output_dir(d, meta={"run": 3}) as st:
            (st / "a.txt").write_text("a3")
            raise KeyboardInterrupt
    assert (d / "a.txt").read_text() == "a2" and _atomic.read_manifest(d)["run"] == 2
    assert _leftovers(tmp_path) == []
    # interrupted before anything was committed to a new folder: no folder at all
    with pytest.raises(KeyboardInterrupt):
        with _atomic.output_dir(tmp_path / "new" / "out") as st:
            (st / "a.txt").write_text("a")
            raise KeyboardInterrupt
    assert not (tmp_path / "new" / "out").exists()
    # a reader notices a changed or missing file
    (d / "a.txt").write_text("tampered")
    with pytest.raises(ValueError, match="a.txt differs"):
        _atomic.read_manifest(d)
    (d / "a.txt").unlink()
    with pytest.raises(ValueError, match="a.txt is listed .* but missing"):
        _atomic.read_manifest(d)
    with pytest.raises(ValueError, match="no MANIFEST.json"):
        _atomic.read_manifest(tmp_path)


@pytest.mark.skipif(os.name != "posix", reason="needs SIGINT delivery")
@pytest.mark.parametrize(("sig", "code", "said"), [
    (signal.SIGINT, 130, "interrupted"),
    (signal.SIGTERM, 143, "terminated (SIGTERM)"),  # timeout, schedulers, docker stop
])
def test_interrupted_reproduce_keeps_the_finished_folder(tmp_path: Path, sig: int, code: int,
                                                         said: str) -> None:
    """``avll reproduce --seed 1`` interrupted by SIGINT (or SIGTERM) in the folder of
    a finished seed-0 run: exit 130 (143) and the folder is still the complete,
    consistent seed-0 run (no new figure beside the old report), no staging folder
    left."""
    out = tmp_path / "out"
    R.reproduce(out, settings=TINY, seed=0, progress=False)
    before = {p.name: sha(p) for p in out.iterdir()}
    assert _atomic.read_manifest(out)["seed"] == 0
    p = subprocess.Popen([sys.executable, "-m", "avll.cli", "reproduce", "--out", str(out),
                          "--seed", "1", "--quick", "-q"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, **SIGINT_DEFAULT)
    interrupt_once_staged(p, out, sig=sig)
    _, err = p.communicate(timeout=60)
    assert p.returncode == code, err
    assert err.strip().splitlines()[-1] == f"avll reproduce: {said}"
    assert {p.name: sha(p) for p in out.iterdir()} == before
    doc = _atomic.read_manifest(out)
    assert doc["seed"] == 0
    assert json.loads((out / "summary.json").read_text())["seed"] == 0
    assert _leftovers(tmp_path) == []


def test_ctrl_c_caught_inside_a_string_exec_still_exits_130_under_python_m(
        tmp_path: Path) -> None:
    """CPython marks a KeyboardInterrupt that ends a string ``exec`` as unhandled even
    when it is caught (a Ctrl-C landing in code that ``dataclasses`` generates did this
    to ``python -m avll.cli reproduce``: it printed "interrupted" and then died by
    SIGINT, exit -2, when interrupted near the end of a run). ``main`` forgets the
    mark, so the exit code stays 130."""
    (tmp_path / "probe_interrupt.py").write_text(textwrap.dedent("""
        import sys

        import avll.cli as cli


        def interrupted(argv):
            try:
                exec("raise KeyboardInterrupt", {})
            except KeyboardInterrupt:
                return 130
            return 0


        cli._main = interrupted
        sys.exit(cli.main([]))
    """))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, "-m", "probe_interrupt"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 130, r.stderr


def test_reproduce_writes_a_manifest_and_replaces_its_own_files(tmp_path: Path) -> None:
    R.reproduce(tmp_path, settings=TINY, seed=0, progress=False)
    doc = _atomic.read_manifest(tmp_path)
    assert {"report.md", "report.html", "summary.json"} <= set(doc["files"])
    assert all(f in doc["files"] for f in json.loads(
        (tmp_path / "summary.json").read_text())["files"]["figures"].values())


# ------------------------------------------------------------------ output == input


def test_write_runs_refuses_its_source(tmp_path: Path) -> None:
    p = tmp_path / "c.csv"
    carma_frame().to_csv(p, index=False)
    before = sha(p)
    runs = avll.io.load_carma(p, min_duration=1.0)
    with pytest.raises(ValueError, match="is the file run .* was read from"):
        write_runs(runs, p)
    assert sha(p) == before


@pytest.mark.parametrize("how", ["same", "relative", "symlink", "hardlink"])
def test_cli_refuses_an_output_that_is_the_input(tmp_path: Path, how: str,
                                                 capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    src = tmp_path / "data5.csv"
    carma_frame().to_csv(src, index=False)
    before = sha(src)
    monkeypatch.chdir(tmp_path)
    out = {"same": str(src), "relative": "./sub/../data5.csv", "symlink": "link.csv",
           "hardlink": "hard.csv"}[how]
    if how == "symlink":
        os.symlink(src, tmp_path / "link.csv")
    if how == "hardlink":
        os.link(src, tmp_path / "hard.csv")
    assert main(["load", str(src), "--format", "carma", "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out" in err and "is the input PATH" in err
    assert sha(src) == before


def test_cli_refuses_outputs_before_computing(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    runs = avll.synth.paper_experiment(runs=(1, 3), duration=20.0)
    data = write_runs(runs, tmp_path / "runs.csv")
    before = sha(data)
    t0 = time.perf_counter()
    cases = [
        ["calibrate", str(data), "--json", str(data)],
        ["calibrate", str(data), "--figure", str(data)],
        ["calibrate", str(data), "--json", str(tmp_path / "x"), "--figure",
         str(tmp_path / "x")],
        ["diagnose", str(data), "--cal-runs", "1", "--json", str(data)],
        ["diagnose", str(data), "--cal-runs", "1", "--json", str(tmp_path / "d.json"),
         "--report", str(data)],
        ["reproduce", "--data", "carma", "--data-path", str(tmp_path), "--out",
         str(tmp_path)],
    ]
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert "replace the input" in err or "choose" in err, err
    assert time.perf_counter() - t0 < 5.0  # refused before any computation
    assert sha(data) == before and not (tmp_path / "x").exists()


# ------------------------------------------------------------------ HTML


EVIL = "<img src=x onerror=alert(1)>"


def test_report_escapes_every_text(tmp_path: Path) -> None:
    rep = Report(EVIL)
    rep.heading(EVIL)
    rep.para(f"run **{EVIL}** and `{EVIL}`")
    rep.bullets([EVIL])
    rep.table([EVIL], [[EVIL]], caption=EVIL)
    rep.figure("a.png", EVIL)
    rep.code(EVIL)
    md, ht = rep.write(tmp_path)
    html_text = ht.read_text()
    assert "<img src=x" not in html_text and "onerror=alert(1)>" not in html_text
    assert html_text.count("&lt;img src=x onerror=alert(1)&gt;") >= 8
    # a Markdown viewer would render raw HTML, except in a fenced code block
    outside = md.read_text().split("```")[0::2]
    assert all("<img src=x" not in part for part in outside)


def test_diagnose_report_escapes_run_ids(tmp_path: Path) -> None:
    """The issue's case: a run id that is an HTML tag, through ``avll diagnose
    --report``; the report is also a complete folder (manifest)."""
    from avll.synth_effects import paper_experiment_effects

    runs = paper_experiment_effects(avll.FirstOrderLag(Td=0.6), {"delay": None}, seed=0)
    runs = [replace(r, run_id=EVIL if i == 1 else r.run_id) for i, r in enumerate(runs)]
    data = write_runs(runs, tmp_path / "evil.csv")
    rep = tmp_path / "rep"
    assert main(["diagnose", str(data), "--model", "first", "--cal-runs", "1,8,12",
                 "--json", str(tmp_path / "d.json"), "--report", str(rep), "--quiet"]) == 0
    text = (rep / "report.html").read_text()
    assert EVIL not in text and "&lt;img src=x onerror=alert(1)&gt;" in text
    assert "report.html" in _atomic.read_manifest(rep)["files"]


@pytest.mark.usefixtures("sigint_handler")
def test_ctrl_c_right_after_a_temporary_is_created_leaves_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A Ctrl-C landing just after ``mkdtemp`` / ``mkstemp`` made the temporary, before
    avll knew it (the signal delivered inside the call here), once left the staging
    folder or the temporary file behind; the creation now runs with Ctrl-C deferred,
    so the interrupt arrives once the cleanup knows the temporary."""
    import tempfile

    real_mkdtemp, real_mkstemp = tempfile.mkdtemp, tempfile.mkstemp

    def mkdtemp(*a: Any, **k: Any) -> str:
        made = real_mkdtemp(*a, **k)
        signal.raise_signal(signal.SIGINT)
        return made

    def mkstemp(*a: Any, **k: Any) -> tuple[int, str]:
        made = real_mkstemp(*a, **k)
        signal.raise_signal(signal.SIGINT)
        return made

    monkeypatch.setattr(tempfile, "mkdtemp", mkdtemp)
    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    (tmp_path / "d").mkdir()
    with pytest.raises(KeyboardInterrupt), _atomic.output_dir(tmp_path / "d"):
        pass
    with pytest.raises(KeyboardInterrupt), _atomic.atomic_paths(tmp_path / "f.json"):
        pass
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["d"]
