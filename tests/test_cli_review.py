"""Findings of a review of the ``avll`` command, each reproduced on the old code:
``stability-map --exact`` without ``--threads``; grids and capacity options checked only
after the maps were computed; ``--from`` read leniently, with errors naming neither the
option nor the file (an OverflowError traceback); ``calibrate --figure-run`` checked after
the calibration and a "wrote" line for a file then rolled back; an ArithmeticError
escaping as a traceback; wrong texts in ``simulate --dt``, ``avll --help`` (data) and
``calibrate --closed-loop``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_helpers import err_line

import avll
import avll.calibration
import avll.demo
import avll.stability
from avll import _atomic
from avll.cli import build_parser, main

TINY = ["--kg", "0.01", "2", "5", "--tg", "0", "15", "6", "--kv", "0", "1", "3",
        "--threads", "1", "-q"]


@pytest.fixture
def no_maps(monkeypatch: pytest.MonkeyPatch) -> None:
    """Computing a map is a test failure: the error must come before."""
    def boom(*a: Any, **k: Any) -> Any:
        raise AssertionError("stability_map was called")

    monkeypatch.setattr(avll.stability, "stability_map", boom)


# -- 1. --exact honours --threads -----------------------------------------------------


def test_exact_passes_threads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[tuple[str, Any]] = []
    for name in ("min_stable_tg", "kv_supremum"):
        real = getattr(avll.stability, name)

        def spy(*a: Any, _real: Any = real, _name: str = name, **k: Any) -> Any:
            seen.append((_name, k.get("threads")))
            return _real(*a, **k)

        monkeypatch.setattr(avll.stability, name, spy)
    assert main(["stability-map", "--models", "first", *TINY, "--exact",
                 "--out", str(tmp_path / "m.png")]) == 0
    assert seen == [("min_stable_tg", 1), ("kv_supremum", 1)]


# -- 2., 3. the grid and the capacity options before any computation ------------------


@pytest.mark.parametrize(("axis", "words"), [
    (["--kg", "0.01", "2", "1"], ("--kg", "N", ">= 2", "got 1")),
    (["--tg", "1", "1", "6"], ("--tg", "MIN < MAX")),
    (["--kv", "0", "1", str(10**18)], ("--kv", "use a smaller N")),
])
def test_axis_refused_before_computing(axis: list[str], words: tuple[str, ...],
                                       tmp_path: Path, no_maps: None,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stability-map", "--models", "first", *TINY, *axis,
                 "--out", str(tmp_path / "m.png")]) == 2
    err = err_line(capsys, *words)
    assert "allocate" not in err
    assert not (tmp_path / "m.png").exists()


@pytest.mark.parametrize(("opt", "value"), [("--length", "-1"), ("--speed", "0"),
                                            ("--speed", "nan")])
def test_capacity_options_checked_up_front(opt: str, value: str, tmp_path: Path,
                                           no_maps: None,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stability-map", "--models", "first", *TINY, opt, value,
                 "--out", str(tmp_path / "m.png")]) == 2
    err = err_line(capsys, f"error: {opt}: ")
    assert f"error: {opt[2:]}:" not in err


# -- 4. calibrate --figure-run, "wrote" only once committed ---------------------------


@pytest.fixture
def small_runs(tmp_path: Path) -> Path:
    """Two open-loop runs (command and acceleration, no leader) of 300 samples."""
    t = np.arange(300) * 0.05
    lines = ["run,t,command,a"]
    for rid, f in (("r1", 0.3), ("r2", 0.5)):
        u = np.sin(2 * np.pi * f * t)
        a = np.convolve(u, np.full(10, 0.1))[: t.size]
        lines += [f"{rid},{t[i]:.2f},{u[i]:.6g},{a[i]:.6g}" for i in range(t.size)]
    path = tmp_path / "runs.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


CAL = ["--command-kind", "acceleration", "--models", "first", "--max-generations", "2",
       "--starts", "1", "--threads", "1", "-q"]


def test_unknown_figure_run_refused_before_calibrating(
        small_runs: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    def boom(*a: Any, **k: Any) -> Any:
        raise AssertionError("calibrated before checking --figure-run")

    monkeypatch.setattr(avll.calibration, "paper_workflow", boom)
    js = tmp_path / "cal.json"
    assert main(["calibrate", str(small_runs), *CAL, "--json", str(js), "--figure",
                 str(tmp_path / "f.png"), "--figure-run", "77"]) == 2
    err = err_line(capsys, "--figure-run", "'77'", "r1, r2")
    assert "run_id" not in err and "wrote" not in err
    assert not js.exists()


def test_wrote_lines_only_for_committed_files(small_runs: Path, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    js, fig = tmp_path / "cal.json", tmp_path / "f.png"
    argv = ["calibrate", str(small_runs), *CAL, "--json", str(js), "--figure", str(fig),
            "--figure-run", "r2"]

    def fail(*a: Any, **k: Any) -> Any:
        raise OSError("disk full")

    with monkeypatch.context() as m:  # the figure fails after the JSON was written
        m.setattr(_atomic, "savefig", fail)
        assert main(argv) == 2
    err_line(capsys, "disk full")  # the only line: no "wrote cal.json"
    assert not js.exists() and not fig.exists()
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert f"wrote {js}\nwrote {fig}" in err
    assert js.is_file() and fig.is_file()


# -- 5. --from read strictly, errors naming --from and the file -----------------------


def _cal(params: dict[str, Any]) -> str:
    return json.dumps({"models": {"first": {"params": params}}})


@pytest.mark.parametrize(("content", "words"), [
    (None, ("No such file",)),
    ("folder", ()),
    (b"\xff\xfe{}", ("utf-8",)),
    ("{nope", ("not valid JSON (line 1",)),
    ('{"models": {"first": {"params": {"Td": 1' + "0" * 400 + "}}}}",
     ("models.first.params.Td", "too large")),
    ('{"models": {"first": {"params": {"Td": 1}}}, "models": {}}', ("duplicated key",)),
    ('{"models": {"first": {"params": {"Td": NaN}}}}', ("NaN",)),
    ('{"models": {"first": {"params": {"Td": Infinity}}}}', ("Infinity",)),
    (_cal({"Td": 1.0, "Tdd": 2.0}), ("models.first.params.Tdd",)),
    (_cal({"Td": -1.0}), ("models.first.params.Td", "> 0")),
], ids=["missing", "folder", "not-utf8", "not-json", "400-digits", "duplicate", "nan",
        "infinity", "unknown-param", "bad-value"])
def test_from_errors_name_the_option_and_the_file(content: str | bytes | None,
                                                  words: tuple[str, ...], tmp_path: Path,
                                                  no_maps: None,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "cal.json"
    if isinstance(content, bytes):
        src.write_bytes(content)
    elif content == "folder":
        src.mkdir()
    elif content is not None:
        src.write_text(content, encoding="utf-8")
    assert main(["stability-map", "--from", str(src), *TINY,
                 "--out", str(tmp_path / "m.png")]) == 2
    err_line(capsys, f"--from: {src}", *words)


def test_from_accepts_the_upper_gains_of_a_closed_loop_calibration(
        tmp_path: Path) -> None:
    src = tmp_path / "cal.json"
    src.write_text(_cal({"Td": 0.5, "kg": 0.1, "kv": 0.5, "Tg": 1.0, "Gmin": 5.0}))
    assert main(["stability-map", "--from", str(src), *TINY,
                 "--out", str(tmp_path / "m.png")]) == 0


def test_path_collisions_name_the_option_not_the_dest(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    (tmp_path / "m.png").write_bytes(b"old")  # a file of the input folder
    assert main(["stability-map", "--from", str(tmp_path), *TINY,
                 "--out", str(tmp_path / "m.png")]) == 2
    err = err_line(capsys, "--out", "is the input --from")
    assert "--source" not in err


@pytest.mark.parametrize("out", ["/", "."])
def test_a_folder_as_the_runs_output_is_named(out: str, capsys: pytest.CaptureFixture[str]
                                             ) -> None:
    """``--out /`` once said "PosixPath('/') has an empty name" (the sidecar's name was
    made before the output was checked)."""
    assert main(["synth", "--out", out]) == 2
    err_line(capsys, f"--out: {out} is a folder, expected a file name")


# -- 6. ArithmeticError is one line -----------------------------------------------------


@pytest.mark.parametrize("exc", [OverflowError("int too large to convert to float"),
                                 ZeroDivisionError("float division by zero")])
def test_arithmetic_errors_are_one_line(exc: ArithmeticError, tmp_path: Path,
                                        monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    def fail(*a: Any, **k: Any) -> Any:
        raise exc

    monkeypatch.setattr(avll.demo, "run", fail)
    assert main(["simulate", "--out", str(tmp_path / "s")]) == 2
    assert err_line(capsys) == f"avll simulate: error: {exc}"


# -- 7.-9. texts that said something else --------------------------------------------


def test_simulate_dt_limit_message(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                   ) -> None:
    assert main(["simulate", "--dt", "30", "--out", str(tmp_path / "s")]) == 2
    err = err_line(capsys, "30 s", "<= 10 s")
    assert "60 s" not in err


def test_data_help_lists_the_real_actions() -> None:
    sub = next(a for a in build_parser()._actions
               if isinstance(a, argparse._SubParsersAction))
    data = sub.choices["data"]
    actions = next(a for a in data._actions if isinstance(a, argparse._SubParsersAction))
    text = next(a.help for a in sub._choices_actions if a.dest == "data")
    listed = text.split(":", 1)[1].split("(")[0]
    assert [w.strip() for w in listed.split(",")] == list(actions.choices)


def test_closed_loop_without_leader_says_the_leader_is_missing(
        small_runs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", str(small_runs), *CAL, "--closed-loop"]) == 2
    err = err_line(capsys, "runs.csv", "run 'r1'", "no leader", "--closed-loop")
    assert "no command" not in err


# -- a library error about an argument an option sets names the option ----------------


@pytest.mark.parametrize(("opts", "said"), [
    (["--pop-size", "1"], "--pop-size: must be 0 (automatic) or in 2"),
    (["--seed", "-1"], "--seed: must be >= 0"),
    (["--threads", "-3"], "--threads: must be >= 0"),
])
def test_library_errors_name_the_option(small_runs: Path, opts: list[str], said: str,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """The library says ``pop_size: ...`` (its argument); the command says which of its
    options that is."""
    assert main(["calibrate", str(small_runs), "--command-kind", "acceleration",
                 "--starts", "1", "--max-generations", "2", *opts]) == 2
    err = err_line(capsys, f"avll calibrate: error: {said}")
    assert f": error: {opts[0][2:].replace('-', '_')}:" not in err


@pytest.mark.parametrize(("opts", "named"), [
    (["--max-gap", "1"], "--max-gap:"),
    (["--dt", "0.1", "--max-gap", "1"], "--dt and --max-gap:"),
])
def test_load_names_the_resampling_option_given(small_runs: Path, opts: list[str], named: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """``--max-gap`` alone on canonical data once blamed ``--dt``."""
    assert main(["load", str(small_runs), "--command-kind", "acceleration", *opts]) == 2
    err_line(capsys, f"error: {named} the canonical format is already uniformly sampled")
