"""CARMA bridging: only empty cells are interpolated; a value that
was measured is never overwritten."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from loader_helpers import CARMA, NO_DATA, carma_frame

from avll.io.carma import load_carma


def _changed_present(path, runs) -> tuple[int, int]:
    """(present cells compared, present cells whose value the runs changed)."""
    df = pd.read_csv(path).sort_values("Time", kind="stable").drop_duplicates()
    row_of = {float(t): i for i, t in enumerate(df["Time"].to_numpy())}
    checked = changed = 0
    for r in runs:
        veh = r.meta["vehicle"]
        rows = [row_of.get(float(t)) for t in r.t]
        for col, arr in ((f"{veh}_Speed_command", r.command),
                         (f"{veh}_avg_speed_driven_wheels", r.v),
                         (f"{veh}_acceleration", r.a)):
            raw = pd.to_numeric(df[col], errors="coerce").to_numpy()
            for k, ri in enumerate(rows):
                if ri is not None and np.isfinite(raw[ri]):
                    checked += 1
                    changed += int(raw[ri] != arr[k])
    return checked, changed


@pytest.mark.data
@pytest.mark.parametrize("name", ["data5", "data6", "data9", "data10"])
def test_present_values_untouched_on_real_files(name):
    path = CARMA / f"{name}.csv"
    if not path.exists():
        pytest.skip(NO_DATA)
    runs = load_carma(path)
    checked, changed = _changed_present(path, runs)
    assert checked > 10_000
    assert changed == 0
    # the files do have bridged samples, so the check exercised the bridging
    assert sum(r.meta["bridged_samples"] for r in runs) > 0


def test_only_empty_cells_interpolated(tmp_path):
    df = carma_frame(300)
    # row 100: the acceleration cell is empty, speed and command are present
    df.loc[100, "follower1_acceleration"] = np.nan
    # row 200: the speed cell is empty, the command is present
    df.loc[200, "follower1_avg_speed_driven_wheels"] = np.nan
    p = tmp_path / "c.csv"
    df.to_csv(p, index=False)
    runs = [r for r in load_carma(p) if r.meta["vehicle"] == "follower1"]
    assert len(runs) == 1
    r = runs[0]
    i100, i200 = int(np.argmin(abs(r.t - df.Time[100]))), int(np.argmin(abs(r.t - df.Time[200])))
    # present values kept exactly
    assert r.v[i100] == df.loc[100, "follower1_avg_speed_driven_wheels"]
    assert r.command[i100] == df.loc[100, "follower1_Speed_command"]
    assert r.command[i200] == df.loc[200, "follower1_Speed_command"]
    assert r.a[i200] == df.loc[200, "follower1_acceleration"]
    # empty cells interpolated between their neighbours
    a = df["follower1_acceleration"]
    assert r.a[i100] == pytest.approx(0.5 * (a[99] + a[101]))
    v = df["follower1_avg_speed_driven_wheels"]
    assert r.v[i200] == pytest.approx(0.5 * (v[199] + v[201]))
    assert any("present values kept" in c for c in r.meta["cleaning"])
