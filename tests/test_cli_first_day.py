"""A new user's first day with the ``avll`` command: each test reproduces one
finding of the audit and checks that it now ends in a clear error or a correct result.

Findings: outputs over an input's sidecar; one command's output folder replaced by
another's; a closed pipe as an error; a hard-coded kv search range; nan for "none";
16-18 digit numbers and float counts; a 101-row table and an empty panel; a help text
describing a ramp that is not there; ``--strict`` and ``--model`` with more than one
meaning; degenerate data accepted silently; figures without ``--dpi`` or vector formats;
raw identifiers as captions; Ctrl-C while importing printing a traceback; a multi-file
output left mixed by Ctrl-C.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import err_line
from signal_helpers import SIGINT_DEFAULT

from avll.cli import build_parser, main

SMALL_MAP = ["--kg", "0.001", "2", "30", "--tg", "0", "15", "31", "--kv", "0", "1", "101"]


@pytest.fixture(scope="module")
def runs_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("runs")
    path = d / "runs.csv"
    assert main(["synth", "--out", str(path), "--duration", "20"]) == 0
    return path


# -- nothing lost ----------------------------------------------------------------------


def test_no_output_is_an_inputs_sidecar(runs_csv: Path, capsys: pytest.CaptureFixture[str]
                                        ) -> None:
    side = runs_csv.with_name(runs_csv.name + ".meta.json")
    before = side.read_bytes()
    capsys.readouterr()
    for argv in (["load", str(runs_csv), "--out", str(side)],
                 ["load", str(runs_csv), "--json", str(side)],
                 ["calibrate", str(runs_csv), "--json", str(side)],
                 ["diagnose", str(runs_csv), "--cal-runs", "1", "--json", str(side)]):
        assert main(argv) == 2, argv
        err_line(capsys, "sidecar", "would replace the input")
    assert side.read_bytes() == before


def test_no_output_is_a_file_of_an_input_folder(runs_csv: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "data"
    folder.mkdir()
    for f in runs_csv.parent.glob("runs.csv*"):
        (folder / f.name).write_bytes(f.read_bytes())
    capsys.readouterr()
    assert main(["load", str(folder), "--json", str(folder / "runs.csv")]) == 2
    err_line(capsys, "a file it holds", "would replace the input")


def test_reproduce_then_simulate_with_defaults_keeps_the_report(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from avll.cli.reproduce import DEFAULT_OUT as REPRO
    from avll.cli.simulate import DEFAULT_OUT as SIM

    assert REPRO != SIM
    monkeypatch.chdir(tmp_path)
    # a finished reproduction as `avll reproduce` leaves it (its manifest last)
    from avll import _atomic

    with _atomic.output_dir(REPRO, meta={"command": "avll reproduce"}) as st:
        (st / "report.md").write_text("# report\n")
        (st / "summary.json").write_text("{}\n")
    assert main(["simulate"]) == 0
    doc = _atomic.read_manifest(REPRO)  # still complete and unchanged
    assert sorted(doc["files"]) == ["report.md", "summary.json"]
    assert (Path(SIM) / "simulate.csv").is_file()


def test_a_folder_of_another_command_is_refused_unless_overwrite(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from avll import _atomic

    out = tmp_path / "shared-out"
    with _atomic.output_dir(out, meta={"command": "avll reproduce"}) as st:
        (st / "report.md").write_text("# report\n")
    capsys.readouterr()
    assert main(["simulate", "--out", str(out)]) == 2
    err_line(capsys, "holds the output of 'avll reproduce'", "--overwrite")
    assert (out / "report.md").is_file() and not (out / "simulate.csv").exists()
    # its own folder again: fine
    own = tmp_path / "own"
    assert main(["simulate", "--out", str(own)]) == 0
    assert main(["simulate", "--out", str(own)]) == 0
    assert main(["simulate", "--out", str(out), "--overwrite"]) == 0
    assert (out / "simulate.csv").is_file()


def test_stability_map_outputs_are_committed_together(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Ctrl-C while the second figure is drawn: the old figure, thresholds figure and
    # JSON stay as they were (no new figure beside the old JSON), and no temporary
    # file is left
    paths = [tmp_path / "map.png", tmp_path / "th.png", tmp_path / "th.json"]
    for p in paths:
        p.write_text("old")
    from avll import _atomic

    real = _atomic.figure_bytes
    calls = []

    def flaky(fig, fmt, **kw):  # type: ignore[no-untyped-def]
        calls.append(fmt)  # the second figure, after the first one was written
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(fig, fmt, **kw)

    monkeypatch.setattr(_atomic, "figure_bytes", flaky)
    argv = ["stability-map", "--models", "first", *SMALL_MAP, "--out", str(paths[0]),
            "--thresholds-out", str(paths[1]), "--json", str(paths[2]), "-q"]
    assert main(argv) == 130
    assert [p.read_text() for p in paths] == ["old"] * 3
    assert sorted(f.name for f in tmp_path.iterdir()) == ["map.png", "th.json", "th.png"]
    monkeypatch.setattr(_atomic, "figure_bytes", real)
    assert main(argv) == 0
    doc = json.loads(paths[2].read_text())
    # the JSON, renamed last, lists the figures it was written with
    for p in paths[:2]:
        assert doc["outputs"][str(p)]["sha256"] == hashlib.sha256(p.read_bytes()).hexdigest()


def _run_avll(argv: list[str], cwd: Path, **kw: object) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "avll", *argv], cwd=cwd, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)  # type: ignore[call-overload]


def test_ctrl_c_while_importing_or_exiting_is_one_line_and_130(tmp_path: Path) -> None:
    # SIGINT at spread-out instants from the moment avll's first module is imported (the
    # interpreter's own start-up is before any avll code) to past the end of a short
    # command: never a traceback, never a bare signal exit; 130 with a one-line message,
    # or 0 when the signal came too late to matter. `-X importtime` says on stderr when
    # the first module has been imported.
    codes = []
    for delay in (0.0, 0.01, 0.03, 0.06, 0.1, 0.15, 0.25, 0.4, 0.7, 1.0, 1.5, 2.5):
        argv = [sys.executable, "-X", "importtime", "-m", "avll", "simulate", "--out",
                str(tmp_path / f"o{delay}")]
        with subprocess.Popen(argv, cwd=tmp_path, text=True, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, **SIGINT_DEFAULT) as p:
            assert p.stderr is not None
            seen = []
            for line in p.stderr:
                seen.append(line)
                if line.rstrip().endswith("avll._startup"):
                    break
            time.sleep(delay)
            p.send_signal(signal.SIGINT)
            out, rest = p.communicate(timeout=120)
        err = "".join(ln for ln in [*seen, *rest.splitlines(True)]
                      if not ln.startswith("import time:"))
        if "Traceback" in err or p.returncode not in (0, 130):
            # the whole stderr (pytest shortens an assertion's message; a rare failure
            # at exit, once in CI, was cut before its cause): shown as captured output
            print(f"delay {delay} s, exit {p.returncode}, stderr:\n{err}")
        assert "Traceback" not in err, (delay, err)
        assert p.returncode in (0, 130), (delay, p.returncode, err)
        if p.returncode == 130:
            assert re.fullmatch(r"avll( simulate)?: interrupted", err.strip()), (delay, err)
        codes.append(p.returncode)
    assert 130 in codes, codes


_HIDDEN_CTRL_C = """
import os, signal, sys
sys.argv = ["avll", "simulate", "--out", sys.argv[1]]  # the avll command's process
import avll.cli.simulate as sim


def run(args):
    class Lands:  # a Ctrl-C while a class is created: Python 3.11 raises RuntimeError
        def __set_name__(self, owner, name):  # ("Error calling __set_name__") from it
            os.kill(os.getpid(), signal.SIGINT)
            sum(range(100_000))

    type("Lazy", (), {"field": Lands()})
    raise AssertionError("the Ctrl-C was lost")


sim._cmd = run
from avll.cli import main
sys.exit(main())
"""


def test_a_ctrl_c_hidden_in_another_error_is_one_line_and_130(tmp_path: Path) -> None:
    # the Ctrl-C was latched, so whatever error carries it out (here the RuntimeError
    # CPython 3.11 wraps around an exception of __set_name__, seen when a SIGINT landed
    # in a lazily imported module's dataclass) the command says "interrupted", 130
    script = tmp_path / "hidden.py"
    script.write_text(_HIDDEN_CTRL_C, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    p = subprocess.run([sys.executable, str(script), str(tmp_path / "o")], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120, env=env, **SIGINT_DEFAULT)
    assert (p.returncode, p.stderr.strip()) == (130, "avll simulate: interrupted"), p.stderr
    assert not (tmp_path / "o").exists()


_CTRL_C_AT_A_HAND_OVER = """
import os, signal, sys
where = sys.argv[2]  # one Ctrl-C right after the command's handler is installed, or
sent = []            # after the command's end, before quiet_exit takes over again
sys.argv = ["avll", "simulate", "--out", sys.argv[1]]  # the avll command's process
import avll.cli as cli
from avll import _sigint


def lands():
    if not sent:
        sent.append(1)
        os.kill(os.getpid(), signal.SIGINT)
        sum(range(100_000))


if where == "start":
    starts = _sigint.command_starts
    _sigint.command_starts = lambda: (starts(), lands())
else:
    cli._forget_unhandled_interrupt = lands
sys.exit(cli.main())
"""


@pytest.mark.parametrize("where", ["start", "end"])
def test_a_ctrl_c_at_the_hand_over_of_the_handlers_is_one_line_and_130(
        tmp_path: Path, where: str) -> None:
    # around the command (avll.cli.main) there are a few bytecodes in which Python's
    # KeyboardInterrupt is raised outside the command's own handling: at the start
    # nothing is written, at the end the outputs are committed; one line and 130 both
    script = tmp_path / "hand_over.py"
    script.write_text(_CTRL_C_AT_A_HAND_OVER, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    p = subprocess.run([sys.executable, str(script), str(tmp_path / "o"), where],
                       cwd=tmp_path, capture_output=True, text=True, timeout=120, env=env,
                       **SIGINT_DEFAULT)
    assert p.returncode == 130, p.stderr
    assert p.stderr.splitlines()[-1] == "avll: interrupted", p.stderr
    assert "Traceback" not in p.stderr
    assert (tmp_path / "o" / "MANIFEST.json").is_file() == (where == "end")


def test_a_closed_pipe_ends_quietly_with_exit_0(runs_csv: Path, tmp_path: Path) -> None:
    for argv in (["stability-map", "--models", "first", *SMALL_MAP, "--out",
                  str(tmp_path / "m.png"), "-q"],
                 ["load", str(runs_csv)]):
        with _run_avll(argv, tmp_path) as p:
            assert p.stdout is not None and p.stderr is not None
            first = p.stdout.readline()  # `| head -1`
            p.stdout.close()
            err = p.stderr.read()
            p.wait(timeout=120)
        assert first and p.returncode == 0, (argv, p.returncode, err)
        assert "Broken pipe" not in err and "Traceback" not in err, err
    assert (tmp_path / "m.png").is_file()  # the output is still written


def test_a_pipe_closed_before_the_first_line_ends_quietly(runs_csv: Path, tmp_path: Path
                                                          ) -> None:
    # the reader is gone before the command prints anything (`| head -0`, or a small
    # output that a `head` would otherwise read whole): every write meets EPIPE
    import os

    for argv in (["load", str(runs_csv), "--json", str(tmp_path / "clean.json")],
                 ["stability-map", "--models", "first", *SMALL_MAP, "--out",
                  str(tmp_path / "m2.png"), "-q"]):
        r, w = os.pipe()
        with subprocess.Popen([sys.executable, "-m", "avll", *argv], cwd=tmp_path,
                              stdout=w, stderr=subprocess.PIPE, text=True) as p:
            os.close(w)
            os.close(r)
            _, err = p.communicate(timeout=120)
        assert p.returncode == 0, (argv, p.returncode, err)
        assert "Broken pipe" not in err and "Traceback" not in err and "error" not in err, err
    # and the files were written all the same
    assert (tmp_path / "clean.json").is_file() and (tmp_path / "m2.png").is_file()


# -- search ranges, none, precision, counts ----------------------------------------------


def test_exact_kv_search_uses_the_grid_and_says_there_is_no_threshold(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["stability-map", "--models", "first,proposed", "--exact", *SMALL_MAP,
               "--out", str(tmp_path / "m.png"), "--json", str(tmp_path / "m.json"), "-q"])
    assert rc == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("first ") and "inf Tg" in ln)
    assert "sup kv: no threshold in the given range" in line and "kv = 1 " in line
    assert "2.000000" not in out
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["exact"]["first"]["kv_supremum"]["ranges"]["kv"] == [0.0, 1.0]  # the grid's
    prop = next(ln for ln in out.splitlines() if ln.startswith("proposed ") and "sup kv" in ln)
    assert re.search(r"sup kv 0\.7\d+ 1/s", prop), prop
    # "none", never nan, where there is no value
    assert not re.search(r"\bnan\b", out, re.I)
    assert "none" in out
    # at most 11 kv rows of the 101 (the JSON has them all), integers as integers
    rows = [ln for ln in out.splitlines() if re.match(r"^\s+[0-9.]+\s+(>= )?[0-9.]", ln)]
    assert 2 <= len(rows) <= 11 and "11 of 101 kv values shown" in out
    assert len(doc["models"]["first"]["kg_max"]) == 101


def test_region_panels_are_never_empty() -> None:
    from avll.cli.stability_map import _panel_indices
    from avll.stability import STABLE

    maps = [np.zeros((4, 5, 101), dtype=np.uint8)]
    maps[0][1, 2, :75] = STABLE  # stable up to kv index 74, as the proposed model
    idx = _panel_indices(maps, 101, 3)
    assert list(idx) == [0, 37, 74]
    assert all((maps[0][:, :, i] == STABLE).any() for i in idx)


def test_simulate_csv_carries_its_precision_only(tmp_path: Path) -> None:
    assert main(["simulate", "--out", str(tmp_path / "s")]) == 0
    rows = (tmp_path / "s" / "simulate.csv").read_text().splitlines()
    assert rows[0] == "t,command,first,second,proposed"
    digits = max(len(re.sub(r"[^0-9]", "", c.split("e")[0]).lstrip("0"))
                 for r in rows[1:] for c in r.split(","))
    assert digits <= 10, digits


def test_simulate_help_describes_the_command_it_simulates(
        capsys: pytest.CaptureFixture[str]) -> None:
    from avll.demo import demo_command

    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "ramp" not in text
    assert "1 m/s² for 10 s, -0.5 m/s² for 10 s, then a 0.1 Hz sine of amplitude 0.8" in text
    u = demo_command(0.05)
    t = np.arange(u.size) * 0.05
    assert np.all(u[t < 10] == 1.0) and np.all(u[(t >= 10) & (t < 20)] == -0.5)
    assert np.max(np.abs(u[t >= 20])) == pytest.approx(0.8, abs=1e-3)


def test_progress_counts_are_integers() -> None:
    import io

    from avll.progress import Progress

    buf = io.StringIO()
    with Progress(7308400, "map", unit="pt", mode="log", file=buf) as p:
        p.advance_to(1234567)
    text = buf.getvalue()
    assert "(0/7308400 pt)" in text and "e+" not in text


def test_diagnose_report_numbers_and_captions() -> None:
    from avll import PAPER_TABLE_II
    from avll.diagnose.report import CAPTIONS, model_text
    from avll.plotting import signal_axis_label

    text = model_text(PAPER_TABLE_II["proposed"])
    assert text == "Proposed(m1=6.789, m2=1.282, m3=8.816, K0=0.3479, Td=0.7903, K=0.1008)"
    for name, caption in CAPTIONS.items():
        assert "_" not in caption and len(caption.split()) >= 8, name
    assert signal_axis_label("speed") == "speed (m/s)"
    assert signal_axis_label("command rate") == "command rate (command unit/s)"


@pytest.mark.slow
def test_diagnose_report_has_captions_and_no_long_floats(runs_csv: Path, tmp_path: Path
                                                         ) -> None:
    rep = tmp_path / "rep"
    assert main(["diagnose", str(runs_csv), "--cal-runs", "1,3", "--val-runs", "2",
                 "--max-generations", "5", "--starts", "1", "--max-effects", "1",
                 "--candidates", "saturation", "--json", str(tmp_path / "d.json"),
                 "--report", str(rep), "-q"]) == 0
    md = (rep / "report.md").read_text()
    assert not re.search(r"\d\.\d{9,}", md), "a number with more digits than it carries"
    captions = re.findall(r"!\[([^\]]*)\]", md)
    assert captions and all(" " in c and not re.fullmatch(r"\w+", c) for c in captions)


# -- options: one meaning each, only where they apply -------------------------------------


def _leaf_parsers() -> dict[str, object]:
    import argparse

    out = {}
    root = build_parser()
    stack = [("", root)]
    while stack:
        name, p = stack.pop()
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            out[name.strip()] = p
        for s in subs:
            for n, q in s.choices.items():
                stack.append((f"{name} {n}", q))
    return out


def test_strict_only_where_data_are_read() -> None:
    leaves = _leaf_parsers()
    with_strict = {n for n, p in leaves.items()
                   if any("--strict" in a.option_strings for a in p._actions)}  # type: ignore[attr-defined]
    assert {"load", "calibrate", "diagnose", "reproduce"} <= with_strict
    assert not ({"simulate", "synth", "stability-map"} & with_strict)


def test_model_means_one_model_everywhere_and_no_abbreviations() -> None:
    from avll.cli._common import MODEL_NAMES

    for name, p in _leaf_parsers().items():
        for a in p._actions:  # type: ignore[attr-defined]
            if "--model" in a.option_strings:
                assert a.option_strings == ["--model"] and a.nargs is None, name
                assert list(a.choices) == list(MODEL_NAMES), name
        assert p.allow_abbrev is False, name  # type: ignore[attr-defined]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["calibrate", "x.csv", "--model", "first"])


def test_json_and_report_mean_one_thing_each() -> None:
    # --json: a strict JSON file; --report: a folder with a Markdown/HTML report (load's
    # cleaning JSON was once --report)
    for name, p in _leaf_parsers().items():
        for a in p._actions:  # type: ignore[attr-defined]
            if "--json" in a.option_strings:
                assert a.metavar == "PATH" and "strict JSON" in a.help, name
            if "--report" in a.option_strings:
                assert a.metavar == "DIR" and "report" in a.help, name


def test_figures_take_dpi_and_vector_formats(runs_csv: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    base = ["stability-map", "--models", "first", *SMALL_MAP, "-q"]
    assert main([*base, "--out", str(tmp_path / "a.png"), "--dpi", "40"]) == 0
    assert main([*base, "--out", str(tmp_path / "b.png"), "--dpi", "160"]) == 0
    def width(png: Path) -> int:  # the IHDR chunk's width, big-endian at byte 16
        return int.from_bytes(png.read_bytes()[16:20], "big")

    wa, wb = width(tmp_path / "a.png"), width(tmp_path / "b.png")
    assert wb == pytest.approx(4 * wa, rel=0.02)
    assert main([*base, "--out", str(tmp_path / "c.svg"),
                 "--thresholds-out", str(tmp_path / "c.pdf")]) == 0
    assert (tmp_path / "c.svg").read_text().lstrip().startswith("<?xml")
    assert (tmp_path / "c.pdf").read_bytes().startswith(b"%PDF")
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "d.jpeg")]) == 2
    err_line(capsys, "--out", ".png, .svg, .pdf")


# -- degenerate input -----------------------------------------------------------------


def _table(path: Path, rows: dict[str, tuple[np.ndarray, np.ndarray]]) -> Path:
    lines = ["run,t,command,a"]
    for rid, (u, a) in rows.items():
        lines += [f"{rid},{0.05 * i:.2f},{u[i]:g},{a[i]:g}" for i in range(u.size)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_degenerate_input_is_an_error_naming_the_file(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    z = _table(tmp_path / "zero.csv", {"1": (np.zeros(2), np.zeros(2))})
    c = _table(tmp_path / "const.csv", {"r": (np.full(400, 0.5), np.full(400, 0.5))})
    o = _table(tmp_path / "allzero.csv", {"r": (np.zeros(400), np.zeros(400))})
    capsys.readouterr()
    for path, words in ((z, "too short: 2 samples"), (c, "command and a are constant"),
                        (o, "all zero")):
        assert main(["calibrate", str(path), "--command-kind", "acceleration",
                     "--max-generations", "2", "--starts", "1", "-q"]) == 2
        err_line(capsys, path.name, words, "nothing to calibrate")


def test_one_degenerate_run_among_good_ones_is_a_warning(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    t = np.arange(400) * 0.05
    u = np.sin(t)
    a = np.convolve(u, np.full(10, 0.1))[:400]
    path = _table(tmp_path / "mixed.csv", {"good": (u, a), "flat": (np.zeros(400),
                                                                     np.zeros(400))})
    rc = main(["calibrate", str(path), "--command-kind", "acceleration", "--models", "first",
               "--cal-runs", "good,flat", "--max-generations", "2", "--starts", "1", "-q"])
    err = capsys.readouterr().err
    assert rc == 0
    assert "warning: " in err and "mixed.csv: run 'flat': command and a are all zero" in err
    rc = main(["calibrate", str(path), "--command-kind", "acceleration", "--models", "first",
               "--cal-runs", "good,flat", "--max-generations", "2", "--starts", "1", "-q",
               "--strict"])
    assert rc == 2


def test_output_group_commits_files_and_folders_as_one_unit(tmp_path: Path) -> None:
    from avll import _atomic

    a, b, d = tmp_path / "a.json", tmp_path / "b.txt", tmp_path / "rep"
    with _atomic.output_group():
        _atomic.write_json(a, {"v": 1})
        with _atomic.output_dir(d, meta={"command": "avll diagnose"}) as st:
            _atomic.write_text(st / "report.md", "one")
        _atomic.write_text(b, "one")
        # nothing visible yet (the folder holds only its hidden staging folder)
        assert not a.exists() and not b.exists()
        assert [p.name.startswith(".avll-tmp-") for p in d.iterdir()] == [True]
    assert json.loads(a.read_text()) == {"v": 1} and b.read_text() == "one"
    assert _atomic.read_manifest(d)["files"].keys() == {"report.md"}
    # Ctrl-C after some outputs were written: every destination as it was, no debris
    with pytest.raises(KeyboardInterrupt), _atomic.output_group():
        _atomic.write_json(a, {"v": 2})
        with _atomic.output_dir(d, meta={"command": "avll diagnose"}) as st:
            _atomic.write_text(st / "report.md", "two")
        raise KeyboardInterrupt
    assert json.loads(a.read_text()) == {"v": 1}
    assert (d / "report.md").read_text() == "one" and _atomic.read_manifest(d)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.txt", "rep"]
    assert sorted(p.name for p in d.iterdir()) == ["MANIFEST.json", "report.md"]


def test_calibrate_tables_say_none_not_nan(runs_csv: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", str(runs_csv), "--max-generations", "2", "--starts", "1",
                 "-q"]) == 0
    out = capsys.readouterr().out
    assert not re.search(r"\bnan\b", out, re.I), out
    assert "-: not a parameter of that model" in out


def test_the_sidecar_of_a_runs_output_is_an_output_too(runs_csv: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    out = tmp_path / "canon.csv"
    capsys.readouterr()
    assert main(["load", str(runs_csv), "--out", str(out), "--json",
                 str(tmp_path / "canon.csv.meta.json")]) == 2
    err_line(capsys, "--out (its sidecar)", "choose distinct names")
    # an input's sidecar as the sidecar of the output: the output is the input itself
    assert main(["synth", "--out", str(tmp_path / "s.csv")]) == 0
    assert main(["load", str(tmp_path / "s.csv"), "--out", str(tmp_path / "s.csv")]) == 2


@pytest.mark.slow
def test_real_reproduce_then_simulate_with_defaults(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from avll import _atomic
    from avll.cli.reproduce import DEFAULT_OUT

    monkeypatch.chdir(tmp_path)
    assert main(["reproduce", "--quick", "--no-diagnosis", "-q"]) == 0
    before = _atomic.read_manifest(DEFAULT_OUT)
    assert "report.md" in before["files"] and "summary.json" in before["files"]
    assert main(["simulate"]) == 0
    assert _atomic.read_manifest(DEFAULT_OUT) == before  # verified file by file


def test_load_json_carries_the_precision_of_the_data(runs_csv: Path, tmp_path: Path) -> None:
    out = tmp_path / "clean.json"
    assert main(["load", str(runs_csv), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["1"]["dt"] == 0.05 and doc["1"]["duration_s"] == 19.95
    assert not re.search(r"\d\.\d{13,}", out.read_text())
