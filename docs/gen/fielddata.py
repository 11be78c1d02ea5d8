"""The numbers of ``docs/findings.md`` and ``docs/guide/field-data.md``, recomputed from
the CARMA and OpenACC AstaZero files in ``../shared/data`` (read, never copied). Parts,
each kept as strict JSON ``out/findings_fielddata/<part>.json`` (a part whose JSON
exists is not recomputed, so an interrupted run resumes) and rendered as the fragment
``docs/_generated/fielddata_<part>.md`` by :mod:`docs.gen` (``python -m docs.gen
--only fielddata-<part>``), its numbers beside it:

* ``loaders``: what the loaders report (CARMA stretches, cleaning, units, quantised
  acceleration, launch/cruise; AstaZero pairs and free-flow runs) — seconds;
* ``grade``: how the road grade maps onto the AstaZero lap (offset and lap scans) —
  seconds;
* ``firstlook``: the paper's Table II models driven by the CARMA speed command, a
  calibration per vehicle on all stretches (:func:`avll.calibrate`), the command/speed
  lag table and an asymmetric-lag grid — about a minute;
* ``closed``: AstaZero steady-state spacing and a closed-loop calibration per pair;
* ``carma``: :func:`avll.studies.fielddata.carma_study` (GA, cruise and launch, two
  objectives) — minutes;
* ``astazero``: :func:`avll.studies.fielddata.astazero_study` (GA, closed loop, two
  objectives, Table II baselines) and the oscillation amplification per car —
  minutes;
* ``budget``: the studies' main combinations with the GA's full budget — hours;
* ``summary``: headline sentences of the parts above.

``tests/test_findings_docs.py`` recomputes the cheap parts and compares them with the
committed numbers and fragments.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

import avll
from avll import _atomic
from avll.defaults import DEFAULT_STARTS, GA_OPTIONS
from avll.paper import G
from avll.report import md_table as _md
from avll.report import num as _f

from . import DATA, ROOT, Generated

OUT = ROOT / "out" / "findings_fielddata"
PARTS = ("loaders", "grade", "firstlook", "closed", "carma", "astazero", "budget")
VEHICLES = ("leader", "follower1", "follower2", "follower3", "follower4")
MODELS = ("first", "second", "proposed")
CARMA_FILES = ("data5", "data6", "data9", "data10")
CAL_FILES = ("data5", "data9")
PAIRS = ("v1-v2", "v2-v3", "v3-v4", "v4-v5")
#: GA budgets of the two studies (the studies' defaults).
STUDY_GA: dict[str, dict[str, Any]] = {
    "carma": dict(max_generations=60, stall_generations=12, starts=1),
    "astazero": dict(max_generations=40, stall_generations=10, starts=1),
}
#: The GA's full default budget (``avll.calibrate``), for the ``budget`` part.
FULL_GA: dict[str, Any] = dict(max_generations=300, stall_generations=20, starts=2)
#: Objective weights ``(wa, wv, wx)`` of the first look's closed-loop calibrations: the
#: acceleration and the gap (the position, the leader being measured) error, 1 m of gap
#: weighing as 0.1 m/s² of acceleration.
CLOSED_WEIGHTS = (1.0, 0.0, 0.01)


# ---------------------------------------------------------------------------- helpers
def _rng(xs: Sequence[float | None], fmt: str = ".3g", sep: str = "–") -> str:
    v = [float(x) for x in xs if x is not None and math.isfinite(x)]
    if not v:
        return "—"
    lo, hi = _f(min(v), fmt), _f(max(v), fmt)
    if min(v) < 0 and sep == "–":
        sep = " … "
    return lo if lo == hi else f"{lo}{sep}{hi}"


def _df(df: Any) -> dict[str, Any]:
    """A pandas table as plain lists (index entries joined by '/')."""
    idx = ["/".join(map(str, i)) if isinstance(i, tuple) else str(i) for i in df.index]
    return {"index": idx, "columns": [str(c) for c in df.columns],
            "data": [[None if not math.isfinite(float(x)) else float(x) for x in row]
                     for row in df.to_numpy(dtype=float)]}  # fmt: skip


def _cell(t: dict[str, Any], row: str, col: str) -> float | None:
    return t["data"][t["index"].index(row)][t["columns"].index(col)]


def _table_md(t: dict[str, Any], fmt: str = ".4f", first: str = "") -> str:
    rows = [[i, *row] for i, row in zip(t["index"], t["data"], strict=True)]
    return _md([first, *t["columns"]], rows, fmt)


def _settings(d: dict[str, Any], ga: dict[str, Any] | None = None) -> str:
    """The line that states a part's settings."""
    if ga is None:
        return "*Deterministic (no random numbers).*\n"
    return (f"*Seed {d['seed']}, GA {ga['max_generations']} generations (stall "
            f"{ga['stall_generations']}), {ga['starts']} start(s), threads "
            f"{d['threads'] or 'all'}.*\n")


#: The GA budget of the first look's calibrations (avll.calibrate's defaults).
_DEFAULT_GA: dict[str, Any] = {"max_generations": GA_OPTIONS["max_generations"],
                               "stall_generations": GA_OPTIONS["stall_generations"],
                               "starts": DEFAULT_STARTS}


def _hp(x: np.ndarray, n: int) -> np.ndarray:
    """High-pass: minus the centred moving average over ``n`` samples."""
    return x - np.convolve(x, np.ones(n) / n, mode="same")


def _col(r: avll.Run, name: Literal["command", "v", "x", "lead_x", "lead_v", "lead_a"]
         ) -> np.ndarray:
    """Series ``name`` of ``r``, which the loaders read here always fill (CARMA: the
    command and the speed; AstaZero: the speed and the position, in a pair the leader's)."""
    x: np.ndarray | None = getattr(r, name)
    if x is None:
        raise ValueError(f"run {r.run_id!r}: no {name!r} series (the loader always sets it)")
    return x


# ---------------------------------------------------------------------------- loaders
def carma_runs(data: Path) -> list[avll.Run]:
    from avll.io import load_carma

    runs: list[avll.Run] = []
    for f in CARMA_FILES:
        runs += load_carma(data / "carma" / f"{f}.csv", min_duration=10.0)
    return runs


def part_loaders(data: Path, **_: Any) -> dict[str, Any]:
    """What the loaders find in the files (the field-data guide's numbers)."""
    from avll.io import carma_report, load_openacc_astazero
    from avll.io.openacc import load_slope
    from avll.studies.fielddata import split_launch_cruise

    runs = carma_runs(data)
    rep = carma_report(runs)
    out_of_order = {}
    for r in runs:
        notes = " ".join(r.meta["file_report"]["notes"])
        m = re.search(r"(\d+) rows were out of order", notes)
        out_of_order[Path(r.meta["file"]).stem] = int(m.group(1)) if m else 0
    vrep = [v for f in {r.meta["file"]: r for r in runs}.values()
            for v in f.meta["file_report"]["vehicles"].values()]  # fmt: skip
    durs = np.array([(len(r) - 1) * r.dt for r in runs])
    a = np.concatenate([r.a for r in runs])
    dv = np.concatenate([np.gradient(_col(r, "v"), r.dt) for r in runs])
    err = np.concatenate([_col(r, "v") - _col(r, "command") for r in runs])
    bridged = int(sum(r.meta["bridged_samples"] for r in runs))
    launch, cruise = split_launch_cruise(runs)
    starts_low = [r for r in runs if _col(r, "v")[0] < 2.0]
    joined = sorted({"/".join(r.run_id.split("/")[:2]) for r in cruise
                     if r.run_id.endswith("/cruise")})  # fmt: skip
    cruise_v = np.concatenate([r.v for r in cruise])
    dv0 = [float(_col(r, "v")[0] - _col(r, "command")[0]) for r in cruise]
    carma = {
        "stretches": len(runs),
        "total_min": float(durs.sum() / 60),
        "median_s": float(np.median(durs)),
        "max_s": float(durs.max()),
        "out_of_order_rows": out_of_order,
        "bridged_samples": bridged,
        "bridged_share": bridged / int(sum(len(r) for r in runs)),
        "ovr_flag_equals_mode2": sum(bool(v["ovr_flag_equals_mode2"]) for v in vrep),
        "vehicle_series": len(vrep),
        "override_flag_present": sum(bool(v["override_flag_present"]) for v in vrep),
        "a_quantum": [min(v["a_quantum"] for v in vrep), max(v["a_quantum"] for v in vrep)],
        "slope_dvdt_on_a": float(np.dot(dv, a) / np.dot(a, a)),
        "share_a_zero": float(np.mean(a == 0)),
        "speed_minus_command_q05_q95": [float(np.quantile(err, 0.05)),
                                        float(np.quantile(err, 0.95))],
        "report": [{k: (v.item() if hasattr(v, "item") else v) for k, v in row.items()}
                   for row in rep.to_dict(orient="records")],  # fmt: skip
        "launch_s": [float(min((len(r) - 1) * r.dt for r in launch)),
                     float(max((len(r) - 1) * r.dt for r in launch))],
        "launch_count": len(launch),
        "starts_from_standstill": len(starts_low),
        "cruise_count": len(cruise),
        "cruise_min": [float(min((len(r) - 1) * r.dt for r in cruise) / 60),
                       float(max((len(r) - 1) * r.dt for r in cruise) / 60)],
        "cruise_speed_q01_q99": [float(np.quantile(cruise_v, 0.01)),
                                 float(np.quantile(cruise_v, 0.99))],
        "joined_launch_cruise": joined,
        "cruise_start_speed_minus_command": [min(dv0), max(dv0)],
        "cruise_start_abs_over_half": int(sum(abs(x) > 0.5 for x in dv0)),
    }
    asta = data / "openacc-astazero"
    sx, sy, lap = load_slope(asta / "platoon" / "Slope.csv")
    ar = load_openacc_astazero(asta)
    plat: dict[str, Any] = {}
    for r in ar:
        if r.meta["kind"] == "platoon":
            stem = r.run_id.split("/")[0]
            e = plat.setdefault(stem, {"pairs": 0, "samples": len(r),
                                       "duration_s": (len(r) - 1) * r.dt,
                                       "spacing_max_deviation": 0.0, "accel_fd_max": 0.0})
            e["pairs"] += 1
            e["spacing_max_deviation"] = max(e["spacing_max_deviation"],
                                             float(r.meta["spacing_max_deviation"]))
            fwd = np.diff(_col(r, "v")) / r.dt
            e["accel_fd_max"] = max(e["accel_fd_max"], float(np.max(np.abs(fwd - r.a[:-1]))))
    free = []
    for r in ar:
        if r.meta["kind"] == "freeflow":
            vs = float(r.meta["set_speed"])
            v = _col(r, "v")
            free.append({"id": r.run_id, "duration_s": (len(r) - 1) * r.dt,
                         "set_kmh": round(vs * 3.6), "mean_minus_set": float(np.mean(v - vs)),
                         "below_pct": float(100 * (1 - np.mean(v) / vs))})  # fmt: skip
    return {"carma": carma,
            "astazero": {"lap_m": float(lap), "grade_integral_m": float(np.trapezoid(sy, sx)),
                         "grade_abs_max": float(np.abs(sy).max()), "platoon": plat,
                         "freeflow": free}}  # fmt: skip


# ---------------------------------------------------------------------------- grade
def part_grade(data: Path, **_: Any) -> dict[str, Any]:
    """The grade lookup's offset (free flow) and lap length (platoon files)."""
    from avll.io import load_openacc_astazero
    from avll.io.openacc import grade_at, load_slope

    asta = data / "openacc-astazero"
    slope = load_slope(asta / "platoon" / "Slope.csv")
    runs = load_openacc_astazero(asta)
    w = 40
    offs = np.arange(-60.0, 81.0, 1.0)
    groups: dict[int, list[avll.Run]] = {}
    for r in runs:
        if r.meta["kind"] == "freeflow":
            groups.setdefault(round(r.meta["set_speed"] * 3.6), []).append(r)
    rows: list[dict[str, Any]] = []
    for kmh, rr in sorted(groups.items()):
        A = np.concatenate([_hp(r.a, w)[w:-w] for r in rr])
        cs = []
        for o in offs:
            D = np.concatenate([_hp(-G * grade_at(_col(r, "x"), slope, offset=o), w)[w:-w]
                                for r in rr])
            cs.append((np.corrcoef(A, D)[0, 1], np.dot(A, D) / np.dot(D, D)))
        c = np.array(cs)
        i = int(np.argmax(c[:, 0]))
        i0 = int(np.flatnonzero(offs == 0)[0])
        near = offs[c[:, 0] >= c[i, 0] - 0.02]
        far = [float(c[int(np.flatnonzero(offs == o)[0]), 0]) for o in (-60.0, 60.0)]
        rows.append({"set_kmh": kmh, "files": len(rr),
                     "seconds": float(sum((len(r) - 1) * r.dt for r in rr)),
                     "best_offset_m": float(offs[i]),
                     "best_offset_s": float(offs[i] / (kmh / 3.6)),
                     "corr_best": float(c[i, 0]), "slope_best": float(c[i, 1]),
                     "corr_0": float(c[i0, 0]), "slope_0": float(c[i0, 1]),
                     "near": [float(near.min()), float(near.max())],
                     "corr_m60": far[0], "corr_p60": far[1]})  # fmt: skip
    ff = [r for r in runs if r.meta["kind"] == "freeflow"]
    A = np.concatenate([_hp(r.a, w)[w:-w] for r in ff])
    D = np.concatenate([_hp(G * grade_at(_col(r, "x"), slope, offset=15.0), w)[w:-w] for r in ff])
    sign = float(np.corrcoef(A, D)[0, 1])
    series = []
    for r in runs:
        if r.meta["kind"] != "platoon":
            continue
        m = _col(r, "v") > 5.0
        series.append((_col(r, "x")[m], r.a[m]))
        if r.meta["leader_index"] == 1:
            series.append((_col(r, "lead_x")[m] + r.meta["lead_length"], _col(r, "lead_a")[m]))
    A = np.concatenate([_hp(a, w)[w:-w] for _, a in series])
    lap = []
    for dl in (-40.0, -20.0, -10.0, -5.0, 0.0, 5.0, 10.0, 20.0, 40.0):
        D = np.concatenate([_hp(-G * grade_at(x, slope, offset=15.0, lap_length=slope[2] + dl),
                                w)[w:-w] for x, _ in series])  # fmt: skip
        lap.append({"delta_m": dl, "corr": float(np.corrcoef(A, D)[0, 1])})
    g15 = np.concatenate([grade_at(_col(r, "x"), slope, offset=15.0) for r in ff])
    g0 = np.concatenate([grade_at(_col(r, "x"), slope) for r in ff])
    return {"offset_scan": rows, "free_flow_minutes": float(sum(x["seconds"] for x in rows) / 60),
            "opposite_sign_corr": sign, "lap_scan": lap,
            "rms_shift_15": float(np.sqrt(np.mean((g15 - g0) ** 2))),
            "rms_grade": float(np.sqrt(np.mean(g0**2)))}  # fmt: skip


# ---------------------------------------------------------------------------- first look
def _costs(model: avll.LowerLevelModel, runs: list[avll.Run],
           weights: tuple[float, float, float]) -> float:
    """Mean over ``runs`` of the per-run cost (one batched call): the speed loop driven
    by the recorded command from the equilibrium of its first value."""
    c = avll.batch_cost(model.name, model.to_array()[None, :], runs, weights=weights,
                        init="steady")  # fmt: skip
    return float(np.mean(c[0]))


def table_ii_transfer(runs: list[avll.Run]) -> dict[str, Any]:
    """The paper's Table II models driven by the CARMA speed command (all stretches)."""
    return {name: {"dc_gain": float(m.dc_gain), "mse_a": _costs(m, runs, (1.0, 0.0, 0.0)),
                   "mse_v": _costs(m, runs, (0.0, 1.0, 0.0))}
            for name, m in avll.PAPER_TABLE_II.items()}  # fmt: skip


def part_firstlook(data: Path, *, seed: int, threads: int, **_: Any) -> dict[str, Any]:
    """Table II transferred, a calibration per vehicle and model on all stretches
    (acceleration objective, the CARMA study's box), the command/speed lags and the
    asymmetric-lag grid of the cruises."""
    from avll.studies.fielddata import CARMA_BOUNDS

    runs = carma_runs(data)
    fits = []
    for veh in VEHICLES:
        vr = [r for r in runs if r.meta["vehicle"] == veh]
        cal = [r for r in vr if r.run_id.split("/")[0] in CAL_FILES]
        val = [r for r in vr if r.run_id.split("/")[0] not in CAL_FILES]
        for k, name in enumerate(MODELS):
            m = avll.calibrate(name, cal, init="steady", bounds=CARMA_BOUNDS.get(name),
                               seed=seed + k, threads=threads).model  # fmt: skip
            fits.append({"vehicle": veh, "model": name,
                         "cal_a": _costs(m, cal, (1.0, 0.0, 0.0)),
                         "val_a": _costs(m, val, (1.0, 0.0, 0.0)),
                         "params": {k: float(v) for k, v in m.to_dict().items()}})
        print(f"  first look: fitted {veh}", file=sys.stderr, flush=True)
    regimes = {"launch": [r for r in runs if _col(r, "v")[0] < 1.0],
               "cruise": [r for r in runs if _col(r, "v")[0] >= 1.0]}
    lags = {}
    for rg, rr in regimes.items():
        vals = {}
        for k in (0, 5, 10, 20, 30):
            e = np.concatenate([_col(r, "command")[: len(r) - k] - _col(r, "v")[k:] for r in rr])
            vals[f"{k * 0.1:g}"] = float(np.mean(np.abs(e)))
        lags[rg] = {"stretches": len(rr), "mean_abs": vals,
                    "rms_a": float(np.sqrt(np.mean(np.concatenate([r.a for r in rr]) ** 2)))}
    asym = []
    tgrid = np.round(np.r_[0.05, np.arange(0.1, 1.0, 0.1), np.arange(1.0, 8.01, 0.2)], 2)
    tu, td_ = (g.ravel() for g in np.meshgrid(tgrid, tgrid, indexing="ij"))
    sym = np.flatnonzero(tu == td_)
    for veh in VEHICLES:
        vr = [r for r in regimes["cruise"] if r.meta["vehicle"] == veh]
        best_s: tuple[float, ...] | None = None
        best_a: tuple[float, ...] | None = None
        for d in (0, 2, 4, 6):
            tot = np.zeros(tu.size)
            for r in vr:
                cmd = _col(r, "command")
                u = np.r_[np.full(d, cmd[0]), cmd[: len(r) - d]]
                v = np.full(tu.size, _col(r, "v")[0])
                sse = np.zeros(tu.size)
                for n in range(len(r)):  # every (T_up, T_down) of the grid at once
                    e = u[n] - v
                    acc = e / np.where(e > 0, tu, td_)
                    sse += (acc - r.a[n]) ** 2
                    v = v + r.dt * acc
                tot += sse / len(r) / len(vr)
            i = int(np.argmin(tot))
            j = int(sym[np.argmin(tot[sym])])
            if best_a is None or tot[i] < best_a[0]:
                best_a = (float(tot[i]), d * 0.1, float(tu[i]), float(td_[i]))
            if best_s is None or tot[j] < best_s[0]:
                best_s = (float(tot[j]), d * 0.1, float(tu[j]))
        assert best_s is not None and best_a is not None
        asym.append({"vehicle": veh, "stretches": len(vr), "sym_d": best_s[1],
                     "sym_T": best_s[2], "sym_mse": best_s[0], "asym_d": best_a[1],
                     "T_up": best_a[2], "T_down": best_a[3], "asym_mse": best_a[0]})
        print(f"  first look: asymmetric lag {veh}", file=sys.stderr, flush=True)
    return {"seed": seed, "threads": threads, "table_ii": table_ii_transfer(runs),
            "fits": fits, "lags": lags, "asymmetric_cruise": asym}


# ---------------------------------------------------------------------------- closed
def closed_pair(r: avll.Run, seed: int, threads: int) -> dict[str, Any]:
    """Steady-state spacing regression and a closed-loop calibration of one pair (from
    the first sample above 1 m/s)."""
    from avll.defaults import UPPER_NAMES, UPPER_PLACEHOLDER
    i0 = int(np.flatnonzero(_col(r, "v") > 1.0)[0])
    r = replace(r.cut(i0, len(r), "", f"from row {i0}, the first above 1 m/s"),
                upper=UPPER_PLACEHOLDER)
    lx, lv, am, x, v = _col(r, "lead_x"), _col(r, "lead_v"), r.a, _col(r, "x"), _col(r, "v")
    gap = lx - x
    calm = ((np.abs(am) < 0.05) & (np.abs(_col(r, "lead_a")) < 0.05) & (np.abs(v - lv) < 0.2)
            & (v > 5))
    calm = np.convolve(calm.astype(float), np.ones(31) / 31, mode="same") > 0.999
    tg_ss, gmin_ss = (np.polyfit(v[calm], gap[calm], 1) if calm.sum() > 50
                      else (math.nan, math.nan))  # fmt: skip
    res = avll.calibrate("first", [r], closed_loop=True, upper_free=UPPER_NAMES,
                         weights=CLOSED_WEIGHTS, seed=seed, threads=threads)  # fmt: skip
    p = res.params
    tr = avll.closed_loop(res.model, lx, lv, r.dt, avll.UpperLevel(**res.upper),
                          v0=float(v[0]), x0=float(x[0]))  # fmt: skip
    e = am - tr.a
    ok = np.isfinite(e)
    gg = -G * r.exo["grade"][ok]
    X = np.c_[np.maximum(tr.a, 0), np.minimum(tr.a, 0)][ok]
    gp, gn = np.linalg.lstsq(X, am[ok], rcond=None)[0]
    return {"pair": r.run_id, "steady_samples": int(calm.sum()), "Tg_steady": float(tg_ss),
            "Gmin_steady": float(gmin_ss),
            "fit": {k: float(p[k]) for k in ("kg", "kv", "Tg", "Gmin", "Td")},
            "mse_a": float(np.mean(e[ok] ** 2)),
            "mse_gap": float(np.mean(((lx - tr.x) - gap)[ok] ** 2)),
            "grade_coef": float(np.dot(e[ok], gg) / np.dot(gg, gg)),
            "grade_corr": float(np.corrcoef(e[ok], gg)[0, 1]),
            "gain_pos": float(gp), "gain_neg": float(gn)}  # fmt: skip


def part_closed(data: Path, *, seed: int, threads: int, **_: Any) -> dict[str, Any]:
    """:func:`closed_pair` of every AstaZero pair and the maximum speed along each
    platoon."""
    from avll.io import load_openacc_astazero

    runs = load_openacc_astazero(data / "openacc-astazero" / "platoon",
                                 command_kind="acceleration")  # fmt: skip
    rows = []
    for r in runs:
        rows.append(closed_pair(r, seed, threads))
        print(f"  closed loop: fitted {r.run_id}", file=sys.stderr, flush=True)
    vmax: dict[str, list[float]] = {}
    for r in runs:
        stem = r.run_id.split("/")[0]
        if r.meta["leader_index"] == 1:
            vmax.setdefault(stem, []).append(float(_col(r, "lead_v").max()))
    for r in runs:
        vmax[r.run_id.split("/")[0]].append(float(_col(r, "v").max()))
    return {"seed": seed, "threads": threads, "pairs": rows, "max_speed": vmax}


# ---------------------------------------------------------------------------- studies
def part_carma(data: Path, *, seed: int, threads: int, **_: Any) -> dict[str, Any]:
    from avll.studies.fielddata import carma_study

    st = carma_study(data / "carma", seed=seed, threads=threads, figures=False,
                     **STUDY_GA["carma"])  # fmt: skip
    if st.summary["interrupted"]:
        raise RuntimeError("carma_study was interrupted")
    studies = st.summary["studies"]
    return {"ga": st.summary["ga"], "seed": seed, "threads": threads,
            "tables": {k: _df(v) for k, v in st.tables.items()},
            "params": {rg: {o: {m: e["params"] for m, e in d["models"].items()}
                            for o, d in s.items()} for rg, s in studies.items()},
            "at_bound": {rg: {o: {m: {g: ge["at_bound"] for g, ge in e["groups"].items()}
                                  for m, e in d["models"].items()} for o, d in s.items()}
                         for rg, s in studies.items()}}  # fmt: skip


def amplification(pairs: list[avll.Run], fits: dict[str, Any]) -> list[dict[str, Any]]:
    """Per pair: std of the follower's 20 s high-passed speed over its predecessor's
    (20 s edges left out), measured and simulated with each calibrated model."""
    from avll.models import UpperLevel
    from avll.rollout import closed_loop
    from avll.studies.fielddata import _UPPER, _model

    out = []
    for r in pairs:
        pair = r.run_id.split("/")[-1]
        sl = slice(200, len(r) - 200)
        lx, lv, v, x = _col(r, "lead_x"), _col(r, "lead_v"), _col(r, "v"), _col(r, "x")
        ref = np.std(_hp(lv, 200)[sl])
        sims = {}
        for m, e in fits.items():
            p = e["params"][pair]
            tr = closed_loop(_model(m, p), lx, lv, r.dt,
                             UpperLevel(*(p[k] for k in _UPPER)), v0=float(v[0]),
                             x0=float(x[0]))  # fmt: skip
            sims[m] = float(np.std(_hp(tr.v, 200)[sl]) / ref)
        out.append({"run": r.run_id, "measured": float(np.std(_hp(v, 200)[sl]) / ref),
                    "simulated": sims})  # fmt: skip
    return out


def part_astazero(data: Path, *, seed: int, threads: int, **_: Any) -> dict[str, Any]:
    from avll.studies.fielddata import astazero_study

    st = astazero_study(data / "openacc-astazero" / "platoon", seed=seed, threads=threads,
                        figures=False, **STUDY_GA["astazero"])  # fmt: skip
    if st.summary["interrupted"]:
        raise RuntimeError("astazero_study was interrupted")
    studies = st.summary["studies"]
    return {"ga": st.summary["ga"], "seed": seed, "threads": threads,
            "tables": {k: _df(v) for k, v in st.tables.items()},
            "params": {o: {m: e["params"] for m, e in d["models"].items()}
                       for o, d in studies.items()},
            "table_ii_params": {o: {m: e["params"] for m, e in d.get("table_ii", {}).items()}
                                for o, d in studies.items()},
            "amplification": amplification(st.runs["pairs"],
                                           studies["mixed"]["models"])}  # fmt: skip


def part_budget(data: Path, *, seed: int, threads: int, **_: Any) -> dict[str, Any]:
    """The studies' main combinations again with the GA's full budget (CARMA cruise,
    both objectives; AstaZero mixed objective, no baseline): what the reduced budget
    of the ``carma`` and ``astazero`` parts costs."""
    from avll.studies.fielddata import astazero_study, carma_study

    c = carma_study(data / "carma", seed=seed, threads=threads, figures=False,
                    regimes=("cruise",), **FULL_GA)
    a = astazero_study(data / "openacc-astazero" / "platoon", seed=seed, threads=threads,
                       figures=False, objectives=("mixed",), baseline=False,
                       **FULL_GA)
    if c.summary["interrupted"] or a.summary["interrupted"]:
        raise RuntimeError("a full-budget study was interrupted")
    keep = ("cal_", "val_")
    return {"ga": FULL_GA, "seed": seed, "threads": threads,
            "carma": {k: _df(v) for k, v in c.tables.items() if k.startswith(keep)},
            "astazero": {k: _df(v) for k, v in a.tables.items() if k.startswith(keep)}}


COMPUTE: dict[str, Callable[..., dict[str, Any]]] = {
    "loaders": part_loaders, "grade": part_grade, "firstlook": part_firstlook,
    "closed": part_closed, "carma": part_carma, "astazero": part_astazero,
    "budget": part_budget,
}


# ---------------------------------------------------------------------------- render
def _not_run(part: str) -> str:
    return f"*Part `{part}` has not been run; no numbers.*\n"


def render_loaders(d: dict[str, Any]) -> str:
    """The loaders' numbers (the field-data guide)."""
    c, a = d["carma"], d["astazero"]
    files: dict[str, list[dict[str, Any]]] = {}
    for row in c["report"]:
        files.setdefault(row["file"], []).append(row)
    keys = ("stretches", "total_s", "min_s", "max_s", "bridged", "long_holes", "dropped_short")
    rows = []
    for f, rr in files.items():
        rows.append([f, " / ".join(r["vehicle"].replace("follower", "f") for r in rr),
                     *[" / ".join(_f(r[k], ".3g") for r in rr) for k in keys]])
    q05, q95 = c["speed_minus_command_q05_q95"]
    lo, hi = c["cruise_start_speed_minus_command"]
    ooo = ", ".join(f"{f}: {n}" for f, n in c["out_of_order_rows"].items())
    lines = [
        _settings(d),
        "**CARMA** (`avll.io.load_carma`, `min_duration` 10 s, `max_hole` 0.2 s):",
        "",
        f"* rows out of order, sorted by `Time`: {ooo};",
        f"* {c['stretches']} stretches, {c['total_min']:.1f} min in all (median "
        f"{c['median_s']:.0f} s, longest {c['max_s']:.0f} s); {c['bridged_samples']} samples "
        f"bridged, {100 * c['bridged_share']:.1f} % of the kept data;",
        f"* `V_CARMA_ovr` equals 1 exactly when the mode is 2 in {c['ovr_flag_equals_mode2']} "
        f"of {c['vehicle_series']} vehicle series; `V_CARMA_ovr_manual` has values in "
        f"{c['override_flag_present']} of them;",
        f"* units: slope of d(wheel speed)/dt on the CAN acceleration "
        f"{c['slope_dvdt_on_a']:.3f} over all stretches (km/h would give 3.6); speed − "
        f"command within [{q05:+.2f}, {q95:+.2f}] m/s (5–95 %);",
        f"* acceleration quantum estimated per vehicle {_rng(c['a_quantum'], '.4f')} m/s² "
        f"(`meta[\"a_quantum\"]`); {100 * c['share_a_zero']:.0f} % of the kept samples read "
        "exactly 0;",
        f"* {c['starts_from_standstill']} stretches start from standstill; "
        f"`split_launch_cruise` gives {c['launch_count']} launches of "
        f"{_rng(c['launch_s'], '.0f')} s and {c['cruise_count']} cruises of "
        f"{_rng(c['cruise_min'], '.1f')} min at {_rng(c['cruise_speed_q01_q99'], '.0f')} m/s "
        "(1–99 % of the cruise speed); stretches where launch and cruise were joined "
        f"(no zero-command glitch): {', '.join(c['joined_launch_cruise']) or 'none'};",
        f"* at the start of the cruises the measured speed differs from the first command "
        f"by {lo:+.2f} … {hi:+.2f} m/s (|Δ| > 0.5 m/s in {c['cruise_start_abs_over_half']} "
        f"of {c['cruise_count']}).",
        "",
        _md(["file", "vehicle", *keys], rows),
        "",
        f"**OpenACC AstaZero**: lap {a['lap_m']:.3f} m (last `X` of `Slope.csv`), the grade "
        f"integrates to {a['grade_integral_m']:+.2f} m over it, |Y| ≤ "
        f"{a['grade_abs_max']:.3f}.",
        "",
        _md(["platoon file", "pairs", "samples", "duration s", "max abs(lead_x − x − Spacing) m",
             "max abs(Accel − forward difference of speed) m/s²"],
            [[f, p["pairs"], p["samples"], _f(p["duration_s"], ".1f"),
              _f(p["spacing_max_deviation"], ".2g"), _f(p["accel_fd_max"], ".2g")]
             for f, p in a["platoon"].items()]),
        "",
        _md(["free-flow run", "duration s", "set speed km/h", "mean speed − set m/s",
             "below set %"],
            [[x["id"], _f(x["duration_s"], ".0f"), x["set_kmh"], _f(x["mean_minus_set"], "+.2f"),
              _f(x["below_pct"], ".1f")] for x in a["freeflow"]]),
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def render_grade(d: dict[str, Any]) -> str:
    """The grade offset and lap scans."""
    rows = [[f"{x['set_kmh']} km/h ({x['files']} files, {x['seconds']:.0f} s)",
             f"{x['best_offset_m']:+.0f} m ({x['best_offset_s']:.2f} s)", _f(x["corr_best"], ".2f"),
             _f(x["slope_best"], ".2f"), _f(x["corr_0"], ".2f"), _f(x["slope_0"], ".2f"),
             f"{x['near'][0]:+.0f}..{x['near'][1]:+.0f} m",
             f"{x['corr_m60']:.2f} / {x['corr_p60']:.2f}"] for x in d["offset_scan"]]
    lap = [[f"{x['delta_m']:+.0f}", _f(x["corr"], ".3f")] for x in d["lap_scan"]]
    lines = [
        _settings(d),
        "Free flow: fast part of the measured acceleration (minus a 4 s moving average) "
        "against that of −g·grade((x + offset) mod lap):",
        "",
        _md(["set speed", "best offset", "corr at best", "slope at best", "corr at offset 0",
             "slope at 0", "within 0.02 of best", "corr at −60 / +60 m"], rows),
        "",
        f"With the opposite sign (+g·grade, offset +15 m) the correlation is "
        f"{d['opposite_sign_corr']:+.2f}. Free flow in all: {d['free_flow_minutes']:.0f} min. "
        "Platoon files (all ten cars, v > 5 m/s, offset +15 m), correlation against a lap "
        "length changed by Δ:",
        "",
        _md(["Δ lap (m)", "corr"], lap),
        "",
        f"RMS of grade(x + 15 m) − grade(x) in free flow: {d['rms_shift_15']:.4f}, against an "
        f"RMS grade of {d['rms_grade']:.4f}.",
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def render_firstlook(d: dict[str, Any]) -> str:
    """Table II transferred, the calibrations on all stretches, the lags and the
    asymmetric-lag grid."""
    t2 = d["table_ii"]
    rows = [[m, _f(e["dc_gain"], ".3g"), _f(e["mse_v"], ".3g"), _f(e["mse_a"], ".3g")]
            for m, e in t2.items()]
    fits = {(x["vehicle"], x["model"]): x for x in d["fits"]}
    frows = []
    for v in VEHICLES:
        cells = []
        for m in MODELS:
            x = fits[(v, m)]
            cell = f"{x['cal_a']:.3f} / {x['val_a']:.3f}"
            if m == "first":
                cell += f" (T {x['params']['Td']:.2f} s)"
            cells.append(cell)
        frows.append([v, *cells])
    tds = [fits[(v, m)]["params"]["Td"] for v in VEHICLES for m in ("second", "proposed")]
    lag_head = ["regime", "stretches", "RMS a (m/s²)"] + [f"k = {k} s" for k in
                                                          d["lags"]["launch"]["mean_abs"]]
    lag = [[rg, e["stretches"], _f(e["rms_a"], ".2f"), *[_f(v, ".2f")
                                                        for v in e["mean_abs"].values()]]
           for rg, e in d["lags"].items()]  # fmt: skip
    asym = [[x["vehicle"], _f(x["sym_d"], ".1f"), _f(x["sym_T"], ".2f"), _f(x["sym_mse"], ".4f"),
             _f(x["asym_d"], ".1f"), _f(x["T_up"], ".2f"), _f(x["T_down"], ".2f"),
             _f(x["asym_mse"], ".4f"), f"{100 * (x['asym_mse'] / x['sym_mse'] - 1):+.1f} %"]
            for x in d["asymmetric_cruise"]]
    ratio = [x["T_down"] / x["T_up"] for x in d["asymmetric_cruise"]]
    lines = [
        _settings(d, _DEFAULT_GA),
        "The paper's Table II models driven by the CARMA speed command from the equilibrium "
        "of its first value (all stretches, launch and cruise):",
        "",
        _md(["Table II model", "DC gain", "speed MSE (m/s)²", "acceleration MSE (m/s²)²"], rows),
        "",
        "Calibrated per vehicle (`avll.calibrate`, acceleration MSE, Eq. 6; the CARMA "
        "study's box), calibration on data5 + data9, validation on data6 + data10 (all "
        "stretches; "
        "cal / val acceleration MSE (m/s²)², first-order T in brackets):",
        "",
        _md(["vehicle", "first", "second", "proposed"], frows),
        "",
        f"Dead times of the second-order and proposed fits: {_rng(tds, '.2f')} s.",
        "",
        "How the command relates to the speed: mean |cmd[n] − v[n + k]| (m/s) by lag k, "
        "and the RMS acceleration, launches (stretches starting below 1 m/s) and cruises:",
        "",
        _md(lag_head, lag),
        "",
        "Cruise stretches, first-order lag with dead time d, symmetric (one T) and "
        "asymmetric (T_up when the delayed command is above the speed, T_down otherwise), "
        "grid search on the acceleration MSE (m/s²)²:",
        "",
        _md(["vehicle", "sym d (s)", "sym T (s)", "sym MSE", "asym d (s)", "T_up (s)",
             "T_down (s)", "asym MSE", "change"], asym),
        "",
        f"T_down / T_up: {_rng(ratio, '.2f')}.",
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def render_closed(d: dict[str, Any]) -> str:
    """The steady-state spacing and the closed-loop calibration per pair."""
    rows = [[x["pair"].split("_")[-1], x["steady_samples"], _f(x["Tg_steady"], ".2f"),
             _f(x["Gmin_steady"], ".1f"),
             " / ".join(_f(x["fit"][k], ".3g") for k in ("kg", "kv", "Tg", "Gmin", "Td")),
             _f(x["mse_a"], ".3f"), _f(x["mse_gap"], ".2f"), _f(x["grade_coef"], "+.2f"),
             _f(x["grade_corr"], "+.2f"), _f(x["gain_pos"], ".2f"), _f(x["gain_neg"], ".2f")]
            for x in d["pairs"]]  # fmt: skip
    neg = [x["gain_neg"] for x in d["pairs"]]
    vmax = "; ".join(f"{f}: " + " → ".join(f"{v:.1f}" for v in vs)
                     for f, vs in d["max_speed"].items())  # fmt: skip
    lines = [
        _settings(d, _DEFAULT_GA),
        "Steady state: |a| < 0.05 and |a_lead| < 0.05 m/s², |v − v_lead| < 0.2 m/s over 3 s, "
        "v > 5 m/s; spacing = Gmin + Tg·v by least squares. Closed-loop calibration "
        "(`avll.calibrate`): the Eq. 3 upper law's four gains with a first-order lower level "
        "driven by the measured predecessor, on the acceleration MSE + 0.01 × the gap MSE. "
        "Then the measured acceleration regressed on the simulated one split by sign (gain "
        "a > 0, gain a < 0), and the residual regressed on −g·grade.",
        "",
        _md(["pair", "steady samples", "Tg steady (s)", "Gmin steady (m)",
             "fit kg / kv / Tg / Gmin / Td", "MSE a", "MSE gap", "resid. on −g·grade", "corr",
             "gain a > 0", "gain a < 0"], rows),
        "",
        f"Braking gain above 1 in {sum(g > 1 for g in neg)} of {len(neg)} pairs. Maximum "
        f"speed of each car along the platoon (m/s): {vmax}.",
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def _avg(t: dict[str, Any], row: str) -> float:
    """The row's "Average" column (nan when it was not finite)."""
    x = _cell(t, row, "Average")
    return math.nan if x is None else float(x)


def render_carma(d: dict[str, Any]) -> str:
    """The CARMA study's tables and parameter ranges."""
    T = d["tables"]
    P = d["params"]
    out = [_settings(d, d["ga"])]
    labels = [i for i in T["cal_cruise_acceleration_a"]["index"]]
    fo, so, po = labels[:3]

    def rngp(rg: str, obj: str, model: str, key: str, fmt: str = ".3g") -> str:
        return _rng([p[key] for p in P[rg][obj][model].values()], fmt)

    def dc(rg: str, obj: str, model: str) -> str:
        t = T[f"params_{rg}_{obj}"]
        j = t["columns"].index(model)
        return _rng([row[j] for i, row in zip(t["index"], t["data"], strict=True)
                     if i.endswith("/DC gain")], ".2f")  # fmt: skip

    slow, fast = [], []
    for p in P["cruise"]["speed"]["second"].values():
        r = sorted(float(abs(x)) for x in np.roots([p["m2"], p["m3"], 1.0]))
        slow.append(r[0])
        fast.append(r[-1])
    per_t = ", ".join(f"{v} {p['Td']:.2f}" for v, p in P["cruise"]["speed"]["first"].items())
    out += [
        "**Calibrated cruise parameters.** Speed objective: first-order T "
        f"{rngp('cruise', 'speed', 'first', 'Td', '.2f')} s ({per_t}); second order K0 "
        f"{rngp('cruise', 'speed', 'second', 'K0', '.3f')}, m2 "
        f"{rngp('cruise', 'speed', 'second', 'm2', '.3g')} s², m3 "
        f"{rngp('cruise', 'speed', 'second', 'm3', '.3g')} s, Td "
        f"{rngp('cruise', 'speed', 'second', 'Td', '.2f')} s (poles at "
        f"{_rng(slow, '.2f')} and {_rng(fast, '.2f')} rad/s); proposed K0 "
        f"{rngp('cruise', 'speed', 'proposed', 'K0')}"
        f" with K {rngp('cruise', 'speed', 'proposed', 'K')} (DC gain "
        f"{dc('cruise', 'speed', 'proposed')}). Acceleration objective: first-order T "
        f"{rngp('cruise', 'acceleration', 'first', 'Td', '.2f')} s; second order m2 "
        f"{rngp('cruise', 'acceleration', 'second', 'm2')}, m3 "
        f"{rngp('cruise', 'acceleration', 'second', 'm3')}, Td "
        f"{rngp('cruise', 'acceleration', 'second', 'Td', '.2f')} s, **DC gain "
        f"{dc('cruise', 'acceleration', 'second')}** (proposed: "
        f"{dc('cruise', 'acceleration', 'proposed')}).",
        "",
    ]
    for rg, obj, met, what in (("cruise", "acceleration", "a", "acceleration MSE (m/s²)²"),
                               ("cruise", "speed", "v", "speed MSE (m/s)²")):
        for which in ("cal", "val"):
            key = f"{which}_{rg}_{obj}_{met}"
            out += [f"Cruise, **{obj} objective**, "
                    f"{'calibration' if which == 'cal' else 'validation'}, {what}:", "",
                    _table_md(T[key], ".4g", "model"), ""]
    va = T["val_cruise_acceleration_v"]
    vs = T["val_cruise_speed_a"]
    out += [
        "Cross-scored (validation averages): fitted on acceleration, scored on speed "
        f"(m/s)²: first {_f(_avg(va, fo), '.3g')}, second {_f(_avg(va, so), '.3g')}, "
        f"proposed {_f(_avg(va, po), '.3g')}; fitted on speed, scored on acceleration "
        f"(m/s²)²: {_f(_avg(vs, fo), '.2g')}, {_f(_avg(vs, so), '.2g')}, "
        f"{_f(_avg(vs, po), '.2g')}.",
        "",
        "Launch, averages over the five vehicles (acceleration objective: acceleration MSE; "
        "speed objective: speed MSE):",
        "",
    ]
    lrows = []
    for lab in T["cal_launch_acceleration_a"]["index"]:
        lrows.append([lab, *[_f(_avg(T[f"{w}_launch_{o}_{m}"], lab), ".4g")
                             for o, m in (("acceleration", "a"), ("speed", "v"))
                             for w in ("cal", "val")]])  # fmt: skip
    out += [_md(["model", "acc. obj.: cal a-MSE", "val a-MSE", "speed obj.: cal v-MSE",
                 "val v-MSE"], lrows), ""]
    out.append(
        "Launch, speed objective, fitted parameters: first-order T "
        f"{rngp('launch', 'speed', 'first', 'Td', '.3g')} s (bound 0.01–10 s); second order "
        f"m2 {rngp('launch', 'speed', 'second', 'm2')}, m3 "
        f"{rngp('launch', 'speed', 'second', 'm3')}, Td "
        f"{rngp('launch', 'speed', 'second', 'Td')} s.")
    return "\n".join(out) + "\n"


def render_astazero(d: dict[str, Any]) -> str:
    """The AstaZero study's tables, spacing and amplification."""
    T = d["tables"]
    P = d["params"]
    out = [_settings(d, d["ga"])]
    up = []
    for pair in PAIRS:
        up.append([pair, *[" / ".join(_f(P["mixed"][m][pair][k], ".3g") for m in MODELS)
                           for k in ("Tg", "Gmin", "kg", "kv")],
                   _f(P["mixed"]["first"][pair]["Td"], ".2f")])  # fmt: skip
    out += ["Mixed objective, calibrated upper gains (first / second / proposed) and the "
            "first-order lag's Td:", "",
            _md(["pair", "Tg (s)", "Gmin (m)", "kg (s⁻²)", "kv (s⁻¹)", "first-order Td (s)"],
                up), ""]  # fmt: skip
    for met, what in (("a", "acceleration MSE (m/s²)²"), ("v", "speed MSE (m/s)²"),
                      ("x", "gap MSE m²")):
        c, v = T[f"cal_mixed_{met}"], T[f"val_mixed_{met}"]
        rows = []
        for lab in c["index"]:
            rows.append([lab, *[f"{_f(_cell(c, lab, p), '.3g')} / {_f(_cell(v, lab, p), '.3g')}"
                                for p in PAIRS],
                         _f(_avg(c, lab), ".4g"), _f(_avg(v, lab), ".4g")])  # fmt: skip
        out += [f"Mixed objective, {what}, calibration (platoon7) / validation (platoon8):", "",
                _md(["model", *PAIRS, "Average cal", "Average val"], rows), ""]
    labs3 = T["cal_mixed_a"]["index"]
    rel = []
    for met, nm in (("a", "acceleration"), ("v", "speed"), ("x", "gap")):
        for w in ("cal", "val"):
            t = T[f"{w}_mixed_{met}"]
            ch = [100 * (_avg(t, t2) / _avg(t, m) - 1)
                  for m, t2 in zip(labs3[:3], labs3[3:6], strict=True)]  # fmt: skip
            rel.append(f"{nm} {'calibration' if w == 'cal' else 'validation'} "
                       f"{_rng(ch, '+.0f', ' … ')} %")
    tp = T["params_mixed"]
    dcs = [row[tp["columns"].index(m)] for m in ("second", "proposed")
           for i, row in zip(tp["index"], tp["data"], strict=True)
           if i.endswith("/DC gain")]  # fmt: skip
    out += ["Table II lower levels with the upper gains refitted, against the calibrated "
            "model of the same name (mixed objective, averages over the pairs): "
            + "; ".join(rel) + ". DC gain of the calibrated second-order and proposed "
            f"lower levels: {_rng(dcs, '.2f')}.", ""]
    ca, va = T["cal_acceleration_a"], T["val_acceleration_a"]
    cx, vx = T["cal_acceleration_x"], T["val_acceleration_x"]
    pa = P["acceleration"]
    labs = ca["index"]
    rows = [[lab, _f(_avg(ca, lab), ".4g"), _f(_avg(va, lab), ".4g"), _f(_avg(cx, lab), ".4g"),
             _f(_avg(vx, lab), ".4g")] for lab in labs]
    out += ["Acceleration objective (the paper's Eq. 6), averages over the pairs:", "",
            _md(["model", "cal a-MSE", "val a-MSE", "cal gap MSE", "val gap MSE"], rows), "",
            f"Acceleration objective, calibrated spacing: Tg "
            f"{_rng([p['Tg'] for e in pa.values() for p in e.values()], '.2f')} s, Gmin "
            f"{_rng([p['Gmin'] for e in pa.values() for p in e.values()], '.1f')} m "
            "(mixed objective: Tg "
            f"{_rng([p['Tg'] for e in P['mixed'].values() for p in e.values()], '.2f')} s, Gmin "
            f"{_rng([p['Gmin'] for e in P['mixed'].values() for p in e.values()], '.1f')} m).",
            ""]  # fmt: skip
    arows = [[x["run"], _f(x["measured"], ".2f"),
              *[_f(x["simulated"][m], ".2f") for m in MODELS]] for x in d["amplification"]]
    meas = [x["measured"] for x in d["amplification"]]
    sims = [s for x in d["amplification"] for s in x["simulated"].values()]
    under = sum(all(s < x["measured"] for s in x["simulated"].values())
                for x in d["amplification"])  # fmt: skip
    out += ["Oscillation amplification per car: std of the follower's 20 s high-passed speed "
            "over its predecessor's (20 s edges left out), measured and replayed by the "
            "mixed-objective fits behind the measured predecessor:", "",
            _md(["run", "measured", "first", "second", "proposed"], arows), "",
            f"Measured {_rng(meas, '.2f')}, simulated {_rng(sims, '.2f')}; all three models "
            f"below the measurement for {under} of {len(meas)} cars."]  # fmt: skip
    return "\n".join(out) + "\n"


def render_budget(d: dict[str, Any], parts: dict[str, dict[str, Any]]) -> str:
    """Reduced against full GA budget: the average MSE of each calibrated model."""
    ga = d["ga"]
    rows = []
    worst = {"cal": 0.0, "val": 0.0}
    for study in ("carma", "astazero"):
        if study not in parts:
            continue
        for key, full in d[study].items():
            red = parts[study]["tables"].get(key)
            if red is None or key.endswith(("_acceleration_v", "_speed_a")):
                continue  # CARMA cross-scored metrics: not what the GA minimised
            which = key.split("_")[0]
            cells = []
            for lab in full["index"][: len(MODELS)]:  # the calibrated models, not Table II
                r, f = _avg(red, lab), _avg(full, lab)
                if r is None or f is None:
                    continue
                ch = f / r - 1
                worst[which] = max(worst[which], abs(ch))
                cells.append(f"{_f(r, '.4g')} → {_f(f, '.4g')} ({100 * ch:+.1f} %)")
            rows.append([f"{study} {key}", *cells])
    st = (f"seed {d['seed']}, full budget: GA {ga['max_generations']} generations (stall "
          f"{ga['stall_generations']}), {ga['starts']} starts, threads {d['threads'] or 'all'}")
    if not rows:
        return _not_run("carma/astazero (needed to compare the budget)")
    return "\n".join([
        f"*{st[:1].upper()}{st[1:]}.*\n",
        "Average MSE of each calibrated model, the studies' reduced GA budget → the full "
        "budget (CARMA cruise, each objective's own metric; AstaZero mixed objective; "
        "`cal`/`val`: calibration/validation; metric `a` acceleration, `v` speed, `x` gap):",
        "",
        _md(["table", "first", "second", "proposed"], rows),
        "",
        f"Largest change: calibration averages {100 * worst['cal']:.1f} %, validation "
        f"averages {100 * worst['val']:.1f} %.",
    ]) + "\n"


def render_summary(parts: dict[str, dict[str, Any]]) -> str:
    """Short generated sentences with the headline numbers of the findings page."""
    s = []
    if "carma" in parts:
        T = parts["carma"]["tables"]
        lab = T["val_cruise_acceleration_a"]["index"]
        va = T["val_cruise_acceleration_a"]
        vv = T["val_cruise_speed_v"]
        xa = T["val_cruise_acceleration_v"]
        sa = T["val_cruise_speed_a"]
        ca_ = T["cal_cruise_speed_a"]
        fo, so, po = lab[:3]
        t2 = [x for x in lab if x.startswith("Table II")]
        rel = [abs(_avg(T[f"{w}_cruise_{o}_{m}"], po) / _avg(T[f"{w}_cruise_{o}_{m}"], so) - 1)
               for w in ("cal", "val") for o, m in (("acceleration", "a"), ("speed", "v"))]
        s += [
            "* **CARMA cruise** (validation averages): acceleration objective, acceleration "
            f"MSE first / second / proposed {_f(_avg(va, fo), '.2g')} / "
            f"{_f(_avg(va, so), '.2g')} / {_f(_avg(va, po), '.2g')} (m/s²)²; speed objective, "
            f"speed MSE {_f(_avg(vv, fo), '.3g')} / {_f(_avg(vv, so), '.3g')} / "
            f"{_f(_avg(vv, po), '.3g')} (m/s)². The proposed model is within "
            f"{100 * max(rel):.1f} % of the second order (cal and val, both objectives). The "
            "second order beats the first-order lag by "
            f"{100 * (1 - _avg(vv, so) / _avg(vv, fo)):.0f} % in speed (speed objective) and "
            f"{100 * (1 - _avg(va, so) / _avg(va, fo)):.0f} % in acceleration (acceleration "
            "objective).",
            "* **Table II as published**, cruise validation: speed MSE "
            + " / ".join(_f(_avg(vv, x), ".3g") for x in t2) + " (m/s)², acceleration MSE "
            + " / ".join(_f(_avg(va, x), ".3g") for x in t2) + " (m/s²)² (first / second / "
            f"proposed); the refitted first-order lag is {_avg(vv, t2[0]) / _avg(vv, fo):.0f}× "
            f"better in speed and {_avg(va, t2[0]) / _avg(va, fo):.0f}× in acceleration than "
            "Table II's.",
            "* **Acceleration-only objective** (Eq. 6): second-order validation speed MSE "
            f"{_f(_avg(xa, so), '.3g')} (m/s)², {_avg(xa, so) / _avg(vv, so):.0f}× the speed "
            f"fit's {_f(_avg(vv, so), '.3g')}; in validation the speed fit scores "
            f"{_f(_avg(sa, so), '.2g')} (m/s²)² in acceleration against the acceleration fit's "
            f"{_f(_avg(va, so), '.2g')} (calibration: {_f(_avg(ca_, so), '.2g')} against "
            f"{_f(_avg(T['cal_cruise_acceleration_a'], so), '.2g')}).",
        ]
    if "firstlook" in parts:
        fl = parts["firstlook"]
        dcs = [e["dc_gain"] for e in fl["table_ii"].values()]
        ratio = [x["T_down"] / x["T_up"] for x in fl["asymmetric_cruise"]]
        s.append("* **First look**: Table II DC gains " + " / ".join(f"{x:.2f}" for x in dcs)
                 + " (first / second / proposed); cruise asymmetric lag T_down / T_up "
                 f"{_rng(ratio, '.2f')}.")
    if "astazero" in parts:
        a = parts["astazero"]
        T = a["tables"]
        spread = []
        for met in ("a", "v", "x"):
            for w in ("cal", "val"):
                t = T[f"{w}_mixed_{met}"]
                vals = [_avg(t, lab) for lab in t["index"][:3]]
                spread.append(max(vals) / min(vals) - 1)
        gx = [_avg(T["cal_acceleration_x"], lab) for lab in T["cal_acceleration_x"]["index"]]
        mx = [_avg(T["cal_mixed_x"], lab) for lab in T["cal_mixed_x"]["index"][:3]]
        meas = [x["measured"] for x in a["amplification"]]
        sims = [v for x in a["amplification"] for v in x["simulated"].values()]
        s += [
            f"* **AstaZero** (mixed objective): the three calibrated lower-level models are "
            f"within {100 * max(spread):.0f} % of each other on every average; the acceleration "
            f"objective's calibration gap MSE is {_rng(gx, '.3g')} m² against "
            f"{_rng(mx, '.3g')} m² with speed and gap terms; measured amplification per car "
            f"{_rng(meas, '.2f')}, replayed by the calibrated models {_rng(sims, '.2f')}.",
        ]
    if "closed" in parts:
        neg = [x["gain_neg"] for x in parts["closed"]["pairs"]]
        corr = [abs(x["grade_corr"]) for x in parts["closed"]["pairs"]]
        s.append(f"* **AstaZero first look**: braking gain {_rng(neg, '.2f')} (above 1 in "
                 f"{sum(g > 1 for g in neg)} of {len(neg)} pairs); closed-loop residual "
                 f"against −g·grade |corr| ≤ {max(corr):.2f}.")
    if not s:
        return _not_run("carma, astazero, firstlook, closed")
    return "*Headline numbers of the parts run; settings in each part's fragment.*\n" + \
        "\n" + "\n".join(s) + "\n"



RENDER: dict[str, Callable[[dict[str, Any]], str]] = {
    "loaders": render_loaders, "grade": render_grade, "firstlook": render_firstlook,
    "closed": render_closed, "carma": render_carma, "astazero": render_astazero}
#: Fragments: every part and the summary.
FRAGMENTS = (*PARTS, "summary")


def part(name: str, data: Path, *, seed: int = 0, threads: int = 1,
         out: Path = OUT) -> dict[str, Any]:
    """The numbers of part ``name`` as strict JSON: ``out/<name>.json`` when an earlier
    run left it there, computed (and kept there) otherwise."""
    f = Path(out) / f"{name}.json"
    if not f.exists():
        if not Path(data).is_dir():
            raise ValueError(f"data: the field data are not at {data}")
        _atomic.write_json(f, _atomic.json_safe(COMPUTE[name](Path(data), seed=seed,
                                                              threads=threads)))
    return dict(json.loads(f.read_text(encoding="utf-8")))


def generate(name: str, data: Path = DATA) -> Generated:
    """The fragment ``fielddata_<name>`` (its body and, for a part, its numbers)."""
    if name == "summary":
        return Generated(render_summary({p: part(p, data) for p in
                                         ("carma", "firstlook", "astazero", "closed")}))
    if name == "budget":
        studies = {p: part(p, data) for p in ("carma", "astazero")}
        d = part("budget", data)
        return Generated(render_budget(d, studies), d)
    d = part(name, data)
    return Generated(RENDER[name](d), d)


def main(argv: Sequence[str] | None = None) -> int:
    """Computes the parts (``--parts``) into ``--out`` and prints each fragment."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--parts", default=",".join(PARTS))
    a = ap.parse_args(argv)
    for p in [p for p in a.parts.split(",") if p]:
        if p not in COMPUTE:
            raise SystemExit(f"--parts: unknown {p!r}; known: {', '.join(PARTS)}")
        part(p, Path(a.data), seed=a.seed, threads=a.threads, out=Path(a.out))
    return 0
