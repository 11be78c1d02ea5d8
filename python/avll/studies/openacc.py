"""OpenACC study: does a calibrated model predict how a real platoon amplifies
disturbances? (``avll study openacc``)

For every follower of every native OpenACC file (:mod:`avll.io.openacc_native`):

1. **Closed-loop calibration.** The constant-time-gap upper level (paper Eq. 3:
   ``kg``, ``kv``, ``Tg``, ``Gmin``) and each lower-level model (first-order lag,
   second-order, proposed) are calibrated together, driven by the measured
   predecessor (``lead_x``, ``lead_v``), all cars in one parallel call per model
   (:func:`avll.calibrate_many`, ``subsets="per_run"``). Objective: :data:`WEIGHTS`
   on the mean squared acceleration, speed and position errors (the AstaZero
   study's "mixed" objective: the acceleration is derived from the speed, so the
   measured speed and position, i.e. the gap, count too; 0.1 m/s², 0.1 m/s and 1 m
   weigh the same). Box: :data:`avll.calibrate.DEFAULT_BOUNDS` except ``Gmin``
   in ``[0, gmin_max]`` (10 m by default). Why: at the near-constant speed of the
   dynamic-platform files only ``Gmin + Tg v`` is identified, and the default
   ``[0, 30]`` m lets the search trade the time gap for standstill distances no
   commercial ACC uses (2–5 m bumper to bumper); the sensitivity to this choice is
   reported by running the study with ``gmin_max=30``.
2. **Setting order.** The calibrated ``Tg`` per car model and ACC setting
   (median over files); for every car model seen under two settings, each pair of
   settings is one check, held when the longer setting has the larger ``Tg``
   (:func:`setting_order`). Files in a folder named ``mixed`` are left out of the
   check (their header says one setting, their folder says the cars' settings
   were mixed); files without ACC are the human control. The same check is made
   on two identifiable quantities: the effective time gap of the calibrated law at
   the run's mean speed, ``Tg + Gmin / v̄``, and the measured time headway (median
   of gap / speed while faster than 3 m/s), which needs no model.
3. **Empirical string stability.** The measured amplification of the
   predecessor's speed oscillations: the ratio of the RMS of the follower's and of
   the predecessor's speed, both band-passed to :data:`DEFAULT_BAND` (0.02–0.2 Hz,
   periods of 5–50 s: the platoon's oscillations peak at 0.03–0.08 Hz in these
   files, and a 100 s record holds at least two periods of 50 s) by a zero-phase
   2nd-order Butterworth band-pass, with :data:`TRIM` seconds cut at each end
   (filter edges). Its confidence interval is a circular block bootstrap over time
   (:data:`N_BOOT` resamples of blocks of :data:`BLOCK` seconds, the follower and
   predecessor resampled together; percentile interval at 95 %). A predecessor
   whose band RMS is below :data:`MIN_EXCITATION` (0.05 m/s, the order of the GNSS
   speed noise) does not excite its follower: no measured amplification (the
   target cars of the dynamic-platform files drive at constant speed).
   Predicted, per lower-level model: (a) from ``|H(jω)|`` of the calibrated closed
   loop (the paper's Eq. 8 with the true delay ``e^{-jωTd}``, no Padé), as the
   RMS gain on the predecessor's measured band-passed spectrum:
   ``sqrt(Σ |H(jω_k)|² P(ω_k) / Σ P(ω_k))`` over the periodogram bins of the band
   (what the measured ratio would be if the car were that linear system driven by
   its predecessor); (b) from a time-domain replay: the calibrated closed loop
   behind the measured predecessor (:func:`avll.closed_loop`), its speed through
   the same band-pass and ratio. The error of a prediction is
   ``predicted / measured - 1``; the goal is within 10 %.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .. import _atomic
from ..calibration import calibrate_many
from ..data import Run
from ..defaults import UPPER_NAMES as _UPPER
from ..defaults import UPPER_PLACEHOLDER
from ..models import LowerLevelModel, UpperLevel, model_class
from ..paper import MODELS as _MODELS
from ..rollout import closed_loop
from ..stability import exact_delay_codes

__all__ = [
    "WEIGHTS",
    "DEFAULT_BAND",
    "TRIM",
    "BLOCK",
    "N_BOOT",
    "MIN_EXCITATION",
    "GMIN_MAX",
    "HEADWAY_MIN_SPEED",
    "OpenACCStudy",
    "openacc_study",
    "bandpass",
    "amplification",
    "bootstrap_ci",
    "transfer_gain",
    "predicted_amplification",
    "replay_amplification",
    "setting_order",
]

#: Objective weights (wa, wv, wx) of the closed-loop calibration.
WEIGHTS: tuple[float, float, float] = (1.0, 1.0, 0.01)
#: Band (Hz) of the amplification.
DEFAULT_BAND: tuple[float, float] = (0.02, 0.2)
#: Seconds cut at each end of the band-passed signals.
TRIM = 5.0
#: Block length (s) of the bootstrap over time.
BLOCK = 20.0
#: Bootstrap resamples.
N_BOOT = 2000
#: Smallest band RMS (m/s) of the predecessor's speed that counts as an excitation.
MIN_EXCITATION = 0.05
#: Upper bound (m) of the standstill distance Gmin in the calibration.
GMIN_MAX = 10.0
#: The measured time headway uses the samples faster than this (m/s).
HEADWAY_MIN_SPEED = 3.0
#: Placeholder upper law of the runs (every gain is calibrated).
_RANK = {"L": 0, "M": 1, "S": 2}


# ---------------------------------------------------------------------------
# Signal measures
# ---------------------------------------------------------------------------


def _check_band(band: Sequence[float], dt: float) -> tuple[float, float]:
    lo, hi = (float(b) for b in band)
    if not (0 < lo < hi < 0.5 / dt):
        raise ValueError(f"band: need 0 < low < high < {0.5 / dt:g} Hz, got ({lo:g}, {hi:g})")
    return lo, hi


def bandpass(x: np.ndarray, dt: float, band: Sequence[float] = DEFAULT_BAND,
             trim: float = TRIM) -> np.ndarray:
    """``x`` detrended (straight line), band-passed by a zero-phase 2nd-order
    Butterworth filter (forwards and backwards) and with ``trim`` seconds cut at
    each end."""
    from scipy import signal

    lo, hi = _check_band(band, dt)
    x = np.asarray(x, dtype=np.float64)
    k = int(round(trim / dt))
    if x.shape[0] <= 2 * k + 20:
        raise ValueError(f"record of {x.shape[0] * dt:g} s is too short for trim {trim:g} s")
    sos = signal.butter(2, [lo * 2 * dt, hi * 2 * dt], btype="bandpass", output="sos")
    y = signal.sosfiltfilt(sos, signal.detrend(x))
    return y[k:x.shape[0] - k] if k else y


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def amplification(v: np.ndarray, lead_v: np.ndarray, dt: float,
                  band: Sequence[float] = DEFAULT_BAND, trim: float = TRIM
                  ) -> tuple[float, float, float]:
    """``(A, rms_follower, rms_predecessor)``: the ratio of the band-passed speeds'
    RMS (see the module doc) and the two RMS (m/s)."""
    bf = bandpass(v, dt, band, trim)
    bp = bandpass(lead_v, dt, band, trim)
    rf, rp = _rms(bf), _rms(bp)
    return (rf / rp if rp > 0 else math.nan), rf, rp


def bootstrap_ci(bf: np.ndarray, bp: np.ndarray, dt: float, *, block: float = BLOCK,
                 n: int = N_BOOT, level: float = 0.95, seed: Any = 0) -> tuple[float, float]:
    """Percentile interval of the RMS ratio of two band-passed series by a circular
    block bootstrap over time (blocks of ``block`` seconds drawn with replacement,
    the same blocks for both series)."""
    m = bf.shape[0]
    lb = max(1, min(m, int(round(block / dt))))
    k = int(math.ceil(m / lb))
    rng = np.random.default_rng(seed)
    starts = rng.integers(0, m, size=(int(n), k))
    idx = ((starts[:, :, None] + np.arange(lb)[None, None, :]) % m).reshape(int(n), -1)[:, :m]
    num = np.sum(bf[idx] ** 2, axis=1)
    den = np.sum(bp[idx] ** 2, axis=1)
    ratio = np.sqrt(num / den)
    q = (1.0 - level) / 2.0
    return float(np.quantile(ratio, q)), float(np.quantile(ratio, 1.0 - q))


def transfer_gain(model: LowerLevelModel, upper: UpperLevel, f_hz: Any) -> np.ndarray:
    """``|H(j 2π f)|`` of the closed loop (paper Eq. 8) with the true delay:
    ``H = G (kv s + kg) / ((A − K G) s² + G ((kv + Tg kg) s + kg))``,
    ``G = (b1 s + b0) e^{−Td s}``, ``A = a2 s² + a1 s + 1``."""
    c = model.linear()
    s = 2j * np.pi * np.asarray(f_hz, dtype=np.float64)
    g = (c["b1"] * s + c["b0"]) * np.exp(-s * c["Td"])
    a = c["a2"] * s * s + c["a1"] * s + 1.0
    mu = upper.kv + upper.Tg * upper.kg
    h = g * (upper.kv * s + upper.kg) / ((a - c["K"] * g) * s * s + g * (mu * s + upper.kg))
    return np.asarray(np.abs(h))


def predicted_amplification(model: LowerLevelModel, upper: UpperLevel, lead_v: np.ndarray,
                            dt: float, band: Sequence[float] = DEFAULT_BAND,
                            trim: float = TRIM) -> float:
    """RMS gain of ``|H|`` on the predecessor's band-passed speed spectrum:
    ``sqrt(Σ |H|² P / Σ P)`` over the periodogram bins (Hann window) within the
    band."""
    from scipy import signal

    lo, hi = _check_band(band, dt)
    bp = bandpass(lead_v, dt, band, trim)
    f, p = signal.periodogram(bp, fs=1.0 / dt, window="hann", detrend=False)
    m = (f >= lo) & (f <= hi)
    if not m.any() or p[m].sum() <= 0:
        return math.nan
    h = transfer_gain(model, upper, f[m])
    return float(np.sqrt(np.sum(h * h * p[m]) / np.sum(p[m])))


def replay_amplification(model: LowerLevelModel, upper: UpperLevel, run: Run,
                         band: Sequence[float] = DEFAULT_BAND,
                         trim: float = TRIM) -> tuple[float, np.ndarray]:
    """The amplification of the calibrated closed loop replayed behind the measured
    predecessor (NaN when the replay diverges), and the simulated speed."""
    assert run.lead_x is not None and run.lead_v is not None and run.v is not None
    x0 = float(run.x[0]) if run.x is not None else 0.0
    tr = closed_loop(model, run.lead_x, run.lead_v, run.dt, upper, v0=float(run.v[0]), x0=x0)
    if not np.all(np.isfinite(tr.v)):
        return math.nan, tr.v
    return amplification(tr.v, run.lead_v, run.dt, band, trim)[0], tr.v


# ---------------------------------------------------------------------------
# Setting order
# ---------------------------------------------------------------------------


def setting_order(rows: Iterable[Mapping[str, Any]], key: str = "Tg") -> dict[str, Any]:
    """Checks that ``key`` follows the ACC setting (long > medium > short) per car.

    ``rows``: dicts with ``car``, ``setting`` (``"L"``, ``"M"``, ``"S"``; others are
    ignored) and ``key`` (non-finite values are ignored). Per car model the median
    of ``key`` per setting; every pair of settings seen for the car is one check,
    held when the longer setting's median is larger. Returns ``{"checked",
    "held", "checks": [{"car", "longer", "shorter", "value_longer",
    "value_shorter", "n_longer", "n_shorter", "held"}], "file_pairs_checked",
    "file_pairs_held"}`` (the last two compare every file of the longer setting with
    every file of the shorter one, per car).
    """
    by: dict[str, dict[str, list[float]]] = {}
    for r in rows:
        st, val = r.get("setting"), r.get(key)
        if st not in _RANK or val is None or not math.isfinite(float(val)):
            continue
        by.setdefault(str(r["car"]), {}).setdefault(st, []).append(float(val))
    checks = []
    pairs = held_pairs = 0
    for car in sorted(by):
        sets = sorted(by[car], key=lambda s: _RANK[s])
        for i, a in enumerate(sets):
            for b in sets[i + 1:]:
                va, vb = float(np.median(by[car][a])), float(np.median(by[car][b]))
                checks.append({"car": car, "longer": a, "shorter": b, "value_longer": va,
                               "value_shorter": vb, "n_longer": len(by[car][a]),
                               "n_shorter": len(by[car][b]), "held": bool(va > vb)})
                for x in by[car][a]:
                    for y in by[car][b]:
                        pairs += 1
                        held_pairs += int(x > y)
    return {"checked": len(checks), "held": sum(c["held"] for c in checks), "checks": checks,
            "file_pairs_checked": pairs, "file_pairs_held": held_pairs}


# ---------------------------------------------------------------------------
# The study
# ---------------------------------------------------------------------------


def _fin(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


@dataclass
class OpenACCStudy:
    """Result of :func:`openacc_study`: ``summary`` (the JSON contract),
    ``tables`` (pandas DataFrames), ``figures`` (matplotlib Figures), ``report``
    (Markdown), the ``runs`` and the calibration ``results`` per model."""

    summary: dict[str, Any]
    tables: dict[str, Any]
    figures: dict[str, Any]
    report: str
    runs: list[Run] = field(default_factory=list)
    results: dict[str, list[Any]] = field(default_factory=dict)

    def save(self, out: str | Path, json_path: str | Path | None = None) -> list[Path]:
        """Writes the tables (CSV), figures (PNG), ``report.md`` and ``summary.json``
        (strict JSON: a non-finite number is ``null`` with a note) into ``out`` (and
        the JSON to ``json_path`` when given), each atomically (:mod:`avll._atomic`).
        Returns the paths written."""
        d = Path(out)
        d.mkdir(parents=True, exist_ok=True)
        paths = [_atomic.to_csv(t, d / f"{k}.csv", float_format="%.6g")
                 for k, t in self.tables.items()]
        paths += [_atomic.savefig(fig, d / f"{k}.png", dpi=90) for k, fig in self.figures.items()]
        text = _atomic.dumps(self.summary, indent=1) + "\n"
        paths.append(_atomic.write_text(d / "report.md", self.report))
        paths.append(_atomic.write_text(d / "summary.json", text))
        if json_path is not None:
            paths.append(_atomic.write_text(Path(json_path), text))
        return paths


def _upper_of(params: Mapping[str, float]) -> UpperLevel:
    return UpperLevel(*(float(params[k]) for k in _UPPER))


def _model_of(name: str, params: Mapping[str, float]) -> LowerLevelModel:
    cls = model_class(name)
    return cls(**{k: float(params[k]) for k in cls.param_names()})


def _headway(run: Run) -> float:
    assert run.v is not None and run.lead_x is not None and run.x is not None
    m = run.v > HEADWAY_MIN_SPEED
    if m.sum() < 10:
        return math.nan
    return float(np.median((run.lead_x - run.x)[m] / run.v[m]))


def _setting_group(run: Run) -> str | None:
    """The setting used by the setting-order check (None: excluded)."""
    if not run.meta.get("acc"):
        return None
    if str(run.meta.get("folder", "")).lower() == "mixed":
        return None
    return run.meta.get("setting")


def openacc_study(
    path: str | Path,
    *,
    model: str = "proposed",
    models: Sequence[str] = _MODELS,
    seed: int = 0,
    threads: int = 0,
    progress: bool | str = False,
    log: Callable[[str], Any] | None = None,
    max_generations: int = 300,
    pop_size: int = 0,
    starts: int = 2,
    band: Sequence[float] = DEFAULT_BAND,
    n_boot: int = N_BOOT,
    block: float = BLOCK,
    gmin_max: float = GMIN_MAX,
    figures: bool = True,
    **load_options: Any,
) -> OpenACCStudy:
    """Runs the study (see the module doc) on native OpenACC data at ``path`` (a
    file or a folder); ``model`` is the lower-level model of the contract's
    ``params``, ``Tg`` and ``amplification_predicted``; ``models`` are compared
    (``model`` is added if missing). ``max_generations``, ``pop_size`` and
    ``starts`` set the GA budget (the defaults are the GA's full budget with two
    independent starts per car); ``load_options`` go to the loader (``setting``,
    ``car``, ``track``, ...). Ctrl-C raises ``KeyboardInterrupt`` (no partial
    result). ``log`` receives progress lines."""
    from ..io.openacc_native import openacc_native_report

    say = log or (lambda s: None)
    t0 = time.perf_counter()
    model_class(model)
    models = list(dict.fromkeys([model, *models]))
    for m in models:
        model_class(m)
    if not (isinstance(gmin_max, (int, float)) and gmin_max > 0 and math.isfinite(gmin_max)):
        raise ValueError(f"gmin_max: must be a finite number > 0, got {gmin_max!r}")
    if int(n_boot) < 100:
        raise ValueError(f"n_boot: must be >= 100, got {n_boot!r}")
    if not (block > 0):
        raise ValueError(f"block: must be > 0 s, got {block!r}")
    say(f"loading {path}")
    runs, load_report = openacc_native_report(path, **load_options)
    runs = [r for r in runs if r.lead_x is not None]
    if not runs:
        raise ValueError(f"{path}: no follower with a recorded predecessor")
    for r in runs:
        _check_band(band, r.dt)
    runs = [replace(r, upper=UPPER_PLACEHOLDER) for r in runs]
    say(f"{len(runs)} followers in {len({r.meta['file'] for r in runs})} files; "
        f"{len(load_report['skipped'])} followers skipped")
    results: dict[str, list[Any]] = {}
    for k, m in enumerate(models):
        say(f"calibrating {m}: {len(runs)} cars in one parallel call "
            f"(GA {max_generations} generations, {starts} start(s) per car)")
        res = calibrate_many(
            m, runs, "per_run", seed=int(seed) + 1000 * k, threads=threads, progress=progress,
            bounds={"Gmin": (0.0, float(gmin_max))}, closed_loop=True, upper_free=_UPPER,
            weights=WEIGHTS, init="rest", starts=starts, max_generations=max_generations,
            pop_size=pop_size)  # fmt: skip
        if any(r.interrupted for r in res):
            raise KeyboardInterrupt
        results[m] = res
    say("measuring and predicting the amplification")
    cars = []
    for i, r in enumerate(runs):
        cars.append(_car_entry(i, r, models, model, results, band, n_boot, block, seed))
    acc_rows = [{"car": c["car"], "setting": c["_group"], "Tg": c["Tg"],
                 "time_gap_effective": c["time_gap_effective"],
                 "headway_measured": c["headway_measured"]} for c in cars]
    order = setting_order(acc_rows, "Tg")
    order_eff = setting_order(acc_rows, "time_gap_effective")
    order_meas = setting_order(acc_rows, "headway_measured")
    mixed_rows = [{"car": c["car"], "setting": c["setting"] if c["acc"] else None,
                   "Tg": c["Tg"]} for c in cars]
    order_all = setting_order(mixed_rows, "Tg")
    for chk in order["checks"]:
        if not chk["held"]:
            chk["why"] = _why_not(chk, cars)
    comparison = _comparison(cars, models)
    summary: dict[str, Any] = {
        "study": "openacc",
        "data": str(path),
        "model": model,
        "models": models,
        "seed": int(seed),
        "ga": {"max_generations": int(max_generations), "pop_size": int(pop_size),
               "starts": int(starts)},
        "objective_weights": list(WEIGHTS),
        "bounds": {"Gmin": [0.0, float(gmin_max)]},
        "band_hz": [float(band[0]), float(band[1])],
        "trim_s": TRIM, "bootstrap": {"n": int(n_boot), "block_s": float(block),
                                      "level": 0.95},
        "min_excitation_m_s": MIN_EXCITATION,
        "cars": [_public(c) for c in cars],
        "setting_order": {"checked": order["checked"], "held": order["held"],
                          "checks": order["checks"],
                          "file_pairs_checked": order["file_pairs_checked"],
                          "file_pairs_held": order["file_pairs_held"],
                          "excluded": "files in a folder named 'mixed' and files without ACC"},
        "setting_order_effective_time_gap": _short(order_eff),
        "setting_order_measured_headway": _short(order_meas),
        "setting_order_with_mixed": _short(order_all),
        "model_comparison": comparison,
        "skipped": load_report["skipped"],
        "files": _files_summary(runs, cars),
        "name_check": _name_check(runs),
        "poor_fits": _poor_fits(runs, cars),
    }
    tables = _tables(cars, models, model, order, comparison, summary["files"])
    figs = _figures(cars, models, model) if figures else {}
    summary["seconds"] = round(time.perf_counter() - t0, 1)
    report = _report(summary, tables)
    return OpenACCStudy(summary, tables, figs, report, runs, results)


def _name_check(runs: Sequence[Run]) -> dict[str, Any]:
    """Evidence that the vehicle numbers index ``Vehicle_order``: the constant
    ``distance − IVS`` of a pair of named cars, compared across the files where the
    same two names follow each other (consistent: within 5 cm)."""
    by: dict[str, list[tuple[str, float]]] = {}
    for r in runs:
        off = r.meta.get("ivs_offset")
        if off is None:
            continue
        key = f"{r.meta['lead_car']} -> {r.meta['car']}"
        by.setdefault(key, []).append((Path(r.meta["file"]).stem, float(off)))
    pairs = {k: v for k, v in by.items() if len(v) > 1}
    consistent = [k for k, v in pairs.items() if np.ptp([o for _, o in v]) <= 0.05]
    return {"pairs_in_several_files": len(pairs), "consistent": len(consistent),
            "pairs": {k: dict(v) for k, v in sorted(pairs.items())}}


def _poor_fits(runs: Sequence[Run], cars: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Cars whose calibration cost is above three times the median of their group
    (ACC or human), with the largest gap over the median gap (a car that stops
    following, e.g. a disengaged ACC, shows a large ratio)."""
    out = []
    for acc in (True, False):
        grp = [(r, c) for r, c in zip(runs, cars, strict=True)
               if c["acc"] == acc and c["cal_mse"] is not None]
        if not grp:
            continue
        med = float(np.median([c["cal_mse"] for _, c in grp]))
        for r, c in grp:
            if c["cal_mse"] > 3 * med:
                assert r.lead_x is not None and r.x is not None
                gap = r.lead_x - r.x
                k = int(np.argmax(gap))
                out.append({"run_id": r.run_id, "car": c["car"], "cal_mse": c["cal_mse"],
                            "group_median_mse": med,
                            "max_gap_over_median": float(gap[k] / np.median(gap)),
                            "t_max_gap": float(r.t[k])})
    return out


def _short(o: Mapping[str, Any]) -> dict[str, Any]:
    return {k: o[k] for k in ("checked", "held", "checks", "file_pairs_checked",
                              "file_pairs_held")}


def _car_entry(i: int, r: Run, models: Sequence[str], main: str,
               results: Mapping[str, list[Any]], band: Sequence[float], n_boot: int,
               block: float, seed: int) -> dict[str, Any]:
    assert r.v is not None and r.lead_v is not None
    meta = r.meta
    e: dict[str, Any] = {
        "file": meta["file"], "run_id": r.run_id, "car": meta["car"],
        "setting": meta["setting"], "position": int(meta["position"]),
        "acc": bool(meta["acc"]), "track": meta["track"], "folder": meta["folder"],
        "lead_car": meta["lead_car"], "duration_s": round((len(r) - 1) * r.dt, 1),
        "speed_mean": float(np.mean(r.v)), "speed_std": float(np.std(r.v)),
        "_group": _setting_group(r),
    }
    reasons: dict[str, str] = {}
    amp, rf, rp = amplification(r.v, r.lead_v, r.dt, band)
    e["rms_follower"], e["rms_predecessor"] = rf, rp
    ci: list[float | None] = [None, None]
    if rp < MIN_EXCITATION:
        reasons["amplification_measured"] = (
            f"the predecessor does not excite: its band RMS speed is {rp:.3f} m/s < "
            f"{MIN_EXCITATION:g} m/s (GNSS speed noise level)")
        amp = math.nan
    else:
        bf, bp = bandpass(r.v, r.dt, band), bandpass(r.lead_v, r.dt, band)
        lo, hi = bootstrap_ci(bf, bp, r.dt, block=block, n=n_boot, seed=[int(seed), i])
        ci = [lo, hi]
    e["amplification_measured"] = _fin(amp)
    e["amplification_measured_ci"] = ci
    if ci[0] is None:
        reasons["amplification_measured_ci"] = reasons.get(
            "amplification_measured", "no measured amplification")
    e["headway_measured"] = _headway(r)
    per: dict[str, Any] = {}
    for m in models:
        res = results[m][i]
        params = dict(res.params)
        mod = _model_of(m, params)
        up = _upper_of(params)
        codes, _settled = exact_delay_codes(mod, up.kg, up.Tg, up.kv)
        code = int(codes[0])
        a_h = predicted_amplification(mod, up, r.lead_v, r.dt, band) if code else math.nan
        a_r, _ = replay_amplification(mod, up, r, band)
        cost = float(res.cost)
        d: dict[str, Any] = {
            "params": params, "cal_mse": _fin(cost), "at_bound": list(res.at_bound),
            "amplification_H": _fin(a_h), "amplification_replay": _fin(a_r),
            "time_gap_effective": _fin(up.Tg + up.Gmin / max(float(np.mean(r.v)), 0.1)),
            "per_run_mse": _fin(res.per_run_mse.get(r.run_id, math.nan)),
            "local_stable": code > 0, "string_stable": (code == 2) if code else None,
        }
        if not code:
            d["string_stable_reason"] = "the calibrated closed loop is locally unstable"
        if not math.isfinite(cost):
            d["cal_mse_reason"] = "every parameter set of the search was unstable"
        if not math.isfinite(a_r):
            d["amplification_replay_reason"] = "the calibrated closed loop diverges in replay"
        if not code:
            d["amplification_H_reason"] = ("the calibrated closed loop is locally unstable "
                                           "(true delay): |H(jω)| is not its gain")
        elif not math.isfinite(a_h):
            d["amplification_H_reason"] = "no periodogram bin in the band"
        meas = e["amplification_measured"]
        for key in ("amplification_H", "amplification_replay"):
            d[f"{key}_error"] = (d[key] / meas - 1.0) if (meas and d[key] is not None) else None
        per[m] = d
    mm = per[main]
    e["params"] = mm["params"]
    e["Tg"] = _fin(mm["params"]["Tg"])
    e["cal_mse"] = mm["cal_mse"]
    if mm["cal_mse"] is None:
        reasons["cal_mse"] = mm["cal_mse_reason"]
    e["amplification_predicted"] = mm["amplification_H"]
    if e["amplification_predicted"] is None:
        reasons["amplification_predicted"] = mm.get("amplification_H_reason", "not finite")
    e["amplification_replay"] = mm["amplification_replay"]
    if e["amplification_replay"] is None:
        reasons["amplification_replay"] = mm.get("amplification_replay_reason", "not finite")
    e["time_gap_effective"] = mm["time_gap_effective"]
    e["at_bound"] = mm["at_bound"]
    e["models"] = per
    for k, v in reasons.items():
        e[f"{k}_reason"] = v
    return e


def _public(c: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in c.items() if not k.startswith("_")}


def _why_not(chk: Mapping[str, Any], cars: Sequence[Mapping[str, Any]]) -> str:
    """A reason, from the numbers, why a setting check failed."""
    car = chk["car"]
    mine = [c for c in cars if c["car"] == car and c["_group"] in (chk["longer"], chk["shorter"])]
    parts = []
    for st in (chk["longer"], chk["shorter"]):
        cs = [c for c in mine if c["_group"] == st]
        desc = ", ".join(
            f"{Path(c['file']).stem} Tg {c['Tg']:.2f} s, Gmin {c['params']['Gmin']:.1f} m, "
            f"Tg+Gmin/v {c['time_gap_effective']:.2f} s, measured headway "
            f"{c['headway_measured']:.2f} s, speed {c['speed_mean']:.1f}±{c['speed_std']:.1f} "
            f"m/s" + (f", at bound: {'/'.join(c['at_bound'])}" if c["at_bound"] else "")
            for c in cs)
        parts.append(f"{st}: {desc}")
    eff = {st: np.median([c["time_gap_effective"] for c in mine if c["_group"] == st
                          and c["time_gap_effective"] is not None] or [np.nan])
           for st in (chk["longer"], chk["shorter"])}
    hw = {st: np.median([c["headway_measured"] for c in mine if c["_group"] == st
                         and c["headway_measured"] is not None
                         and math.isfinite(c["headway_measured"])] or [np.nan])
          for st in (chk["longer"], chk["shorter"])}
    lo_std = min((c["speed_std"] for c in mine), default=math.nan)
    why = []
    flat = [Path(c["file"]).stem for c in mine if c["params"]["kg"] < 0.01]
    if flat:
        why.append(f"kg ≈ 0 in {', '.join(flat)}: the calibrated law ignores the gap there, "
                   "so its Tg is not identified")
    if hw[chk["longer"]] <= hw[chk["shorter"]]:
        why.append("the measured headway itself is not longer in the longer setting "
                   f"({hw[chk['longer']]:.2f} vs {hw[chk['shorter']]:.2f} s)")
    if eff[chk["longer"]] > eff[chk["shorter"]]:
        why.append("the calibrated law's effective time gap Tg + Gmin/v does follow the "
                   f"setting ({eff[chk['longer']]:.2f} vs {eff[chk['shorter']]:.2f} s): "
                   "the split between Tg and Gmin is what fails")
    if lo_std < 1.0:
        why.append(f"a run's speed varies little (std {lo_std:.2f} m/s), so Tg and Gmin "
                   "are hardly separable there")
    if any(c["at_bound"] for c in mine):
        why.append("a parameter is at its bound")
    return ("; ".join(why) or "no simple reason found") + ". " + " | ".join(parts)


def _comparison(cars: Sequence[Mapping[str, Any]], models: Sequence[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    acc = [c for c in cars if c["acc"] and c["amplification_measured"] is not None]
    human = [c for c in cars if not c["acc"] and c["amplification_measured"] is not None]
    for m in models:
        d: dict[str, Any] = {}
        for key in ("amplification_H", "amplification_replay"):
            for grp, cs in (("acc", acc), ("human", human)):
                errs = [c["models"][m][f"{key}_error"] for c in cs
                        if c["models"][m][f"{key}_error"] is not None]
                inside = [c for c in cs if c["models"][m][key] is not None
                          and c["amplification_measured_ci"][0] is not None
                          and c["amplification_measured_ci"][0] <= c["models"][m][key]
                          <= c["amplification_measured_ci"][1]]
                am = [c["amplification_measured"] for c in cs
                      if c["models"][m][f"{key}_error"] is not None]
                d[f"{key}_{grp}"] = {
                    "n": len(errs),
                    "underestimated": int(np.sum(np.asarray(errs) < 0)) if errs else 0,
                    "corr_error_vs_measured": (_fin(np.corrcoef(errs, am)[0, 1])
                                               if len(errs) > 2 else None),
                    "median_abs_error": _fin(np.median(np.abs(errs))) if errs else None,
                    "mean_error": _fin(np.mean(errs)) if errs else None,
                    "within_10pct": int(np.sum(np.abs(errs) <= 0.10)) if errs else 0,
                    "inside_ci": len(inside),
                }
        su = [c for c in acc if c["amplification_measured_ci"][0] is not None]
        meas_unst = [c for c in su if c["amplification_measured_ci"][0] > 1.0]
        meas_st = [c for c in su if c["amplification_measured_ci"][1] < 1.0]
        d["string_stability"] = {
            "measured_unstable": len(meas_unst),
            "measured_stable": len(meas_st),
            "undecided": len(su) - len(meas_unst) - len(meas_st),
            "model_unstable_where_measured_unstable": sum(
                1 for c in meas_unst if c["models"][m]["string_stable"] is False),
            "model_stable_where_measured_stable": sum(
                1 for c in meas_st if c["models"][m]["string_stable"] is True),
            "model_string_unstable_all": sum(1 for c in cars if c["acc"]
                                             and c["models"][m]["string_stable"] is False),
            "model_locally_unstable_all": sum(1 for c in cars if c["acc"]
                                              and not c["models"][m]["local_stable"]),
            "cars_acc": sum(1 for c in cars if c["acc"]),
        }
        out[m] = d
    best = {}
    for key in ("amplification_H", "amplification_replay"):
        cand = [(out[m][f"{key}_acc"]["median_abs_error"], m) for m in models
                if out[m][f"{key}_acc"]["median_abs_error"] is not None]
        best[key] = min(cand)[1] if cand else None
    out["best"] = best
    return out


def _files_summary(runs: Sequence[Run], cars: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    from scipy import signal

    out = []
    for f in dict.fromkeys(r.meta["file"] for r in runs):
        rs = [r for r in runs if r.meta["file"] == f]
        m0 = rs[0].meta
        # where the platoon oscillates: mean periodogram of the predecessors' speeds
        spec = []
        for r in rs:
            assert r.lead_v is not None
            fr, p = signal.periodogram(signal.detrend(r.lead_v), fs=1 / r.dt, window="hann")
            spec.append(np.interp(np.linspace(0.005, 0.5, 400), fr, p))
        fg = np.linspace(0.005, 0.5, 400)
        mean = np.mean(spec, axis=0)
        out.append({"file": f, "folder": m0["folder"], "track": m0["track"],
                    "setting": m0["setting"], "acc": m0["acc"], "date": m0["date"],
                    "followers": len(rs), "n_vehicles": m0["n_vehicles"],
                    "peak_hz": float(fg[int(np.argmax(mean))]),
                    "band_power_share": float(mean[(fg >= DEFAULT_BAND[0])
                                                   & (fg <= DEFAULT_BAND[1])].sum() / mean.sum()),
                    "excited_followers": sum(1 for c in cars if c["file"] == f
                                             and c["amplification_measured"] is not None)})
    return out


def _tables(cars: Sequence[Mapping[str, Any]], models: Sequence[str], main: str,
            order: Mapping[str, Any], comparison: Mapping[str, Any],
            files: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    import pandas as pd

    rows = []
    for c in cars:
        ci = c["amplification_measured_ci"]
        rows.append({"file": Path(c["file"]).stem, "car": c["car"],
                     "setting": c["setting"] or "none", "position": c["position"],
                     "track": c["track"], "Tg": c["Tg"], "Gmin": c["params"]["Gmin"],
                     "kg": c["params"]["kg"], "kv": c["params"]["kv"],
                     "time_gap_effective": c["time_gap_effective"],
                     "headway_measured": c["headway_measured"], "cal_mse": c["cal_mse"],
                     "A_measured": c["amplification_measured"], "A_ci_low": ci[0],
                     "A_ci_high": ci[1], "A_predicted_H": c["amplification_predicted"],
                     "A_replay": c["amplification_replay"],
                     "at_bound": "/".join(c["at_bound"])})
    per_model = []
    for c in cars:
        for m in models:
            d = c["models"][m]
            per_model.append({"file": Path(c["file"]).stem, "car": c["car"],
                              "setting": c["setting"] or "none", "position": c["position"],
                              "model": m, "cal_mse": d["cal_mse"], "Tg": d["params"]["Tg"],
                              "A_measured": c["amplification_measured"],
                              "A_H": d["amplification_H"], "A_replay": d["amplification_replay"],
                              "error_H": d["amplification_H_error"],
                              "error_replay": d["amplification_replay_error"],
                              **{f"p_{k}": v for k, v in d["params"].items()}})
    cars_df = pd.DataFrame(rows)
    label = [("none" if c["setting"] is None else
              f"{c['setting']} (folder mixed)" if c["_group"] is None else c["setting"])
             for c in cars]
    tg = (cars_df.assign(setting=label)
          .pivot_table(index="car", columns="setting", values="Tg", aggfunc="median"))
    order_df = pd.DataFrame(order["checks"]) if order["checks"] else pd.DataFrame(
        columns=["car", "longer", "shorter", "value_longer", "value_shorter", "held"])
    comp = []
    for m in models:
        for key, lab in (("amplification_H", "|H(jw)|"), ("amplification_replay", "replay")):
            for grp in ("acc", "human"):
                d = comparison[m][f"{key}_{grp}"]
                comp.append({"model": m, "prediction": lab, "cars": grp, **d})
    return {"cars": cars_df, "models": pd.DataFrame(per_model), "tg_by_car_setting": tg,
            "setting_order": order_df, "model_comparison": pd.DataFrame(comp),
            "files": pd.DataFrame([{**f, "file": Path(f["file"]).stem} for f in files])}


def _figures(cars: Sequence[Mapping[str, Any]], models: Sequence[str], main: str
             ) -> dict[str, Any]:
    from ..plotting import amplification_per_car, time_gap_per_car

    return {"amplification": amplification_per_car(cars, models),
            "tg_setting": time_gap_per_car(cars, main)}


def _f(x: Any, nd: int = 2) -> str:
    v = _fin(x)
    return "–" if v is None else f"{v:.{nd}f}"


def _md_table(df: Any, floatfmt: int = 3) -> str:
    cols = list(df.columns)
    lines = ["| " + " | ".join(str(c) for c in cols) + " |",
             "|" + "|".join("---" for _ in cols) + "|"]
    for _, row in df.iterrows():
        cells = []
        for c in cols:
            v = row[c]
            if isinstance(v, (float, np.floating)):
                cells.append(_f(v, floatfmt))
            else:
                cells.append(str(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _findings(s: Mapping[str, Any]) -> list[str]:
    """The main numbers of the study as Markdown bullets (generated, not typed)."""
    main = s["model"]
    comp = s["model_comparison"]
    so = s["setting_order"]
    eff = s["setting_order_effective_time_gap"]
    hw = s["setting_order_measured_headway"]
    fails = [c["car"] for c in so["checks"] if not c["held"]]
    out = [f"- **Setting order**: the calibrated Tg ({main} model) is longer for the longer "
           f"ACC setting in {so['held']} of {so['checked']} checks (car model × pair of "
           "settings)" + (f"; not for {', '.join(fails)}" if fails else "") + "; file by "
           f"file, in {so['file_pairs_held']} of {so['file_pairs_checked']} pairs of files. "
           "The "
           f"effective time gap Tg + Gmin/v̄ follows the setting in {eff['held']} of "
           f"{eff['checked']}, the measured headway (no model) in {hw['held']} of "
           f"{hw['checked']}."]
    for key, lab in (("amplification_replay", "time-domain replay"),
                     ("amplification_H", "abs H(jω)")):
        parts = []
        for m in s["models"]:
            d = comp[m][f"{key}_acc"]
            if d["n"]:
                parts.append(f"{m} {d['within_10pct']}/{d['n']} within 10 % (median abs "
                             f"error {_f(d['median_abs_error'], 3)}, mean error "
                             f"{_f(d['mean_error'], 3)}, underestimated for "
                             f"{d['underestimated']})")
        out.append(f"- **Amplification, {lab}** (ACC cars with an excited predecessor): "
                   + "; ".join(parts) + f". Best: **{comp['best'][key]}**.")
    d = comp[main]["amplification_replay_acc"]
    if d["corr_error_vs_measured"] is not None:
        out.append(f"- The {main} model's replay error correlates with the measured "
                   f"amplification at {_f(d['corr_error_vs_measured'])}: the more a car "
                   "amplifies, the more the calibrated model underestimates it"
                   if d["corr_error_vs_measured"] < 0 else
                   f"- The {main} model's replay error correlates with the measured "
                   f"amplification at {_f(d['corr_error_vs_measured'])}.")
    q = comp[main]["string_stability"]
    out.append(f"- **String stability**: the measured amplification's 95 % CI is above 1 "
               f"for {q['measured_unstable']} ACC cars and below 1 for "
               f"{q['measured_stable']} ({q['undecided']} undecided); the calibrated "
               f"{main} closed loops are string-unstable (max abs H > 1, true delay) for "
               f"{q['model_string_unstable_all']} of {q['cars_acc']} ACC cars, locally "
               f"unstable for {q['model_locally_unstable_all']}.")
    hum = [c for c in s["cars"] if not c["acc"]]
    if hum:
        dh = comp[main]["amplification_replay_human"]
        tgs = [c["Tg"] for c in hum if c["Tg"] is not None]
        out.append(f"- **Human control** ({len(hum)} drivers): calibrated Tg "
                   f"{min(tgs):.2f}–{max(tgs):.2f} s; replay within 10 % for "
                   f"{dh['within_10pct']} of {dh['n']}.")
    return out


def _report(s: Mapping[str, Any], tables: Mapping[str, Any]) -> str:
    main = s["model"]
    cars = s["cars"]
    acc = [c for c in cars if c["acc"]]
    hum = [c for c in cars if not c["acc"]]
    so = s["setting_order"]
    comp = s["model_comparison"]
    lines = [
        "# OpenACC study: calibrated time gaps and measured string stability",
        "",
        "## Findings",
        "",
        *_findings(s),
        "",
        "## Data and method",
        "",
        f"Data: `{s['data']}`; {len(cars)} followers with a recorded predecessor in "
        f"{len(s['files'])} files ({len(acc)} under ACC, {len(hum)} human-driven); "
        f"{len(s['skipped'])} followers skipped (see below). Main model: **{main}**; "
        f"compared: {', '.join(s['models'])}. GA: {s['ga']['max_generations']} generations, "
        f"population {s['ga']['pop_size'] or 'automatic'}, {s['ga']['starts']} start(s) per "
        f"car; seed {s['seed']}; objective weights (a, v, x) = "
        f"{tuple(s['objective_weights'])}; Gmin in [0, {s['bounds']['Gmin'][1]:g}] m. "
        f"Amplification band {s['band_hz'][0]:g}–{s['band_hz'][1]:g} Hz, block bootstrap "
        f"{s['bootstrap']['n']} × {s['bootstrap']['block_s']:g} s blocks. Wall time "
        f"{s.get('seconds', 0):.0f} s.",
        "",
        "## Files",
        "",
        _md_table(tables["files"][["file", "folder", "track", "setting", "acc", "followers",
                                   "excited_followers", "peak_hz", "band_power_share"]]),
        "",
        "`peak_hz`: peak of the mean periodogram of the predecessors' speeds; "
        "`band_power_share`: its share in the amplification band.",
        "",
        "## Setting order (calibrated Tg)",
        "",
        f"Checks held: **{so['held']} of {so['checked']}** (per car model and pair of "
        f"settings, medians over files; {so['excluded']} excluded); file by file: "
        f"{so['file_pairs_held']} of {so['file_pairs_checked']}. With the folder "
        f"'mixed' included: {s['setting_order_with_mixed']['held']} of "
        f"{s['setting_order_with_mixed']['checked']}. The same check on the effective "
        f"time gap Tg + Gmin/v̄: {s['setting_order_effective_time_gap']['held']} of "
        f"{s['setting_order_effective_time_gap']['checked']}; on the measured headway "
        f"(no model): {s['setting_order_measured_headway']['held']} of "
        f"{s['setting_order_measured_headway']['checked']}.",
        "",
    ]
    if not tables["tg_by_car_setting"].empty:
        lines += ["Calibrated Tg (s), median per car model and setting ('none': the human "
                  "control; the folder 'mixed' apart):", "",
                  _md_table(tables["tg_by_car_setting"].reset_index(), 2), ""]
    fails = [c for c in so["checks"] if not c["held"]]
    if fails:
        lines += ["Where the order does not hold:", ""]
        lines += [f"- **{c['car']}** ({c['longer']} {c['value_longer']:.2f} s vs "
                  f"{c['shorter']} {c['value_shorter']:.2f} s): {c['why']}" for c in fails]
        lines.append("")
    if hum:
        lines += ["Human control (no ACC): Tg " + ", ".join(
            f"{c['car']} {_f(c['Tg'])} s" for c in hum) + ".", ""]
    lines += ["## Amplification: measured vs predicted", ""]
    best = comp["best"]
    lines.append("| model | prediction | cars | n | median abs error | mean error | "
                 "within 10 % | inside CI | under-estimated | corr(error, measured) |")
    lines.append("|---|---|---|---|---|---|---|---|---|---|")
    for m in s["models"]:
        for key, lab in (("amplification_H", "abs H(jω)"), ("amplification_replay", "replay")):
            for grp in ("acc", "human"):
                d = comp[m][f"{key}_{grp}"]
                if not d["n"]:
                    continue
                lines.append(f"| {m} | {lab} | {grp} | {d['n']} | "
                             f"{_f(d['median_abs_error'], 3)} | {_f(d['mean_error'], 3)} | "
                             f"{d['within_10pct']} | {d['inside_ci']} | "
                             f"{d['underestimated']} | {_f(d['corr_error_vs_measured'])} |")
    lines += ["", "String stability per car (ACC cars with a measured amplification; "
              "measured string-unstable: CI above 1, stable: CI below 1):", "",
              "| model | measured unstable | model says unstable there | measured stable | "
              "model says stable there | undecided | model string-unstable (all ACC cars) | "
              "model locally unstable |", "|---|---|---|---|---|---|---|---|"]
    for m in s["models"]:
        q = comp[m]["string_stability"]
        lines.append(f"| {m} | {q['measured_unstable']} | "
                     f"{q['model_unstable_where_measured_unstable']} | {q['measured_stable']} | "
                     f"{q['model_stable_where_measured_stable']} | {q['undecided']} | "
                     f"{q['model_string_unstable_all']} of {q['cars_acc']} | "
                     f"{q['model_locally_unstable_all']} |")
    lines += ["", f"Best predictor of the measured amplification (smallest median absolute "
              f"error over the ACC cars): from abs H(jω): **{best['amplification_H']}**; by "
              f"replay: **{best['amplification_replay']}**.", ""]
    lines += ["Per car (main model):", "",
              _md_table(tables["cars"][["file", "car", "setting", "position", "Tg", "Gmin",
                                        "time_gap_effective", "headway_measured", "cal_mse",
                                        "A_measured", "A_ci_low", "A_ci_high",
                                        "A_predicted_H", "A_replay"]], 2), ""]
    out10 = [c for c in acc if c["models"][main]["amplification_replay_error"] is not None
             and abs(c["models"][main]["amplification_replay_error"]) > 0.10]
    if out10:
        weak = sum(c["rms_predecessor"] < 0.1 for c in out10)
        strong = sum(c["amplification_measured"] > 1.3 for c in out10)
        lines += [f"ACC cars whose {main} replay misses the measured amplification by more "
                  f"than 10 % ({len(out10)}; {strong} of them amplify by more than 1.3, "
                  f"{weak} have a predecessor band RMS below 0.1 m/s):", ""]
        lines += [f"- {c['run_id']} ({c['car']}, {c['setting']}): measured "
                  f"{c['amplification_measured']:.2f} "
                  f"[{c['amplification_measured_ci'][0]:.2f}, "
                  f"{c['amplification_measured_ci'][1]:.2f}], replay "
                  f"{_f(c['amplification_replay'])} "
                  f"({c['models'][main]['amplification_replay_error']:+.0%}); predecessor band "
                  f"RMS {c['rms_predecessor']:.2f} m/s; calibration cost {_f(c['cal_mse'], 3)}"
                  for c in out10]
        lines.append("")
    nc = s["name_check"]
    lines += ["## Vehicle names", "",
              f"`IVS` is the straight-line distance of the two cars' positions minus a "
              f"constant per pair. Of the {nc['pairs_in_several_files']} pairs of named cars "
              f"that follow each other in several files, {nc['consistent']} have the same "
              "constant (within 5 cm) in every file"
              + (". The constant is thus a property of the two named cars, which supports "
                 "reading the vehicle numbers as positions in `Vehicle_order`:"
                 if nc["consistent"] == nc["pairs_in_several_files"] else
                 "; the others differ between files, so the constant is not a property of "
                 "the two names alone and this check neither confirms nor refutes the "
                 "mapping of names to vehicle numbers (the loader follows the README: "
                 "vehicle i is the i-th name of `Vehicle_order`):"), ""]
    lines += [f"- {k}: " + ", ".join(f"{f} {o:.3f} m" for f, o in v.items())
              for k, v in nc["pairs"].items()]
    lines.append("")
    if s["poor_fits"]:
        lines += ["## Poor fits", "",
                  "Cars whose calibration cost is above three times their group's median "
                  "(a large max gap / median gap suggests the car stopped following, e.g. "
                  "a disengaged ACC):", ""]
        lines += [f"- {p['run_id']} ({p['car']}): cost {p['cal_mse']:.3f} vs median "
                  f"{p['group_median_mse']:.3f}; max gap {p['max_gap_over_median']:.1f} x the "
                  f"median gap at t = {p['t_max_gap']:.1f} s" for p in s["poor_fits"]]
        lines.append("")
    no_meas = [c for c in cars if c["amplification_measured"] is None]
    if no_meas:
        lines += ["No measured amplification: " + "; ".join(
            f"{c['run_id']} ({c.get('amplification_measured_reason', '')})"
            for c in no_meas) + ".", ""]
    if s["skipped"]:
        lines += ["## Skipped followers", ""]
        lines += [f"- {Path(k['file']).stem} vehicle {k['follower']} ({k['car']}): "
                  f"{k['reason']}" for k in s["skipped"]]
        lines.append("")
    return "\n".join(lines) + "\n"
