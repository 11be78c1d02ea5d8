"""The add-effect loop on the measured data (CARMA speed command; AstaZero closed
loop with grade). Reads canonical files converted by the loaders' `avll load`:

    avll load ../shared/data/carma/dataN.csv --format carma --out DIR/carma_dataN.csv
    avll load ../shared/data/openacc-astazero/platoon/ASta_040719_platoonN.csv \\
        --format openacc-astazero --out DIR/asta_pN.csv

Usage: MPLBACKEND=Agg python benches/effects_real_data.py DIR OUTDIR
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from avll.diagnose import effect_loop, write_report
from avll.io import read_runs


def carma(d: Path, out: Path) -> list[dict]:
    rows = []
    runs = {f: read_runs(d / f"carma_{f}.csv") for f in ("data5", "data6", "data9", "data10")}
    for veh in ("leader", "follower1", "follower2", "follower3", "follower4"):
        # Cruise stretches only (>= 60 s): the launch stretches are another regime
        # (the logged command is the current speed there; see README § Field data).
        def pick(files, veh=veh):
            return [r for f in files for r in runs[f]
                    if r.run_id.split("/")[1] == veh and r.t[-1] - r.t[0] >= 60]  # fmt: skip

        cal, val = pick(("data5", "data9")), pick(("data6", "data10"))
        t = time.perf_counter()
        res = effect_loop("second", cal, val, seed=0, progress=True)
        write_report(res, out / f"carma_{veh}", title=f"CARMA {veh} (speed command)")
        d0 = res.to_dict()
        d0["vehicle"] = veh
        d0["time_s"] = time.perf_counter() - t
        rows.append(d0)
        print(veh, d0["effects"], flush=True)
    return rows


def asta(d: Path, out: Path) -> list[dict]:
    rows = []
    p7, p8 = read_runs(d / "asta_p7.csv"), read_runs(d / "asta_p8.csv")
    for a, b in zip(p7, p8, strict=True):
        pair = a.run_id.split("/")[1]
        t = time.perf_counter()
        res = effect_loop("second", [a], [b], seed=0, progress=True)
        write_report(res, out / f"asta_{pair}", title=f"AstaZero {pair} (closed loop)")
        d0 = res.to_dict()
        d0["pair"] = pair
        d0["time_s"] = time.perf_counter() - t
        rows.append(d0)
        print(pair, d0["effects"], flush=True)
    return rows


def main() -> None:
    d, out = Path(sys.argv[1]), Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    which = sys.argv[3] if len(sys.argv) > 3 else "both"
    res = {}
    if which in ("both", "carma"):
        res["carma"] = carma(d, out)
        (out / "carma.json").write_text(json.dumps(res["carma"], indent=1, default=float))
    if which in ("both", "asta"):
        res["asta"] = asta(d, out)
        (out / "asta.json").write_text(json.dumps(res["asta"], indent=1, default=float))


if __name__ == "__main__":
    main()
