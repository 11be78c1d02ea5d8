"""The CLI's help: every command has a description, every option a help text that
states its default; the shared options behave the same everywhere; old names warn."""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys

import pytest

from avll.cli import _all_parsers, build_parser, main
from avll.cli._common import FORMAT_NAMES, MODEL_NAMES, select_runs

_SKIP = (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction)


def _commands() -> list[tuple[str, argparse.ArgumentParser]]:
    root = build_parser()
    return [(p.prog, p) for p in _all_parsers(root) if p is not root]


def test_every_command_has_a_description() -> None:
    cmds = _commands()
    assert {"avll simulate", "avll synth", "avll load", "avll diagnose", "avll calibrate",
            "avll stability-map", "avll reproduce", "avll study", "avll study openacc"
            } <= {name for name, _ in cmds}
    missing = [name for name, p in cmds if not (p.description or "").strip()]
    assert missing == []


def test_every_option_has_help_stating_its_default() -> None:
    bad = []
    for name, p in _commands():
        for a in p._actions:
            if isinstance(a, _SKIP):
                continue
            opt = a.option_strings[0] if a.option_strings else a.dest
            if not (a.help or "").strip():
                bad.append(f"{name} {opt}: no help")
            elif a.default not in (None, argparse.SUPPRESS) and "default" not in a.help:
                bad.append(f"{name} {opt}: default {a.default!r} not stated")
    assert bad == []


def test_shared_options_are_the_same_everywhere() -> None:
    """--seed, --threads, --json and --progress/-q mean one thing on every command."""
    seen: dict[str, set[str]] = {}
    for _, p in _commands():
        for a in p._actions:
            for o in a.option_strings:
                if o in ("--seed", "--threads", "--json", "--progress", "-q"):
                    seen.setdefault(o, set()).add(a.help or "")
    for o in ("--seed", "--threads", "--progress", "-q"):
        assert o in seen
    # --progress and -q are identical everywhere; --threads too
    assert len(seen["--progress"]) == 1 and len(seen["-q"]) == 1
    assert len(seen["--threads"]) == 1


def test_models_comma_and_repeat_and_model_means_one(capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    p = build_parser()
    a = p.parse_args(["stability-map", "--models", "first,second", "--models", "proposed"])
    assert a.models == ["first", "second", "proposed"]
    assert capsys.readouterr().err == ""
    # --model is one model everywhere: the old --model spelling of --models is gone
    with pytest.raises(SystemExit):
        p.parse_args(["stability-map", "--model", "first"])
    c = p.parse_args(["calibrate", "x.csv"])
    assert c.models is None and list(c.models_default) == list(MODEL_NAMES)
    with pytest.raises(SystemExit) as e:
        p.parse_args(["calibrate", "x.csv", "--models", "first,bogus"])
    assert e.value.code == 2


def test_quiet_is_progress_none() -> None:
    p = build_parser()
    assert p.parse_args(["calibrate", "x.csv", "-q"]).progress == "none"
    assert p.parse_args(["calibrate", "x.csv"]).progress == "auto"
    assert p.parse_args(["reproduce", "--progress", "log"]).progress == "log"


def test_run_selection_globs() -> None:
    ids = ["data5/a", "data5/b", "data9/a", "x"]
    assert select_runs(ids, "data9/*,x") == ["data9/a", "x"]
    assert select_runs(ids, "data5/?,data5/a") == ["data5/a", "data5/b"]
    with pytest.raises(ValueError, match="--cal-runs: pattern 'nope/\\*' matches no run"):
        select_runs(ids, "nope/*")
    with pytest.raises(ValueError, match="comma-separated"):
        select_runs(ids, "a,,b")


def test_format_names_match_the_loaders() -> None:
    from avll.io import FORMATS

    assert sorted(FORMAT_NAMES) == sorted(FORMATS)


@pytest.mark.parametrize("module", ["avll.calibration", "avll.stability", "avll.demo",
                                    "avll.synth", "avll.reproduce", "avll.studies",
                                    "avll.studies.openacc", "avll.diagnose"])
def test_no_register_cli_shims(module: str) -> None:
    # the package was never released: the commands live in avll.cli only
    mod = importlib.import_module(module)
    with pytest.raises(AttributeError):
        _ = mod.register_cli


def test_python_dash_m_avll_runs() -> None:
    for argv in (["-m", "avll", "--version"], ["-m", "avll.cli", "--version"]):
        r = subprocess.run([sys.executable, *argv], capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and r.stdout.startswith("avll "), r.stderr


def test_help_exits_zero(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["stability-map", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "--from CAL.json" in out and "(default: 0.001 5 400" in out


def test_help_does_not_import_scipy_or_pandas() -> None:
    code = ("import sys; from avll.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "try:\n    main(['stability-map', '--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('scipy', 'pandas', 'matplotlib') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "[]"


def test_diagnose_entry_is_the_full_one() -> None:
    from avll.cli.diagnose import HELP

    p = build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    act = next(a for a in sub._choices_actions if a.dest == "diagnose")
    assert act.help == HELP
    assert len(sub.choices["diagnose"]._actions) > 5


def test_ga_budget_named_alike() -> None:
    # One name per idea: --max-generations / --starts on calibrate, diagnose and study;
    # the old spellings are gone (the package was never released).
    from avll.cli import build_parser

    parser = build_parser()
    for argv, gen in ((["calibrate", "d.csv", "--max-generations", "7"], 7),
                      (["diagnose", "d.csv", "--cal-runs", "1", "--json", "o.json",
                        "--max-generations", "9", "--starts", "3"], 9),
                      (["study", "openacc", "d", "--out", "o", "--max-generations", "4"], 4)):
        ns = parser.parse_args(argv)
        assert ns.max_generations == gen
    for old in (["diagnose", "d.csv", "--cal-runs", "1", "--json", "o", "--maxiter", "9"],
                ["study", "openacc", "d", "--out", "o", "--generations", "4"]):
        with pytest.raises(SystemExit):  # the old spellings are gone
            parser.parse_args(old)
    with pytest.raises(ValueError, match="--starts: must be >= 1, got 0"):
        parser.parse_args(["diagnose", "d.csv", "--cal-runs", "1", "--json", "o", "--starts",
                           "0"])
