"""A corruption corpus over every loader (canonical, generic, carma, openacc-astazero)
and the CLI options.

Every case is a small valid input set with one defect, run through the ``avll``
command. Each must end with exit code 2 and exactly one line on stderr (no
traceback), leave every input file byte-for-byte unchanged and write no output (not
even a partial or temporary file).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from loader_helpers import canonical_frame, carma_frame, openacc_dir, sha

from avll.cli import main

Builder = Callable[[Path, Path], list[str]]
CASES: dict[str, tuple[Builder, str]] = {}


def case(name: str, expect: str) -> Callable[[Builder], Builder]:
    """Registers a case: ``builder(indir, out) -> argv``; ``expect`` is a fragment
    of the one-line error."""

    def deco(f: Builder) -> Builder:
        CASES[name] = (f, expect)
        return f

    return deco


def _canonical(d: Path, df: pd.DataFrame | None = None, side: object = "default",
               name: str = "c.csv") -> Path:
    p = d / name
    (canonical_frame(runs=("1", "2")) if df is None else df).to_csv(p, index=False)
    if side == "default":
        side = {"command_kind": "acceleration"}
    if side is not None:
        text = side if isinstance(side, str) else json.dumps(side)
        (d / (name + ".meta.json")).write_text(text)
    return p


def _load(p: Path, out: Path, *extra: str) -> list[str]:
    return ["load", str(p), "--out", str(out), *extra]


def _cell(col: str, row: int, value: str) -> pd.DataFrame:
    df = canonical_frame(runs=("1", "2")).astype({col: object})
    df.loc[row, col] = value
    return df


# ------------------------------------------------------------------ canonical
@case("canonical/empty file", "empty")
def _(d: Path, out: Path) -> list[str]:
    p = d / "c.csv"
    p.write_text("")
    return _load(p, out, "--command-kind", "acceleration")


@case("canonical/header only", "no data rows")
def _(d: Path, out: Path) -> list[str]:
    p = d / "c.csv"
    p.write_text("run,t,a\n")
    return _load(p, out, "--command-kind", "acceleration")


@case("canonical/missing column", "missing column(s) 'a'")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, canonical_frame().drop(columns="a")), out)


@case("canonical/text cell", "column 'v' line 14: 'abc' is not a number")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, _cell("v", 12, "abc")), out)


@case("canonical/NaN cell", "column 'a' line 9: 'nan' is not a number")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, _cell("a", 7, "nan")), out)


@case("canonical/inf cell", "column 'x' line 7: value inf is not finite")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, _cell("x", 5, "inf")), out)


@case("canonical/1e300 acceleration", "column 'a', row 30 (line 32): acceleration 1e+300")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, _cell("a", 30, "1e300")), out)


@case("canonical/1e300 position", "column 'x', row 3 (line 5): position 1e+300 m")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, _cell("x", 3, "1e300")), out)


@case("canonical/time backwards", "column 't' line 12: time goes backwards")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame(runs=("1", "2"))
    df.loc[[9, 10], "t"] = df.loc[[10, 9], "t"].to_numpy()
    return _load(_canonical(d, df), out)


@case("canonical/duplicated time", "time repeats")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame(runs=("1", "2"))
    df.loc[20, "t"] = df.loc[19, "t"]
    return _load(_canonical(d, df), out)


@case("canonical/non-uniform time", "non-uniform sampling")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame(runs=("1", "2"))
    df.loc[30:399, "t"] += 0.01
    return _load(_canonical(d, df), out)


@case("canonical/run rows not contiguous", "not contiguous")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame(runs=("1", "2"))
    df = pd.concat([df.iloc[:100], df.iloc[400:500], df.iloc[100:400], df.iloc[500:]])
    return _load(_canonical(d, df), out)


@case("canonical/duplicated header column", "column 'a': duplicated column")
def _(d: Path, out: Path) -> list[str]:
    p = _canonical(d)
    lines = p.read_text().splitlines()
    lines[0] = lines[0].replace("x", "a")  # run,t,command,a,v,a
    p.write_text("\n".join(lines) + "\n")
    return _load(p, out)


@case("canonical/speed in km/h", "column 'v': speed looks like km/h")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame(runs=("1", "2"))
    df["v"] *= 3.6
    return _load(_canonical(d, df), out)


@case("canonical/time in milliseconds", "are the time stamps in milliseconds")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame(runs=("1", "2"))
    df["t"] *= 1000
    return _load(_canonical(d, df), out)


@case("canonical/grade in percent", "column 'exo_grade', row 0 (line 2): grade 4")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame(runs=("1", "2"))
    df["exo_grade"] = 4.0
    return _load(_canonical(d, df), out)


@case("canonical/not UTF-8", "not a readable CSV file")
def _(d: Path, out: Path) -> list[str]:
    p = d / "c.csv"
    p.write_bytes(b"run,t,a\n1,0,\xff\xfe\x00\n" * 3)
    return _load(p, out, "--command-kind", "acceleration")


@case("canonical/no command kind", "the command kind is not given")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side=None), out)


@case("sidecar/runs is a list", "c.csv.meta.json: runs: must be an object")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side={"command_kind": "acceleration", "runs": []}), out)


@case("sidecar/run entry is a string", "runs.'1': must be an object")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side={"command_kind": "acceleration", "runs": {"1": "oops"}}),
                 out)


@case("sidecar/meta is a number", "runs.'1'.meta: must be an object, got 5")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side={"command_kind": "acceleration",
                                     "runs": {"1": {"meta": 5}}}), out)


@case("sidecar/deeply nested", "nested deeper than 32 levels")
def _(d: Path, out: Path) -> list[str]:
    deep = '{"command_kind":"acceleration","runs":{"1":{"meta":{"a":' + "[" * 50_000 + \
        "]" * 50_000 + "}}}}"
    return _load(_canonical(d, side=deep), out)


@case("sidecar/not JSON", "not valid JSON")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side='{"command_kind": "acceleration",'), out)


@case("sidecar/run id written differently", "runs.'01' matches no run")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side={"command_kind": "acceleration",
                                     "runs": {"01": {"upper": {"kg": 0.5}}}}), out)


@case("sidecar/run id 2.0", "runs.'2.0' matches no run")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side={"command_kind": "acceleration",
                                     "runs": {"2.0": {"upper": {"kg": 0.5}}}}), out)


@case("sidecar/upper gain is text", "runs.'1'.upper.kg: must be a number, got 'x'")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side={"command_kind": "acceleration",
                                     "runs": {"1": {"upper": {"kg": "x"}}}}), out)


@case("sidecar/unknown key", "unknown key 'uper'")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side={"command_kind": "acceleration",
                                     "runs": {"1": {"uper": {"kg": 1}}}}), out)


@case("sidecar/duplicated key", "duplicated key 'command_kind'")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side='{"command_kind": "speed", "command_kind": "speed"}'), out)


@case("strict/sidecar names a missing run", "names 1 run(s) that are not in c.csv: '7'")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, side={"command_kind": "acceleration",
                                     "runs": {"7": {"upper": {"kg": 0.5}}}}), out, "--strict")


@case("strict/implausible acceleration", "acceleration 12 m/s² is outside the plausible")
def _(d: Path, out: Path) -> list[str]:
    return _load(_canonical(d, _cell("a", 40, "12")), out, "--strict")


# ------------------------------------------------------------------ generic
def _generic(d: Path, df: pd.DataFrame) -> Path:
    p = d / "g.csv"
    df.to_csv(p, index=False)
    return p


def _gload(p: Path, out: Path) -> list[str]:
    return _load(p, out, "--format", "generic", "--command-kind", "acceleration")


@case("generic/missing time column", "g.csv, column 't': missing column")
def _(d: Path, out: Path) -> list[str]:
    return _gload(_generic(d, canonical_frame().drop(columns="t")), out)


@case("generic/text cell", "column 'command', row 17 (line 19): not a number")
def _(d: Path, out: Path) -> list[str]:
    return _gload(_generic(d, _cell("command", 17, "1,5")), out)


@case("generic/duplicated header", "column 'v': duplicated column")
def _(d: Path, out: Path) -> list[str]:
    p = _generic(d, canonical_frame())
    lines = p.read_text().splitlines()
    lines[0] = lines[0].replace(",x", ",v")
    p.write_text("\n".join(lines) + "\n")
    return _gload(p, out)


@case("generic/speed in mph", "speed looks like mph")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame()
    df["v"] *= 2.2369
    return _gload(_generic(d, df), out)


@case("generic/time in milliseconds", "are the time stamps in milliseconds")
def _(d: Path, out: Path) -> list[str]:
    df = canonical_frame()
    df["t"] *= 1000
    return _gload(_generic(d, df), out)


@case("generic/1e300 speed", "speed 1e+300 is implausible in m/s")
def _(d: Path, out: Path) -> list[str]:
    return _gload(_generic(d, _cell("v", 77, "1e300")), out)


@case("generic/negative resampling step", "dt: must be a positive time step")
def _(d: Path, out: Path) -> list[str]:
    return _gload(_generic(d, canonical_frame()), out) + ["--dt", "-0.1"]


# ------------------------------------------------------------------ CARMA
def _carma(d: Path, df: pd.DataFrame) -> Path:
    p = d / "data5.csv"
    df.to_csv(p, index=False)
    return p


def _cload(p: Path, out: Path) -> list[str]:
    return _load(p, out, "--format", "carma", "--min-duration", "1")


@case("carma/missing column", "column 'follower1_Speed_command': missing column")
def _(d: Path, out: Path) -> list[str]:
    return _cload(_carma(d, carma_frame().drop(columns="follower1_Speed_command")), out)


@case("carma/text cell", "column 'leader_acceleration', row 123 (line 125): not a number")
def _(d: Path, out: Path) -> list[str]:
    df = carma_frame().astype({"leader_acceleration": object})
    df.loc[123, "leader_acceleration"] = "n/a?"
    return _cload(_carma(d, df), out)


@case("carma/conflicting duplicated time", "duplicated time")
def _(d: Path, out: Path) -> list[str]:
    df = carma_frame()
    df.loc[50, "Time"] = df.loc[49, "Time"]
    return _cload(_carma(d, df), out)


@case("carma/time off the grid", "non-uniform sampling")
def _(d: Path, out: Path) -> list[str]:
    df = carma_frame()
    df.loc[77, "Time"] += 0.04
    return _cload(_carma(d, df), out)


@case("carma/speed in km/h", "km/h")
def _(d: Path, out: Path) -> list[str]:
    df = carma_frame()
    df["follower1_avg_speed_driven_wheels"] *= 3.6
    df["follower1_avg_speed_driven_wheels"] -= 20.0
    return _cload(_carma(d, df), out)


@case("carma/no engaged stretch", "empty engaged stretch")
def _(d: Path, out: Path) -> list[str]:
    df = carma_frame()
    df["leader_CARMA_mode"] = 0.0
    df["follower1_CARMA_mode"] = 1.0
    return _cload(_carma(d, df), out)


@case("carma/inf cell", "column 'leader_Speed_command', row 5 (line 7): value is inf")
def _(d: Path, out: Path) -> list[str]:
    df = carma_frame()
    df.loc[5, "leader_Speed_command"] = np.inf
    return _cload(_carma(d, df), out)


@case("carma/time stamp typo", "row 1 (line 3): the time jumps from 59.9 to 7.036874418e+13 s")
def _(d: Path, out: Path) -> list[str]:
    df = carma_frame().astype({"Time": object})
    df.loc[1, "Time"] = "70368744177665.0"
    return _cload(_carma(d, df), out)


@case("carma/not a CARMA file", "column 'Time': missing column")
def _(d: Path, out: Path) -> list[str]:
    return _cload(_carma(d, canonical_frame()), out)


@case("carma/duplicated header", "column 'leader_CARMA_mode': duplicated column")
def _(d: Path, out: Path) -> list[str]:
    p = _carma(d, carma_frame())
    lines = p.read_text().splitlines()
    lines[0] = lines[0].replace("leader_ACC_speed", "leader_CARMA_mode", 1)
    p.write_text("\n".join(lines) + "\n")
    return _cload(p, out)


@case("carma/acceleration scaled", "is implausible (> 15); wrong unit or column?")
def _(d: Path, out: Path) -> list[str]:
    df = carma_frame()
    df["leader_acceleration"] *= 9.81 * 2
    return _cload(_carma(d, df), out)


# ------------------------------------------------------------------ OpenACC
def _oload(p: Path, out: Path) -> list[str]:
    return _load(p, out, "--format", "openacc-astazero")


def _openacc_edit(d: Path, edit: Callable[[pd.DataFrame], pd.DataFrame]) -> Path:
    p = openacc_dir(d)
    edit(pd.read_csv(p)).to_csv(p, index=False)
    return p


def _set(col: str, row: int, value: object) -> Callable[[pd.DataFrame], pd.DataFrame]:
    def f(df: pd.DataFrame) -> pd.DataFrame:
        df = df.astype({col: object})
        df.loc[row, col] = value
        return df

    return f


@case("openacc/text cell", "column 'Accel2', row 99 (line 101): not a number")
def _(d: Path, out: Path) -> list[str]:
    return _oload(_openacc_edit(d, _set("Accel2", 99, "--")), out)


@case("openacc/missing column", "column 'SpeedDoppler3': missing column")
def _(d: Path, out: Path) -> list[str]:
    return _oload(_openacc_edit(d, lambda df: df.drop(columns="SpeedDoppler3")), out)


@case("openacc/time backwards", "column 'Time', row 201 (line 203): time goes backwards")
def _(d: Path, out: Path) -> list[str]:
    def f(df: pd.DataFrame) -> pd.DataFrame:
        df.loc[[200, 201], "Time"] = df.loc[[201, 200], "Time"].to_numpy()
        return df

    return _oload(_openacc_edit(d, f), out)


@case("openacc/no Labels row", "no row for 'ASta_010101_platoon1'")
def _(d: Path, out: Path) -> list[str]:
    p = openacc_dir(d)
    (d / "Labels.csv").write_text("File,type1\nsomething_else,1\n")
    return _oload(p, out)


@case("openacc/speed in km/h", "SpeedDoppler2")
def _(d: Path, out: Path) -> list[str]:
    def f(df: pd.DataFrame) -> pd.DataFrame:
        df["SpeedDoppler2"] *= 3.6
        return df

    return _oload(_openacc_edit(d, f), out)


@case("openacc/grade in percent", "Slope.csv, column 'Y'")
def _(d: Path, out: Path) -> list[str]:
    p = openacc_dir(d)
    sl = pd.read_csv(d / "Slope.csv")
    sl["Y"] *= 100
    sl.to_csv(d / "Slope.csv", index=False)
    return _oload(p, out)


@case("openacc/no Slope.csv", "Slope.csv: not found")
def _(d: Path, out: Path) -> list[str]:
    p = openacc_dir(d)
    (d / "Slope.csv").unlink()
    return _oload(p, out)


@case("openacc/1e300 position", "column 'X1', row 10 (line 12): position 1e+300 m")
def _(d: Path, out: Path) -> list[str]:
    return _oload(_openacc_edit(d, _set("X1", 10, 1e300)), out)


# ------------------------------------------------------------------ CLI options
@case("cli/seed beyond 64 bits", "seed: must be <= 18446744073709551615")
def _(d: Path, out: Path) -> list[str]:
    return ["calibrate", str(_canonical(d)), "--seed", "99999999999999999999999", "--json",
            str(out)]


@case("cli/a million threads", "threads: 1000000 is more than 4 x")
def _(d: Path, out: Path) -> list[str]:
    return ["calibrate", str(_canonical(d)), "--threads", "1000000", "--json", str(out)]


@case("cli/weights not numbers", "--weights: expected three numbers")
def _(d: Path, out: Path) -> list[str]:
    return ["calibrate", str(_canonical(d)), "--weights", "a,b,c", "--json", str(out)]


@case("cli/stability grid reversed", "--kg: need finite MIN <= MAX")
def _(d: Path, out: Path) -> list[str]:
    return ["stability-map", "--kg", "2", "0.001", "10", "--out", str(out)]


@case("cli/missing data folder", "does not exist")
def _(d: Path, out: Path) -> list[str]:
    return ["reproduce", "--data", "carma", "--data-path", str(d / "nope"), "--out",
            str(out)]


@case("cli/output is the input", "is the input PATH")
def _(d: Path, out: Path) -> list[str]:
    p = _canonical(d)
    return ["load", str(p), "--out", str(p)]


@case("cli/diagnose unknown calibration run", "--cal-runs: unknown run(s)")
def _(d: Path, out: Path) -> list[str]:
    return ["diagnose", str(_canonical(d)), "--cal-runs", "9", "--json", str(out)]


def _snapshot(d: Path) -> dict[str, str]:
    return {str(p.relative_to(d)): sha(p) for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("name", sorted(CASES))
def test_corrupted_input(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    build, expect = CASES[name]
    indir, outdir = tmp_path / "in", tmp_path / "out"
    indir.mkdir()
    outdir.mkdir()
    out = outdir / ("o.png" if name.startswith("cli/stability") else "o.csv")
    argv = build(indir, out)
    before = _snapshot(indir)
    capsys.readouterr()
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, (name, err)
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert "Traceback" not in err and "error: " in err
    assert expect in err, err
    assert _snapshot(indir) == before, "an input file changed"
    assert list(outdir.iterdir()) == [], "an output (or a partial one) was written"
    assert not any(".tmp-" in p.name or "avll-tmp" in p.name for p in tmp_path.rglob("*"))


def test_corpus_size_and_coverage() -> None:
    assert len(CASES) >= 40
    kinds = {n.split("/")[0] for n in CASES}
    assert {"canonical", "sidecar", "strict", "generic", "carma", "openacc", "cli"} <= kinds


@pytest.mark.parametrize("name", ["canonical/1e300 acceleration", "sidecar/deeply nested",
                                  "carma/text cell", "cli/seed beyond 64 bits"])
def test_corrupted_input_real_process(name: str, tmp_path: Path) -> None:
    """A few cases through a real ``avll`` process: exit 2, one line, no traceback."""
    build, expect = CASES[name]
    indir, outdir = tmp_path / "in", tmp_path / "out"
    indir.mkdir()
    outdir.mkdir()
    argv = build(indir, outdir / "o.csv")
    before = _snapshot(indir)
    res = subprocess.run([sys.executable, "-m", "avll.cli", *argv], capture_output=True,
                         text=True, timeout=120, env={**os.environ, "PYTHONWARNINGS": ""})
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1 and expect in res.stderr, res.stderr
    assert "Traceback" not in res.stderr
    assert _snapshot(indir) == before and list(outdir.iterdir()) == []
