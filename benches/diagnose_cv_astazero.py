"""The cross-validated residual loop on AstaZero (OpenACC, closed loop, grade), per
predecessor->follower pair. Two designs (``DESIGN``):

* ``blocks`` (default): calibration on platoon 7 (one run: three contiguous block
  folds), validation on the first half of platoon 8, test on its second half;
* ``runs``: calibration on platoon 7 and the first half of platoon 8 (two runs of two
  days: leave-one-run-out, so "most folds" means both), no validation, test on the
  second half of platoon 8.

Test runs are simulated only after the loop. Prints the fold selections and the gains
on each split; writes the JSON (strict) and a report per pair.

    MPLBACKEND=Agg python benches/diagnose_cv_astazero.py ../shared/data OUTDIR \
        [DESIGN] [PAIR ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from avll import _atomic
from avll.data import Run
from avll.diagnose import effect_loop, write_report
from avll.diagnose.loop import _block
from avll.io import read_runs


def main() -> None:
    data, out = Path(sys.argv[1]), Path(sys.argv[2])
    rest = sys.argv[3:]
    design = rest.pop(0) if rest and rest[0] in ("blocks", "runs") else "blocks"
    pairs = rest or ["v1-v2", "v2-v3", "v3-v4", "v4-v5"]
    out.mkdir(parents=True, exist_ok=True)
    plat = data / "openacc-astazero" / "platoon"
    p7 = {r.run_id.split("/")[1]: r for r in
          read_runs(plat / "ASta_040719_platoon7.csv", format="openacc-astazero",
                    command_kind="acceleration")}  # fmt: skip
    p8 = {r.run_id.split("/")[1]: r for r in
          read_runs(plat / "ASta_040719_platoon8.csv", format="openacc-astazero",
                    command_kind="acceleration")}  # fmt: skip
    for pair in pairs:
        b = p8[pair]
        half = len(b) // 2
        val: Run | None = _block(b, 0, half)
        test = _block(b, half, len(b))
        t = time.perf_counter()
        if design == "blocks":
            cal = [p7[pair]]
        else:
            assert val is not None
            cal, val = [p7[pair], val], None
        res = effect_loop("second", cal, [val] if val is not None else [], test_runs=[test],
                          seed=0, progress=True)  # fmt: skip
        d = res.to_dict()
        d["time_s"] = time.perf_counter() - t
        _atomic.write_json(out / f"asta_{pair}.json", _atomic.json_safe(d), default=float)
        write_report(res, out / f"asta_{pair}", title=f"AstaZero {pair} (closed loop)")
        print(f"== {pair}: effects {d['effects'] or 'none'} ({d['time_s']:.0f} s)")
        bm = d["baseline_mse"]
        print("   baseline MSE cal/val/test:",
              ", ".join(f"{k} {v['mean']:.4g}" for k, v in bm.items() if v["per_run"]))
        for tr in d["trials"]:
            print(f"   it {tr['iteration']} {tr['effect']}: fold gains "
                  + ", ".join(f"{100 * g:+.1f}%" for g in tr["fold_gains"])
                  + f", fold_selection {tr['fold_selection']:.2f}, pooled "
                  f"{100 * tr['gain']:+.1f}% (p={tr['p_value']:.2g}) -> "
                  + ("pass" if tr["passed"] else "; ".join(tr["reasons"])))
        for s in d["steps"]:
            def g(a: str, s: dict = s) -> str:
                b0, b1 = s.get(f"{a}_mse_before"), s.get(f"{a}_mse_after")
                if b0 is None or b1 is None:
                    return "—"
                return "—" if b0 is None else f"{b0:.4g}->{b1:.4g} ({100 * (1 - b1 / b0):+.1f}%)"

            print(f"   step {s['effect']} {s['params']}: cal {g('cal')}, val {g('val')}, "
                  f"test {g('test')}, flags {s['flags']}, at bound "
                  f"{[a['param'] for a in s['at_bound']]}")
        print("   residual:", d["unexplained"].get("message"))
        print("   flags:", [f["kind"] for f in d["flags"]], flush=True)


if __name__ == "__main__":
    main()
