"""Calibration studies on the measured field data.

Two studies, each returning a :class:`Study` (pandas tables, matplotlib figures, a
JSON-able summary and a plain-text report):

* :func:`carma_study` — FHWA CARMA platoon files (``--format carma``): each
  vehicle's lower-level controller, speed command -> speed, identified with the
  paper's three models (open loop, ``init="steady"`` because every stretch is cut
  out of a longer drive). **Launch and cruise are separate problems**: a stretch
  that starts from standstill is a *launch* up to the hand-over to the cruise
  logic (the first command >= :data:`HANDOVER_SPEED`; the cruise logic's first
  command is 20.11 m/s = 45 mph in every cruise stretch of the four files); the
  rest is *cruise*. In launch the logged command is the current measured speed
  (docs/guide/field-data.md § CARMA), so a launch fit identifies the logging, not a
  controller;
  cruise is the controller's regime and gets the main tables. Split: calibration on
  ``data5`` + ``data9``, validation on ``data6`` + ``data10`` (the two short and
  the two long drives each contribute one calibration and one validation file).
* :func:`astazero_study` — JRC OpenACC AstaZero platoon files
  (``--format openacc-astazero``): each follower calibrated in closed loop (the
  constant-time-gap upper law's kg, kv, Tg, Gmin free together with the lower
  level) behind its measured predecessor; calibration on the first platoon file,
  validation on the second (the same five cars in the same order, checked against
  ``Labels.csv``).

Two objectives in each study, both with :func:`avll.calibrate`'s weights
``(wa, wv, wx)`` on the mean squared acceleration, speed and position errors:
``"acceleration"`` = (1, 0, 0), the paper's Eq. 6, and a second one (CARMA:
``"speed"`` = (0, 1, 0); AstaZero: ``"mixed"``, the closed-loop weighting
:data:`avll.defaults.CLOSED_LOOP_WEIGHTS`, see :data:`ASTAZERO_OBJECTIVES`). The
paper's Table II models serve as the baseline (CARMA: as they are; AstaZero: with
the upper-level gains refitted, since the paper gives none for these cars).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..calibration import CalibrationResult, calibrate_many
from ..data import Run
from ..defaults import CLOSED_LOOP_WEIGHTS, EQ6_WEIGHTS, UPPER_PLACEHOLDER
from ..defaults import UPPER_NAMES as _UPPER
from ..models import LowerLevelModel, UpperLevel, model_class
from ..paper import MODEL_LABELS
from ..paper import MODELS as _MODELS
from ..report import finite_or_none as _finite
from ..rollout import batch_cost, closed_loop, simulate_full

__all__ = ["Study", "HANDOVER_SPEED", "CARMA_OBJECTIVES", "ASTAZERO_OBJECTIVES",
           "CARMA_CAL_FILES", "CARMA_BOUNDS", "read_carma", "split_launch_cruise",
           "read_astazero_pairs", "carma_study", "astazero_study"]

#: First command of the CARMA cruise logic is 20.11 m/s; a launch ends at the first
#: command at or above this speed (m/s).
HANDOVER_SPEED = 20.05

#: Objectives of the CARMA study: name -> (wa, wv, wx).
CARMA_OBJECTIVES: dict[str, tuple[float, float, float]] = {
    "acceleration": EQ6_WEIGHTS,
    "speed": (0.0, 1.0, 0.0),
}

#: Objectives of the AstaZero study: name -> (wa, wv, wx). ``Accel`` in these files
#: is the forward difference of the Doppler speed (noise x 1/dt, half a sample
#: ahead), so ``"mixed"`` weighs the measured speed and position (i.e. the gap, the
#: leader being measured) too: :data:`avll.defaults.CLOSED_LOOP_WEIGHTS`.
ASTAZERO_OBJECTIVES: dict[str, tuple[float, float, float]] = {
    "acceleration": EQ6_WEIGHTS,
    "mixed": CLOSED_LOOP_WEIGHTS,
}

#: Search boxes that differ from :data:`avll.calibration.DEFAULT_BOUNDS` in the CARMA
#: study: the first-order lag's time constant reaches the default 3 s bound in cruise
#: (the speed loop is slow: T = 3.5–4.5 s), so its box is widened to 10 s.
CARMA_BOUNDS: dict[str, dict[str, tuple[float, float]]] = {"first": {"Td": (0.01, 10.0)}}

#: CARMA files whose stretches calibrate (the others validate).
CARMA_CAL_FILES: tuple[str, ...] = ("data5", "data9")

#: Table row names of the models ("First-order lag", ...: the paper's short labels).
_LABEL = {m: lab.capitalize() for m, lab in MODEL_LABELS.items()}


@dataclass
class Study:
    """Result of a field-data study.

    ``tables`` are pandas DataFrames by name, ``figures`` matplotlib Figures by
    name, ``summary`` is JSON-able: ``{"models": {name: {"params", "cal_mse",
    "val_mse", "per_run_mse"}}, "vehicles": {vehicle: {"models": {...}}}, ...}``
    (the ``avll calibrate`` contract; top-level ``params`` are per vehicle),
    ``text`` a plain-text report of the tables, ``seconds`` the wall time and
    ``runs`` the runs used (CARMA: ``"launch"``, ``"cruise"``; AstaZero: ``"pairs"``).
    """

    name: str
    tables: dict[str, Any]
    figures: dict[str, Any]
    summary: dict[str, Any]
    text: str
    seconds: float = 0.0
    runs: dict[str, list[Run]] = field(default_factory=dict)

    def save(self, out: str | Path) -> list[Path]:
        """Writes tables (CSV), figures (PNG), ``summary.json`` and ``report.txt``
        into ``out`` as one unit (built in a hidden temporary folder inside it, committed with a
        ``MANIFEST.json`` written last, see :mod:`avll._atomic`); returns the paths
        written."""
        from .. import _atomic

        d = Path(out)
        names: list[str] = []
        with _atomic.output_dir(d, meta={"command": f"avll field study {self.name}"}) as st:
            for k, t in self.tables.items():
                names.append(f"{self.name}_{k}.csv")
                _atomic.to_csv(t, st / names[-1], float_format="%.6g")
            for k, f in self.figures.items():
                names.append(f"{self.name}_{k}.png")
                _atomic.savefig(f, st / names[-1], dpi=80)
            names.append(f"{self.name}_summary.json")
            _atomic.write_json(st / names[-1], self.summary)
            names.append(f"{self.name}_report.txt")
            _atomic.write_text(st / names[-1], self.text + "\n")
        return [d / n for n in names]


# ---------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------


def read_carma(path: str | Path, **options: Any) -> list[Run]:
    """CARMA runs of one file or of every ``*.csv`` in a folder (in natural order of
    the names: data5, data6, data9, data10)."""
    from ..io import read_runs

    return read_runs(path, format="carma", **options)


def _num(stem: str) -> int:
    m = re.search(r"(\d+)$", stem)
    return int(m.group(1)) if m else -1


def split_launch_cruise(
    runs: Sequence[Run], *, handover: float = HANDOVER_SPEED, min_duration: float = 10.0
) -> tuple[list[Run], list[Run]]:
    """Splits CARMA stretches into launches and cruises.

    A stretch starting below 2 m/s is a launch up to (excluding) the first sample
    whose command is at least ``handover``; what follows (if at least
    ``min_duration`` long) is a cruise, with ids ``<id>/launch`` and ``<id>/cruise``
    and the cut recorded in ``meta["cleaning"]``. Stretches starting above 2 m/s
    are cruises as they are. Launch pieces shorter than 2 s are dropped.
    """
    launch: list[Run] = []
    cruise: list[Run] = []
    for r in runs:
        if r.command is None or r.v is None:
            raise ValueError(f"run {r.run_id!r}: a CARMA stretch needs command and speed")
        if r.v[0] >= 2.0:
            cruise.append(r)
            continue
        hit = np.flatnonzero(r.command >= handover)
        k = int(hit[0]) if hit.size else len(r)
        if len(r) - k < round(min_duration / r.dt):
            launch.append(r)
            continue
        note = (f"split at t={r.t[k]:.1f} s (row {k}), the first command >= {handover} m/s: "
                "launch before, cruise from there")  # fmt: skip
        if k * r.dt >= 2.0:
            launch.append(r.cut(0, k, "/launch", note))
        cruise.append(r.cut(k, len(r), "/cruise", note))
    return launch, cruise


def read_astazero_pairs(path: str | Path, **options: Any) -> list[Run]:
    """The predecessor→follower pairs of the AstaZero platoon files in ``path``
    (a file or a folder; free-flow files are left out), each with a placeholder
    upper law so that it can run in closed loop with every gain free."""
    from ..io import read_runs

    runs = read_runs(path, format="openacc-astazero", command_kind="acceleration", **options)
    return [replace(r, upper=r.upper or UPPER_PLACEHOLDER) for r in runs]


# ---------------------------------------------------------------------------
# Fitting helpers
# ---------------------------------------------------------------------------


def _mse(model: str, x: np.ndarray, runs: Sequence[Run], weights: tuple[float, float, float],
         *, init: str, closed: bool, free: Sequence[int], threads: int) -> dict[str, float]:
    if not runs:
        return {}
    p = np.asarray(x, dtype=np.float64)[None, :]
    c = batch_cost(model, p, runs, weights=weights, init=init, closed_loop=closed,
                   upper_free=list(free), threads=threads)[0]  # fmt: skip
    return {r.run_id: float(v) for r, v in zip(runs, c, strict=True)}


_METRICS = {"a": (1.0, 0.0, 0.0), "v": (0.0, 1.0, 0.0), "x": (0.0, 0.0, 1.0)}


@dataclass
class _Fit:
    params: dict[str, float]
    x: np.ndarray
    cost: float
    cal: dict[str, dict[str, float]]  # metric -> run -> mse
    val: dict[str, dict[str, float]]
    cal_obj: dict[str, float]
    val_obj: dict[str, float]
    interrupted: bool = False
    at_bound: tuple[str, ...] = ()
    generations: int = 0
    stop: str = ""


def _fit_groups(model: str, groups: Mapping[str, tuple[list[Run], list[Run]]], *,
                weights: tuple[float, float, float], init: str, closed: bool,
                metrics: Sequence[str], seed: int, threads: int,
                progress: bool | Callable[[dict[str, Any]], Any],
                fixed: LowerLevelModel | None = None, fit: bool = True,
                bounds: Mapping[str, Any] | None = None, **ga: Any) -> dict[str, _Fit]:
    """Calibrates ``model`` per group (one GA problem per group, all in one parallel
    call) on the group's calibration runs and evaluates it on both sets. ``fixed``
    fixes the lower level (only the upper gains are free); ``fit=False`` evaluates
    ``fixed`` as it is (open loop)."""
    free = list(range(4)) if closed else []
    names = list(groups)
    out: dict[str, _Fit] = {}
    xs: dict[str, tuple[np.ndarray, CalibrationResult | None]]
    if fit:
        pool = list({r.run_id: r for g in names for r in groups[g][0]}.values())
        subsets = [[r.run_id for r in groups[g][0]] for g in names]
        if fixed is not None:
            bounds = {k: (v, v) for k, v in fixed.to_dict().items()}
        res = calibrate_many(model, pool, subsets, seed=seed, threads=threads, progress=progress,
                             bounds=bounds, closed_loop=closed, upper_free=free,
                             weights=weights, init=init, **ga)  # fmt: skip
        xs = {g: (np.array(list(c.params.values())), c) for g, c in zip(names, res, strict=True)}
    else:
        assert fixed is not None
        xs = {g: (fixed.to_array(), None) for g in names}
    for g in names:
        x, cr = xs[g]
        cal, val = groups[g]
        kw: dict[str, Any] = dict(init=init, closed=closed, free=free, threads=threads)
        cal_m = {m: _mse(model, x, cal, _METRICS[m], **kw) for m in metrics}
        val_m = {m: _mse(model, x, val, _METRICS[m], **kw) for m in metrics}
        cal_o = _mse(model, x, cal, weights, **kw)
        val_o = _mse(model, x, val, weights, **kw)
        cls = model_class(model)
        n = len(cls.param_names())
        params = {**cls.from_array(x[:n]).to_dict(),
                  **{_UPPER[i]: float(x[n + j]) for j, i in enumerate(free)}}  # fmt: skip
        state = ((bool(cr.interrupted), tuple(cr.at_bound), int(cr.generations), str(cr.stop))
                 if cr is not None else (False, (), 0, "not fitted"))
        out[g] = _Fit(params, x, float(np.mean(list(cal_o.values()))), cal_m, val_m, cal_o, val_o,
                      *state)
    return out


def _model(name: str, params: Mapping[str, float]) -> LowerLevelModel:
    cls = model_class(name)
    return cls(**{k: params[k] for k in cls.param_names()})


def _mean(d: Mapping[str, float]) -> float:
    return float(np.mean(list(d.values()))) if d else float("nan")


def _contract(fits: Mapping[str, _Fit]) -> dict[str, Any]:
    """``{"params", "cal_mse", "val_mse", "per_run_mse"}`` of one model over groups:
    the per-group entries and the average over groups."""
    per_group: dict[str, dict[str, Any]] = {
        g: {"params": f.params, "cal_mse": _finite(f.cost),
            "val_mse": _finite(_mean(f.val_obj)) if f.val_obj else None,
            "per_run_mse": {k: _finite(v) for k, v in {**f.cal_obj, **f.val_obj}.items()},
            "at_bound": list(f.at_bound), "generations": f.generations, "stop": f.stop,
            "interrupted": f.interrupted}
        for g, f in fits.items()}
    cal = [f.cost for f in fits.values()]
    val = [_mean(f.val_obj) for f in fits.values() if f.val_obj]
    return {
        "params": {g: f.params for g, f in fits.items()},
        "cal_mse": _finite(float(np.mean(cal))),
        "val_mse": _finite(float(np.mean(val))) if val else None,
        "per_run_mse": {k: v for e in per_group.values() for k, v in e["per_run_mse"].items()},
        "interrupted": any(f.interrupted for f in fits.values()),
        "groups": per_group,
    }


def _mse_tables(fits: Mapping[str, Mapping[str, _Fit]], metric: str, which: str) -> Any:
    """Tables III/IV style: rows the models, columns the groups (vehicles) and the
    average; each cell the mean over the group's runs of the per-run MSE."""
    import pandas as pd

    rows = {}
    for label, per in fits.items():
        d = {g: _mean((f.cal if which == "cal" else f.val)[metric]) for g, f in per.items()}
        d["Average"] = float(np.nanmean([v for v in d.values()])) if d else float("nan")
        rows[label] = d
    return pd.DataFrame(rows).T


def _params_table(fits: Mapping[str, Mapping[str, _Fit]]) -> Any:
    """Table II style: rows (group, parameter), columns the models."""
    import pandas as pd

    cols: dict[str, dict[tuple[str, str], float]] = {}
    for m, per in fits.items():
        cols[m] = {(g, k): v for g, f in per.items() for k, v in f.params.items()}
        for g, f in per.items():
            mod = _model(m, f.params)
            cols[m][(g, "DC gain")] = float(mod.dc_gain)
    df = pd.DataFrame(cols)
    df.index = pd.MultiIndex.from_tuples(df.index, names=["vehicle", "parameter"])
    return df


def _fmt(df: Any) -> str:
    import pandas as pd

    with pd.option_context("display.width", 200, "display.max_columns", 50,
                           "display.max_rows", 500):  # fmt: skip
        return str(df.to_string(float_format=lambda v: f"{v:.4f}", na_rep="-"))


_UNIT = {"a": "acceleration MSE (m/s^2)^2", "v": "speed MSE (m/s)^2",
         "x": "position (= gap) MSE m^2"}


def _fit_models(models: Sequence[str], groups: Mapping[str, tuple[list[Run], list[Run]]],
                seed: int, bounds: Mapping[str, Any] | None = None,
                **kw: Any) -> tuple[dict[str, dict[str, _Fit]], bool]:
    """:func:`_fit_groups` of each model (seeds ``seed + 1000 k``, the model's box of
    ``bounds``), stopping after an interrupted one; and whether one was."""
    fits: dict[str, dict[str, _Fit]] = {}
    for k, m in enumerate(models):
        fits[m] = _fit_groups(m, groups, seed=seed + 1000 * k,
                              bounds=(bounds or {}).get(m), **kw)  # fmt: skip
        if any(f.interrupted for f in fits[m].values()):
            return fits, True
    return fits, False


def _tables(key: str, title: str, what: str, fits: Mapping[str, Mapping[str, _Fit]],
            base: Mapping[str, Mapping[str, _Fit]], metrics: Sequence[str],
            tables: dict[str, Any], text: list[str]) -> None:
    """One objective's tables into ``tables`` and ``text``: the fitted parameters per
    ``what`` (Table II style), the MSEs of the fitted models and of the baselines
    ``base`` (Tables III/IV style)."""
    tables[f"params_{key}"] = _params_table(fits)
    labelled = {_LABEL[m]: f for m, f in fits.items()} | dict(base)
    text += [title, f"Calibrated parameters per {what} (cf. Table II)",
             _fmt(tables[f"params_{key}"])]  # fmt: skip
    for metric in metrics:
        for which, nm in (("cal", "Calibration"), ("val", "Validation")):
            t = tables[f"{which}_{key}_{metric}"] = _mse_tables(labelled, metric, which)
            text += ["", f"{nm} {_UNIT[metric]} per {what} (cf. Table "
                     f"{'III' if which == 'cal' else 'IV'})", _fmt(t)]  # fmt: skip
    text.append("")


# ---------------------------------------------------------------------------
# CARMA
# ---------------------------------------------------------------------------


def _file_of(r: Run) -> str:
    return str(r.run_id).split("/")[0]


def _vehicle_of(r: Run) -> str:
    return str(r.meta.get("vehicle", str(r.run_id).split("/")[1]))


def carma_study(
    path: str | Path,
    *,
    seed: int = 0,
    progress: bool | Callable[[dict[str, Any]], Any] = False,
    threads: int = 0,
    out: str | Path | None = None,
    cal_files: Sequence[str] = CARMA_CAL_FILES,
    regimes: Sequence[str] = ("cruise", "launch"),
    objectives: Sequence[str] = tuple(CARMA_OBJECTIVES),
    models: Sequence[str] = _MODELS,
    max_generations: int = 60,
    stall_generations: int = 12,
    starts: int = 1,
    figures: bool = True,
) -> Study:
    """Identifies each CARMA vehicle's lower-level controller (speed command ->
    speed) with the paper's models, per regime (``"cruise"``, ``"launch"``, see
    :func:`split_launch_cruise`) and objective (:data:`CARMA_OBJECTIVES`):
    calibration on the stretches of ``cal_files``, validation on the others,
    ``init="steady"``. The GA budget (``max_generations``, ``stall_generations``,
    ``starts``) is reduced from :func:`avll.calibrate`'s defaults to keep the whole
    study near a minute on two cores. Tables: ``params_<regime>_<objective>``
    (Table II style, per vehicle), ``cal_<regime>_<objective>_<metric>`` and
    ``val_...`` (Tables III/IV style: rows the models plus the paper's Table II
    models, columns the vehicles and the average; metric ``a`` acceleration MSE
    (m/s²)², ``v`` speed MSE (m/s)²). ``summary["models"]`` is the
    ``avll calibrate`` JSON contract for cruise + acceleration objective, per
    vehicle params; ``summary["studies"][regime][objective]`` the same for every
    combination. ``out`` saves everything there (:meth:`Study.save`).
    """
    from .. import PAPER_TABLE_II
    from .._limits import check_seed, check_threads

    seed, threads = check_seed(seed), check_threads(threads)
    t0 = time.perf_counter()
    for o in objectives:
        if o not in CARMA_OBJECTIVES:
            raise ValueError(f"objectives: unknown {o!r}; known: {', '.join(CARMA_OBJECTIVES)}")
    for rg in regimes:
        if rg not in ("cruise", "launch"):
            raise ValueError(f"regimes: unknown {rg!r}; known: cruise, launch")
    for m in models:
        model_class(m)
    runs = read_carma(path)
    launch, cruise = split_launch_cruise(runs)
    by_regime = {"launch": launch, "cruise": cruise}
    cal_set = {str(f) for f in cal_files}
    files = sorted({_file_of(r) for r in runs}, key=lambda s: (_num(s), s))
    if not cal_set & set(files):
        raise ValueError(f"cal_files: none of {sorted(cal_set)} in the data ({', '.join(files)})")
    vehicles = list(dict.fromkeys(_vehicle_of(r) for r in runs))
    ga: dict[str, Any] = dict(max_generations=max_generations,
                              stall_generations=stall_generations, starts=starts)
    tables: dict[str, Any] = {}
    figs: dict[str, Any] = {}
    studies: dict[str, Any] = {}
    text: list[str] = []
    interrupted = False
    for rg in regimes:
        if interrupted:
            break
        groups = {}
        for v in vehicles:
            cal = [r for r in by_regime[rg] if _vehicle_of(r) == v and _file_of(r) in cal_set]
            val = [r for r in by_regime[rg] if _vehicle_of(r) == v and _file_of(r) not in cal_set]
            if cal:
                groups[v] = (cal, val)
        if not groups:
            continue
        studies[rg] = {}
        for obj in objectives:
            if interrupted:
                break
            w = CARMA_OBJECTIVES[obj]
            kw: dict[str, Any] = dict(weights=w, init="steady", closed=False, metrics=("a", "v"),
                                      threads=threads)  # fmt: skip
            fits, interrupted = _fit_models(models, groups, seed, CARMA_BOUNDS,
                                            progress=progress, **kw, **ga)  # fmt: skip
            base = {f"Table II {m}": _fit_groups(m, groups, seed=seed, progress=False,
                                                 fixed=PAPER_TABLE_II[m], fit=False, **kw)
                    for m in models}  # fmt: skip
            key = f"{rg}_{obj}"
            _tables(key, f"== CARMA {rg}, objective {obj} (wa, wv, wx) = {w} ==", "vehicle",
                    fits, base, ("a", "v"), tables, text)
            studies[rg][obj] = {
                "weights": list(w),
                "models": {m: _contract(f) for m, f in fits.items()},
                "table_ii": {m: _contract(base[f"Table II {m}"]) for m in models},
                "cal_runs": {g: [r.run_id for r in c] for g, (c, _) in groups.items()},
                "val_runs": {g: [r.run_id for r in v] for g, (_, v) in groups.items()},
            }
            if figures:
                figs[key] = _figure(fits, groups, f"CARMA {rg}: measured vs simulated, "
                                    f"fitted on {obj}", rg)
    main = studies.get("cruise", studies.get(next(iter(studies), ""), {}))
    main = main.get("acceleration", next(iter(main.values()), {})) if main else {}
    summary = {
        "study": "carma", "interrupted": interrupted, "data": str(path),
        "split": {"cal_files": sorted(cal_set),
                  "val_files": [f for f in files if f not in cal_set]},
        "init": "steady", "handover_speed": HANDOVER_SPEED, "ga": ga, "seed": seed,
        "runs": {"launch": [r.run_id for r in launch], "cruise": [r.run_id for r in cruise]},
        "models": main.get("models", {}),
        "vehicles": {v: {"models": {m: e["groups"][v] for m, e in main.get("models", {}).items()
                                    if v in e["groups"]}} for v in vehicles},
        "studies": studies,
    }
    st = Study("carma", tables, figs, summary, "\n".join(text),
               time.perf_counter() - t0, {"launch": launch, "cruise": cruise})  # fmt: skip
    st.summary["seconds"] = round(st.seconds, 2)
    if out is not None:
        st.save(out)
    return st


# ---------------------------------------------------------------------------
# AstaZero
# ---------------------------------------------------------------------------


def _pair_of(r: Run) -> str:
    return str(r.run_id).split("/")[-1]


def astazero_study(
    path: str | Path,
    *,
    seed: int = 0,
    progress: bool | Callable[[dict[str, Any]], Any] = False,
    threads: int = 0,
    out: str | Path | None = None,
    cal_file: str | None = None,
    objectives: Sequence[str] = tuple(ASTAZERO_OBJECTIVES),
    models: Sequence[str] = _MODELS,
    baseline: bool = True,
    max_generations: int = 40,
    stall_generations: int = 10,
    starts: int = 1,
    figures: bool = True,
) -> Study:
    """Calibrates each AstaZero follower in closed loop (upper-level kg, kv, Tg,
    Gmin free with the lower-level model) behind its measured predecessor, per
    objective (:data:`ASTAZERO_OBJECTIVES`); calibration on ``cal_file`` (default:
    the first platoon file), validation of the same pair in the other file(s) (the
    study checks the pair's vehicle types agree in ``meta``). ``baseline`` adds the
    paper's Table II lower-level models with only the upper gains fitted. Tables
    as in :func:`carma_study` with the metrics ``a``, ``v`` and ``x`` (position,
    i.e. gap, MSE m²); groups are the pairs ``v1-v2``…``v4-v5``.
    """
    from .. import PAPER_TABLE_II
    from .._limits import check_seed, check_threads

    seed, threads = check_seed(seed), check_threads(threads)
    t0 = time.perf_counter()
    for o in objectives:
        if o not in ASTAZERO_OBJECTIVES:
            raise ValueError(f"objectives: unknown {o!r}; known: {', '.join(ASTAZERO_OBJECTIVES)}")
    for m in models:
        model_class(m)
    runs = read_astazero_pairs(path)
    stems = list(dict.fromkeys(_file_of(r) for r in runs))
    cal_stem = cal_file or stems[0]
    if cal_stem not in stems:
        raise ValueError(f"cal_file: {cal_stem!r} not in the data ({', '.join(stems)})")
    pairs = list(dict.fromkeys(_pair_of(r) for r in runs if _file_of(r) == cal_stem))
    groups: dict[str, tuple[list[Run], list[Run]]] = {}
    mismatched: list[str] = []
    for p in pairs:
        cal = [r for r in runs if _pair_of(r) == p and _file_of(r) == cal_stem]
        types = (cal[0].meta.get("type"), cal[0].meta.get("lead_type"))
        val = []
        for r in runs:
            if _pair_of(r) != p or _file_of(r) == cal_stem:
                continue
            if (r.meta.get("type"), r.meta.get("lead_type")) == types:
                val.append(r)
            else:
                mismatched.append(r.run_id)
        groups[p] = (cal, val)
    ga: dict[str, Any] = dict(max_generations=max_generations,
                              stall_generations=stall_generations, starts=starts)
    tables: dict[str, Any] = {}
    figs: dict[str, Any] = {}
    studies: dict[str, Any] = {}
    text: list[str] = []
    interrupted = False
    for obj in objectives:
        if interrupted:
            break
        w = ASTAZERO_OBJECTIVES[obj]
        kw: dict[str, Any] = dict(weights=w, init="rest", closed=True, metrics=("a", "v", "x"),
                                  threads=threads, **ga)  # fmt: skip
        fits, interrupted = _fit_models(models, groups, seed, progress=progress, **kw)
        base: dict[str, dict[str, _Fit]] = {}
        if baseline and not interrupted:
            for k, m in enumerate(models):
                base[f"Table II {m} (upper refitted)"] = _fit_groups(
                    m, groups, seed=seed + 1000 * k + 500, progress=False,
                    fixed=PAPER_TABLE_II[m], **kw)  # fmt: skip
        _tables(obj, f"== AstaZero closed loop, objective {obj} (wa, wv, wx) = {w} ==", "pair",
                fits, base, ("a", "v", "x"), tables, text)
        studies[obj] = {
            "weights": list(w), "models": {m: _contract(f) for m, f in fits.items()},
            "table_ii_upper_refitted": {m: _contract(base[f"Table II {m} (upper refitted)"])
                                        for m in models
                                        if f"Table II {m} (upper refitted)" in base}}
        if figures:
            figs[obj] = _figure(fits, groups, "AstaZero closed loop: measured vs simulated, "
                                f"fitted on {obj}")
    main = studies.get("mixed", next(iter(studies.values()), {}))
    summary = {
        "study": "openacc-astazero", "interrupted": interrupted, "data": str(path),
        "split": {"cal_file": cal_stem, "val_files": [s for s in stems if s != cal_stem],
                  "type_mismatch_excluded": mismatched},
        "closed_loop": True, "upper_free": list(_UPPER),
        "init": "rest (lower level), measured v0, x0", "ga": ga, "seed": seed,
        "models": main.get("models", {}),
        "vehicles": {p: {"models": {m: e["groups"][p] for m, e in main.get("models", {}).items()}}
                     for p in groups},
        "studies": studies,
    }
    st = Study("astazero", tables, figs, summary, "\n".join(text), time.perf_counter() - t0,
               {"pairs": runs})  # fmt: skip
    st.summary["seconds"] = round(st.seconds, 2)
    if out is not None:
        st.save(out)
    return st


def _figure(fits: Mapping[str, Mapping[str, _Fit]],
            groups: Mapping[str, tuple[list[Run], list[Run]]], title: str,
            carma_regime: str | None = None) -> Any:
    """Measured vs simulated on each group's first validation run (else its first
    calibration run): with ``carma_regime`` CARMA's speed loop driven by the command
    (a launch whole, a cruise's first 120 s), else AstaZero's closed loop behind the
    predecessor (100-300 s)."""
    from ..plotting import measured_vs_simulated

    rows = []
    for g, (cal, val) in groups.items():
        run = val[0] if val else cal[0]
        assert run.v is not None
        if carma_regime is not None:
            assert run.command is not None
            lo, hi = 0, (len(run) if carma_regime == "launch"
                         else min(len(run), round(120.0 / run.dt)))
            sims = {m: simulate_full(_model(m, per[g].params), run.command, run.dt,
                                     command_kind="speed", init="steady")
                    for m, per in fits.items() if g in per}  # fmt: skip
            t, ref = run.t[lo:hi] - run.t[0], ("command", run.command[lo:hi])
            right = {"ylabel": "accel. (m/s²)", "measured": run.a[lo:hi],
                     "simulated": {m: tr.a[lo:hi] for m, tr in sims.items()}}
        else:
            assert run.x is not None and run.lead_x is not None and run.lead_v is not None
            lo, hi = round(100 / run.dt), min(len(run), round(300 / run.dt))
            sims = {m: closed_loop(_model(m, per[g].params), run.lead_x, run.lead_v, run.dt,
                                   UpperLevel(*(per[g].params[k] for k in _UPPER)),
                                   v0=float(run.v[0]), x0=float(run.x[0]))
                    for m, per in fits.items()}  # fmt: skip
            t, ref = run.t[lo:hi], ("predecessor", run.lead_v[lo:hi])
            right = {"ylabel": "gap (m)", "measured": (run.lead_x - run.x)[lo:hi],
                     "simulated": {m: (run.lead_x - tr.x)[lo:hi] for m, tr in sims.items()}}
        rows.append({
            "name": g, "title": f"{run.run_id} ({'validation' if val else 'calibration'})",
            "t": t,
            "left": {"ylabel": "speed (m/s)", "measured": run.v[lo:hi], "reference": ref,
                     "simulated": {m: tr.v[lo:hi] for m, tr in sims.items()}},
            "right": right,
        })  # fmt: skip
    if carma_regime is not None:
        return measured_vs_simulated(rows, xlabel="time in run (s)", title=title)
    return measured_vs_simulated(rows, title=title)
