"""What the loaders open: regular files only (a FIFO in a
data folder hung the loader; a device or a socket is refused the same way), never a
symbolic link loop (it gave a traceback), a bounded header (a canonical CSV with a
10^7-column header ran for minutes at 5.7 GB), and a ``nan`` cell called what it is
(it was reported as "is empty")."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import avll
from avll.io import _common

pytestmark = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs POSIX FIFOs")


def _frame(n: int = 100) -> pd.DataFrame:
    t = np.arange(n) * 0.1
    return pd.DataFrame({"run": "r1", "t": t, "a": np.zeros(n), "v": np.full(n, 10.0)})


def _read_in_child(path: Path, fmt: str) -> subprocess.CompletedProcess[str]:
    """read_runs in a child process with a timeout: a loader that opens a FIFO waits
    for a writer forever, and must not hang the test runner."""
    code = textwrap.dedent(f"""
    import avll
    try:
        avll.io.read_runs({str(path)!r}, command_kind="acceleration", format={fmt!r})
    except ValueError as e:
        print("REFUSED:", e)
    else:
        print("READ")
    """)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)


@pytest.mark.parametrize("fmt", ["canonical", "generic", "carma", "openacc",
                                 "openacc-astazero"])
def test_read_runs_of_a_fifo_is_refused_in_every_format(tmp_path: Path, fmt: str) -> None:
    os.mkfifo(tmp_path / "b.csv")
    res = _read_in_child(tmp_path / "b.csv", fmt)
    assert res.returncode == 0, res.stderr
    assert "b.csv: is a FIFO (named pipe)" in res.stdout, res.stdout + res.stderr


@pytest.mark.parametrize("fmt", ["canonical", "generic"])
@pytest.mark.parametrize("target", ["folder", "file"])
def test_a_fifo_is_refused_not_opened(tmp_path: Path, fmt: str, target: str) -> None:
    _frame().to_csv(tmp_path / "a.csv", index=False)
    os.mkfifo(tmp_path / "b.csv")
    res = _read_in_child(tmp_path if target == "folder" else tmp_path / "b.csv", fmt)
    assert res.returncode == 0, res.stderr
    assert "REFUSED:" in res.stdout and "b.csv: is a FIFO (named pipe)" in res.stdout, (
        res.stdout + res.stderr)


def test_a_device_and_a_fifo_sidecar_are_refused(tmp_path: Path) -> None:
    if not os.path.exists("/dev/null"):  # pragma: no cover - not POSIX
        pytest.skip("no /dev/null")
    os.symlink("/dev/null", tmp_path / "dev.csv")
    with pytest.raises(avll.DataError, match=r"dev\.csv: is a device"):
        avll.io.read_runs(tmp_path / "dev.csv", command_kind="acceleration")
    d = tmp_path / "side"
    d.mkdir()
    _frame().to_csv(d / "a.csv", index=False)
    os.mkfifo(d / "a.csv.meta.json")
    res = _read_in_child(d / "a.csv", "canonical")
    assert "a.csv.meta.json: is a FIFO (named pipe), expected the JSON sidecar" in res.stdout, (
        res.stdout + res.stderr)


@pytest.mark.parametrize("fmt", ["canonical", "generic"])
def test_symbolic_link_loops_are_clear_errors(tmp_path: Path, fmt: str) -> None:
    os.symlink("self.csv", tmp_path / "self.csv")  # a file link to itself, in a folder
    os.symlink("loopdir", tmp_path / "loopdir")  # a folder link to itself
    os.symlink("loopdir/x.csv", tmp_path / "through.csv")  # a path through the loop
    for p in (tmp_path, tmp_path / "self.csv", tmp_path / "loopdir", tmp_path / "through.csv"):
        with pytest.raises(avll.DataError, match="a symbolic link loop"):
            avll.io.read_runs(p, command_kind="acceleration", format=fmt)


def test_cli_load_of_a_symbolic_link_loop_is_one_line(tmp_path: Path) -> None:
    os.symlink("loopdir", tmp_path / "loopdir")
    res = subprocess.run([sys.executable, "-m", "avll", "load", str(tmp_path / "loopdir"),
                          "--out", str(tmp_path / "o.csv")], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr
    assert "a symbolic link loop" in res.stderr


@pytest.mark.parametrize("fmt", ["canonical", "generic"])
def test_the_header_is_bounded(tmp_path: Path, fmt: str) -> None:
    n = _common.MAX_COLUMNS + 1
    wide = tmp_path / "wide.csv"
    wide.write_text(",".join(["run", "t", "a"] + [f"c{i}" for i in range(n)]) + "\n"
                    + ",".join(["r1", "0", "0"] + ["0"] * n) + "\n")
    with pytest.raises(avll.DataError, match=f"wide.csv: the header has {n + 3} columns, "
                                             f"more than the {_common.MAX_COLUMNS}"):
        avll.io.read_runs(wide, command_kind="acceleration", format=fmt)
    # a header line past the byte bound is refused after reading the bound, not the file
    long = tmp_path / "long.csv"
    with open(long, "w") as f:
        f.write("run,t,a," + ",".join(["x"] * 3_000_000) + "\n" + "r1,0,0\n")
    t0 = time.perf_counter()
    with pytest.raises(avll.DataError, match=f"long.csv: the header line is longer than "
                                             f"{_common.MAX_HEADER_BYTES} bytes"):
        avll.io.read_runs(long, command_kind="acceleration", format=fmt)
    assert time.perf_counter() - t0 < 10.0
    # at the bound: read (quoted commas are not columns)
    ok = tmp_path / "ok.csv"
    ok.write_text('run,t,a,"x,y"\n' + "\n".join(f"r1,{i / 10},0,1" for i in range(50)) + "\n")
    assert len(avll.io.read_runs(ok, command_kind="acceleration", format=fmt)) == 1


def test_a_parquet_file_with_too_many_columns_is_refused(tmp_path: Path) -> None:
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    n = _common.MAX_COLUMNS + 1
    cols = {"run": ["r1"], "t": [0.0], "a": [0.0], **{f"c{i}": [0.0] for i in range(n)}}
    pq.write_table(pa.table(cols), tmp_path / "wide.parquet")
    with pytest.raises(avll.DataError, match=f"{n + 3} columns, more than the"):
        avll.io.read_runs(tmp_path / "wide.parquet", command_kind="acceleration")


@pytest.mark.parametrize("cell", ["nan", "NaN", "-nan", "NA"])
def test_a_nan_cell_is_not_called_empty(tmp_path: Path, cell: str) -> None:
    df = _frame()
    df["v"] = df["v"].astype(object)
    df.loc[5, "v"] = cell
    df.to_csv(tmp_path / "x.csv", index=False)
    with pytest.raises(avll.DataError, match=rf"column 'v' line 7: '{cell}' is not a number "
                                             r"\(NaN is not allowed\)"):
        avll.io.read_runs(tmp_path / "x.csv", command_kind="acceleration")
    df.loc[5, "v"] = ""
    df.to_csv(tmp_path / "x.csv", index=False)
    with pytest.raises(avll.DataError, match=r"column 'v' line 7: is empty"):
        avll.io.read_runs(tmp_path / "x.csv", command_kind="acceleration")


def test_the_documented_bounds_are_the_code() -> None:
    from avll import stability

    text = (Path(__file__).resolve().parents[1] / "docs" / "guarantees.md").read_text()
    assert f"at most {_common.MAX_COLUMNS:,} columns" in text
    assert f"at most {_common.MAX_HEADER_BYTES:,} bytes" in text
    assert f"at most {_common.MAX_PARQUET_FOOTER // 2**20} MiB" in text
    assert f"`n_scan` at most {stability.MAX_SCAN:,}" in text
    assert f"`n_grid` at most {stability.MAX_GRID:,}" in text
