"""Zarr maps are complete or refused: a map written with
``.to_zarr`` and killed mid-write opened as complete, its missing chunks read as 0
("locally unstable"); Ctrl-C during ``write_map`` left its temporary folder (2 of 6
runs). ``write_map`` marks a store complete last, ``open_map`` refuses a store
without the mark, and an interrupted ``write_map`` leaves nothing behind."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from signal_helpers import SIGINT_DEFAULT

import avll
from avll import maps as avll_maps

pytest.importorskip("zarr")
pytest.importorskip("dask")

M = avll.PAPER_TABLE_II["second"]
KG, TG, KV = np.linspace(0.05, 1.0, 40), np.linspace(0.0, 15.0, 30), np.linspace(0.0, 1.0, 20)


def _lazy() -> object:
    return avll.map_dataset(M, KG, TG, KV, chunks={"kg": 10})


def test_write_map_marks_the_store_and_open_map_reads_it(tmp_path: Path) -> None:
    p = avll.write_map(_lazy(), tmp_path / "m.zarr")
    assert avll_maps.COMPLETE_MARKER in os.listdir(p)
    got = avll.open_map(p)
    np.testing.assert_array_equal(got.values, avll.stability_map(M, KG, TG, KV))
    assert "complete" not in got.attrs  # the mark is not a map attribute
    assert sorted(os.listdir(tmp_path)) == ["m.zarr"]


def test_open_map_refuses_a_store_without_the_mark(tmp_path: Path) -> None:
    import xarray as xr

    # the metadata written and no chunk yet: what a .to_zarr killed early leaves
    _lazy().to_zarr(tmp_path / "killed.zarr", compute=False, consolidated=False)
    hole = xr.open_zarr(tmp_path / "killed.zarr", consolidated=False)["codes"].values
    assert (hole == avll.stability.LOCAL_UNSTABLE).all()  # the hazard: it reads as a whole map
    with pytest.raises(ValueError, match=r"killed\.zarr has no completeness marker .* "
                                         r"written by avll\.write_map"):
        avll.open_map(tmp_path / "killed.zarr")
    # a complete .to_zarr, and a copy of a marked store: not marked either
    _lazy().to_zarr(tmp_path / "plain.zarr", consolidated=False)
    marked = avll.write_map(_lazy(), tmp_path / "m.zarr")
    xr.open_zarr(marked, consolidated=False).to_zarr(tmp_path / "copy.zarr",
                                                      consolidated=False)
    for name in ("plain.zarr", "copy.zarr"):
        with pytest.raises(ValueError, match="has no completeness marker"):
            avll.open_map(tmp_path / name)
    with pytest.raises(ValueError, match="is not a Zarr store"):
        avll.open_map(tmp_path / "none.zarr")


def _failing_block(block: np.ndarray) -> np.ndarray:
    raise RuntimeError("a chunk failed")


def test_a_failed_write_leaves_the_old_map_and_no_temporary(tmp_path: Path) -> None:
    p = avll.write_map(avll.map_dataset(M, KG, TG, KV), tmp_path / "m.zarr")
    bad = _lazy().copy(data=_lazy().data.map_blocks(_failing_block, dtype=np.uint8))
    with pytest.raises(RuntimeError, match="a chunk failed"):
        avll.write_map(bad, p)
    assert sorted(os.listdir(tmp_path)) == ["m.zarr"]
    np.testing.assert_array_equal(avll.open_map(p).values, avll.stability_map(M, KG, TG, KV))


_CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    import avll
    m = avll.PAPER_TABLE_II["proposed"]
    lazy = avll.map_dataset(m, np.linspace(0.01, 2, 200), np.linspace(0, 15, 200),
                            np.linspace(0, 1.2, 100), chunks={"kg": 25, "Tg": 200})
    print("start", flush=True)
    try:
        avll.write_map(lazy, sys.argv[1])
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(130)
    print("done", flush=True)
""")


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child is POSIX")
def test_ctrl_c_during_write_map_leaves_no_temporary(tmp_path: Path) -> None:
    """Ctrl-C at six instants of a streamed write (8 chunks of 1e6 points): the folder
    holds afterwards either nothing or the complete, marked map; never a temporary."""
    script = tmp_path / "child.py"
    script.write_text(_CHILD)
    outcomes = []
    for delay in (0.0, 0.1, 0.3, 0.6, 1.0, 1.5):
        out = tmp_path / f"out-{delay}"
        out.mkdir()
        p = subprocess.Popen([sys.executable, str(script), str(out / "m.zarr")],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             **SIGINT_DEFAULT)
        assert p.stdout is not None
        assert p.stdout.readline().strip() == "start"
        time.sleep(delay)
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=300)
        time.sleep(0.5)  # a straggling chunk writer would show up by now
        left = sorted(os.listdir(out))
        outcomes.append((delay, p.returncode, left))
        # 130: interrupted in write_map; 0: finished first; -SIGINT: the signal landed
        # after the child's own handler (interpreter exit), whatever write_map did
        assert p.returncode in (0, 130, -signal.SIGINT), stderr
        if p.returncode == 0:
            assert left == ["m.zarr"], outcomes
        elif p.returncode == 130:
            assert left == [], outcomes
        assert left in ([], ["m.zarr"]), outcomes  # never a temporary store
        if left:
            assert avll.open_map(out / "m.zarr").shape == (200, 200, 100)
        shutil.rmtree(out)
    assert any(rc == 130 for _, rc, _ in outcomes), outcomes  # some Ctrl-C hit the write
