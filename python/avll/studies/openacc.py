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
   weigh the same). Box: :data:`avll.calibration.DEFAULT_BOUNDS` except ``Gmin``
   in ``[0, gmin_max]`` (10 m by default). Why: at the near-constant speed of the
   dynamic-platform files only ``Gmin + Tg v`` is identified, and the default
   ``[0, 30]`` m lets the search trade the time gap for standstill distances no
   commercial ACC uses (2–5 m bumper to bumper); the sensitivity to this choice is
   reported by running the study with ``gmin_max=30``.
2. **Setting order.** The calibrated ``Tg`` per campaign, car model and ACC
   setting (median over runs); for every car model seen under two settings of the
   same campaign, each pair of settings is one check, held when the longer setting
   has the larger ``Tg`` (:func:`setting_order`). "Longer" is the campaign's own
   order of its settings (the run meta's ``setting_rank``: ``L``/``M``/``S``,
   ``min``/``shortest``/``second shortest``, ``SL`` resolved per car, as the
   loader reads the campaign's notes); settings of different campaigns are never
   compared; the result is reported per car model and per campaign. Runs in a
   folder named ``mixed`` are left out of the check (their header says one
   setting, their folder says the cars' settings were mixed). The same check is made
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
   Runs of any length: a run whose record, after the trim, is shorter than one
   period of the band's low edge (50 s) gets no measured or predicted
   amplification; one shorter than :data:`MIN_BLOCKS` bootstrap blocks gets no
   interval (each ``null`` with a ``_reason``: a block bootstrap over one or two
   blocks only rotates the record and its interval collapses).
   Beside the band RMS ratio, the H1 cross-spectral band gain of predecessor ->
   follower speed (:func:`avll.spectral.h1_band_gain`: power-weighted over the
   band, with the band's coherence and a 95 % interval): per car
   ``amplification_measured_h1``, ``amplification_measured_h1_ci``, ``coherence``.
   Like with like: ``|H(jω)|`` on the predecessor's spectrum is compared with the
   H1 gain, a replay with the RMS ratio.
4. **Out of sample** (the headline; the figures above are in-sample: each car's
   model is calibrated on the run it is compared on). Leave one file out: for
   every run, one model of ``model`` is calibrated on all the runs of the same car
   (campaign, car, setting, ACC state) from the car's OTHER files, together (one
   multi-run problem of :func:`avll.calibrate_many`, same budget and box), and
   predicts the held-out run: ``amplification_predicted_oos`` (``|H|`` vs H1),
   ``amplification_replay_oos`` (replay vs the RMS ratio) and
   ``time_gap_effective_oos`` (``Tg + Gmin / v̄`` at the held-out run's mean
   speed, compared with the measured headway). Each is ``null`` with a
   ``_reason`` when the car has no other file of its setting. The summary's
   ``out_of_sample`` gives, per group, the bias (mean error), the share within 10 %,
   the share inside the measured 95 % interval and the share of the measurements
   inside the predicted 95 % interval, out of sample and in-sample.
5. **Intervals** (``intervals=True``, the default). The main model's calibrations,
   in-sample and out of sample, get their uncertainty (:mod:`avll.uncertainty`: a
   moving-block bootstrap over time with the block length from the residuals, each
   resample refit by a local search from the full-data optimum; for the
   out-of-sample model the blocks are those of the car's other files). Per car, all
   at 95 %: ``amplification_predicted_ci`` and ``amplification_predicted_oos_ci``
   (``|H|`` of the resampled closed loops on the run's predecessor spectrum; locally
   unstable resamples left out and counted in ``_note``), ``time_gap_effective_ci``
   and ``time_gap_effective_oos_ci`` (at the run's mean speed),
   ``string_stable_probability`` (and ``_oos``: the share of resamples string stable
   by the exact test with the true delay; locally unstable ones count as not
   stable), ``params_ci`` (name -> [low, high]) and ``identified`` (the parameters
   and combinations the data determine, :meth:`avll.Uncertainty.verdicts`); each
   ``null`` with a ``_reason`` where none can be computed. ``final_model_effects``
   names the effects of the model the predictions come from (empty: the base
   model).

**ACC state** (the run meta's ``acc``): runs under ACC are the study's cars;
human-driven runs (``acc`` False) are calibrated with the same closed-loop
structure and reported as a **control**, never counted as ACC (not in the ACC
comparisons nor in the setting-order check); runs of unknown state (``acc`` None)
are left out and counted (``acc_unknown="exclude"``, the default) or studied as
ACC (``"include"``). The summary's ``car_overview`` gives, per campaign and car
model, the raw settings and their order, the ACC state of the runs studied, and
the stretches studied and left out with the reasons (the loader's report's
dropped stretches and the study's own exclusions).
"""

from __future__ import annotations

import math
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .. import _atomic
from ..calibration import calibrate_many
from ..data import Run
from ..defaults import CLOSED_LOOP_WEIGHTS, DEFAULT_STARTS, GA_OPTIONS, LEVEL, UPPER_PLACEHOLDER
from ..defaults import UPPER_NAMES as _UPPER
from ..models import LowerLevelModel, UpperLevel, model_class
from ..paper import MODELS as _MODELS
from ..report import finite_or_none as _fin
from ..report import md_table
from ..rollout import closed_loop
from ..spectral import (
    DEFAULT_BAND,
    MIN_EXCITATION,
    TRIM,
    band_rms_gain,
    bandpass,
    check_band,
)
from ..stability import exact_delay_codes
from ..uncertainty import symmetric_interval
from .openacc_select import ALPHA as SELECT_ALPHA
from .openacc_select import MAX_STRUCTURES
from .openacc_select import MIN_GAIN as SELECT_MIN_GAIN

__all__ = ["WEIGHTS", "DEFAULT_BAND", "TRIM", "BLOCK", "N_BOOT", "MIN_EXCITATION",
           "GMIN_MAX", "HEADWAY_MIN_SPEED", "OpenACCStudy", "openacc_study", "bandpass",
           "amplification", "bootstrap_ci", "transfer_gain", "predicted_amplification",
           "replay_amplification", "measured_amplification", "time_gap_effective",
           "run_meta", "setting_order", "MIN_BLOCKS", "ACC_UNKNOWN"]

#: Objective weights (wa, wv, wx) of the closed-loop calibration: the project's one
#: closed-loop weighting (:data:`avll.defaults.CLOSED_LOOP_WEIGHTS`).
WEIGHTS: tuple[float, float, float] = CLOSED_LOOP_WEIGHTS
#: Block length (s) of the bootstrap over time.
BLOCK = 20.0
#: Bootstrap resamples.
N_BOOT = 2000
#: Upper bound (m) of the standstill distance Gmin in the calibration.
GMIN_MAX = 10.0
#: The measured time headway uses the samples faster than this (m/s).
HEADWAY_MIN_SPEED = 3.0
#: The block bootstrap needs at least this many blocks in the trimmed record.
MIN_BLOCKS = 3
#: ``--acc-unknown`` choices: stretches of unknown ACC state left out or taken as ACC.
ACC_UNKNOWN = ("exclude", "include")
#: Fallback order of the settings (larger = longer time gap) for runs whose meta has
#: no ``setting_rank`` (runs of a loader that does not rank the campaign's settings).
_RANK = {"S": 0, "M": 1, "L": 2}


# ---------------------------------------------------------------------------
# Signal measures
# ---------------------------------------------------------------------------


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
                 n: int = N_BOOT, level: float = LEVEL, seed: Any = 0) -> tuple[float, float]:
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


def transfer_gain(model: Any, upper: UpperLevel, f_hz: Any, *, v: float = 0.0,
                  hold: float = 0.0) -> np.ndarray:
    """``|H(j 2π f)|`` of the closed loop (paper Eq. 8) with the true delay, for a base
    model or an :class:`avll.WithEffects` (both levels, linearised at the speed ``v``),
    the loop run at sample period ``hold`` (0: continuous): the modulus of
    :func:`avll.effect_stability.frequency_response`. For a base model and ``hold=0``,
    ``H = G (kv s + kg) / ((A − K G) s² + G ((kv + Tg kg) s + kg))``,
    ``G = (b1 s + b0) e^{−Td s}``, ``A = a2 s² + a1 s + 1``."""
    from ..effect_stability import frequency_response

    return np.asarray(np.abs(frequency_response(model, upper, 2.0 * np.pi * np.asarray(
        f_hz, dtype=np.float64), v=v, hold=hold)))


def predicted_amplification(model: Any, upper: UpperLevel, lead_v: np.ndarray,
                            dt: float, band: Sequence[float] = DEFAULT_BAND,
                            trim: float = TRIM, *, v: float | None = None,
                            hold: float | None = None) -> float:
    """RMS gain of ``|H|`` (:func:`transfer_gain`; a base model or an
    :class:`avll.WithEffects`, linearised at ``v``, by default the predecessor's mean
    speed) on the predecessor's band-passed speed spectrum: ``sqrt(Σ |H|² P / Σ P)``
    over the periodogram bins (Hann window) within the band
    (:func:`avll.spectral.band_weights`). ``hold``: the sample period of the loop
    (default ``dt``: a model calibrated on runs sampled at ``dt``; 0: the continuous
    loop). The weighting is :func:`avll.spectral.band_rms_gain`'s."""
    def gain(f: np.ndarray) -> np.ndarray:
        return transfer_gain(model, upper, f, v=float(np.mean(lead_v)) if v is None else v,
                             hold=float(dt) if hold is None else hold)

    return band_rms_gain(gain, lead_v, dt, band, trim)


def replay_amplification(model: Any, upper: UpperLevel, run: Run,
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


def _rank_of(r: Mapping[str, Any]) -> int | None:
    """The order of a row's setting: its ``setting_rank`` when given, else the
    fallback L > M > S; None when neither applies."""
    if "setting_rank" in r:
        rank = r["setting_rank"]
        ok = isinstance(rank, (int, np.integer)) and not isinstance(rank, bool)
        return int(rank) if ok else None
    st = r.get("setting")
    return _RANK.get(st) if isinstance(st, str) else None


def setting_order(rows: Iterable[Mapping[str, Any]], key: str = "Tg") -> dict[str, Any]:
    """Checks that ``key`` follows the ACC setting (the longer setting, the larger
    ``key``) per campaign and car model.

    ``rows``: dicts with ``car``, ``setting`` (raw, as in the file), ``key``
    (non-finite values are ignored) and optionally ``setting_rank`` (the setting's
    order within its campaign, larger = longer time gap; without it ``L`` > ``M`` >
    ``S`` and other settings are ignored) and ``campaign`` (settings of different
    campaigns are never compared; default one campaign). Rows whose setting is
    ``None`` or has no order are ignored. Per campaign and car model the median of
    ``key`` per setting rank (raw settings of the same rank are pooled, e.g. a
    campaign's ``SL`` resolved to its long setting); every pair of ranks seen for
    the car is one check, held when the longer setting's median is larger.

    Returns ``{"checked", "held", "checks": [{"campaign", "car", "longer",
    "shorter", "rank_longer", "rank_shorter", "value_longer", "value_shorter",
    "n_longer", "n_shorter", "held"}], "per_car": [{"campaign", "car", "settings",
    "checked", "held"}], "file_pairs_checked", "file_pairs_held"}`` (the last two
    compare every run of the longer setting with every run of the shorter one, per
    campaign and car).
    """
    by: dict[tuple[str, str], dict[int, list[float]]] = {}
    names: dict[tuple[str, str], dict[int, set[str]]] = {}
    for r in rows:
        st, val = r.get("setting"), r.get(key)
        rank = _rank_of(r)
        if st is None or rank is None or val is None or not math.isfinite(float(val)):
            continue
        k = (str(r.get("campaign") or ""), str(r["car"]))
        by.setdefault(k, {}).setdefault(rank, []).append(float(val))
        names.setdefault(k, {}).setdefault(rank, set()).add(str(st))
    checks = []
    per_car = []
    pairs = held_pairs = 0
    for k in sorted(by):
        camp, car = k
        ranks = sorted(by[k], reverse=True)
        lab = {rk: "/".join(sorted(names[k][rk])) for rk in ranks}
        mine: list[dict[str, Any]] = []
        for i, a in enumerate(ranks):
            for b in ranks[i + 1:]:
                va, vb = float(np.median(by[k][a])), float(np.median(by[k][b]))
                mine.append({"campaign": camp, "car": car, "longer": lab[a], "shorter": lab[b],
                             "rank_longer": a, "rank_shorter": b, "value_longer": va,
                             "value_shorter": vb, "n_longer": len(by[k][a]),
                             "n_shorter": len(by[k][b]), "held": bool(va > vb)})
                pairs += len(by[k][a]) * len(by[k][b])
                held_pairs += sum(x > y for x in by[k][a] for y in by[k][b])
        checks += mine
        per_car.append({"campaign": camp, "car": car,
                        "settings": [{"setting": lab[rk], "rank": rk, "n": len(by[k][rk]),
                                      "median": float(np.median(by[k][rk]))} for rk in ranks],
                        "checked": len(mine), "held": sum(c["held"] for c in mine)})
    return {"checked": len(checks), "held": sum(c["held"] for c in checks), "checks": checks,
            "per_car": per_car, "file_pairs_checked": pairs, "file_pairs_held": held_pairs}


# ---------------------------------------------------------------------------
# The study
# ---------------------------------------------------------------------------


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
        (strict JSON: a non-finite number is ``null`` with a note) into ``out`` as a
        whole: everything is written into a hidden staging folder and committed with
        its manifest written last (:func:`avll._atomic.output_dir`); the JSON copy at
        ``json_path`` (when given) is committed in the same step. Ctrl-C at any
        instant leaves the old folder (and JSON) or the complete new ones. Returns
        the paths written."""
        import contextlib

        d = Path(out)
        text = _atomic.dumps(self.summary, indent=1) + "\n"
        names = [*(f"{k}.csv" for k in self.tables), *(f"{k}.png" for k in self.figures),
                 "report.md", "summary.json"]
        stack = contextlib.ExitStack()
        try:
            jtmp = stack.enter_context(_atomic.atomic_path(json_path)) if json_path else None
            stage = stack.enter_context(_atomic.output_dir(
                d, meta={"command": "avll study openacc", "data": self.summary.get("data")}))
            for k, t in self.tables.items():
                t.to_csv(stage / f"{k}.csv", float_format="%.6g")
            for k, fig in self.figures.items():
                fig.savefig(stage / f"{k}.png", dpi=90)
            (stage / "report.md").write_text(self.report, encoding="utf-8")
            (stage / "summary.json").write_text(text, encoding="utf-8")
            if jtmp is not None:
                jtmp.write_text(text, encoding="utf-8")
        except BaseException:
            stack.__exit__(*sys.exc_info())
            raise
        # the folder's commit (manifest last), then the JSON's rename, with Ctrl-C
        # held back until both are done
        with _atomic.deferred_sigint():
            stack.close()
        return [d / n for n in names] + ([Path(json_path)] if json_path else [])


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


_NOTES_CACHE: dict[Path, bool] = {}


def _campaign_root(file: Path) -> Path | None:
    """The nearest folder above ``file`` (up to four levels) holding a campaign's
    notes (``*notes*.txt``), as the JRC distributes every campaign; None if none."""
    for d in [file.parent, *file.parent.parents][:5]:
        if d not in _NOTES_CACHE:
            try:
                _NOTES_CACHE[d] = any(f.is_file() and "notes" in f.name.lower()
                                      and f.suffix.lower() == ".txt" for f in d.iterdir())
            except OSError:
                _NOTES_CACHE[d] = False
        if _NOTES_CACHE[d]:
            return d
    return None


def _acc_of(v: Any) -> bool | None:
    if v is None or isinstance(v, bool):
        return v
    if isinstance(v, (int, np.integer)) and int(v) in (0, 1):
        return bool(v)
    return None


def run_meta(run: Run, root: str | Path | None = None) -> dict[str, Any]:
    """The study's view of a run's ``meta``: ``file``, ``car``, ``setting`` (raw),
    ``setting_rank``, ``acc`` (True / False / None), ``campaign``, ``position``,
    ``track``, ``folder``, ``lead_car``, ``vehicle_index``, ``lead_index``.

    The keys of the native OpenACC loader's contract are used as given. Fallbacks
    for runs that lack them (e.g. canonical runs, or an older loader): ``file`` the
    run id; ``car`` the run id; ``setting`` the raw ``setting_in_file`` when there
    is one; ``setting_rank`` L > M > S (2, 1, 0), None for other settings;
    ``acc`` None (unknown) when the meta does not say; ``campaign`` the meta's
    ``campaign``, else the nearest folder above the file holding the campaign's
    notes (``*notes*.txt``), else ``root``'s name."""
    m = run.meta or {}
    file = str(m.get("file") or run.run_id)
    setting = m["setting_in_file"] if "setting_in_file" in m else m.get("setting")
    if "setting_rank" in m:
        setting = m.get("setting")
    setting = None if setting is None or str(setting).strip() == "" else str(setting)
    rank = _rank_of({**m, "setting": setting})
    camp = m.get("campaign")
    if not camp:
        cr = _campaign_root(Path(file)) if "file" in m else None
        if cr is not None:
            camp = cr.name
        elif root is not None:
            rp = Path(root)
            camp = rp.parent.name if rp.is_file() else rp.name
        else:
            camp = ""
    vi = m.get("vehicle_index")
    pos = m.get("position", vi - 1 if isinstance(vi, int) else None)
    return {"file": file, "car": str(m.get("car") or run.run_id), "setting": setting,
            "setting_rank": rank, "acc": _acc_of(m.get("acc")), "campaign": str(camp),
            "position": int(pos) if isinstance(pos, (int, np.integer)) else None,
            "track": m.get("track"), "folder": str(m.get("folder") or Path(file).parent.name),
            "lead_car": m.get("lead_car"), "vehicle_index": vi,
            "lead_index": m.get("lead_index")}


def _acc_label(acc: bool | None) -> str:
    return {True: "ACC", False: "human", None: "unknown"}[acc]


def _loader_dropped(report: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The stretches the loader dropped, with its reasons: the entries of the
    report's ``stretches`` not marked kept, and of ``dropped`` / ``skipped``, each
    as ``{"file", "car", "reason", "seconds"}`` (``seconds`` None when not said)."""
    out = []
    # the report's stretches, when it has them, hold every dropped stretch (its
    # "skipped" repeats them per follower); else its "dropped" / "skipped" entries
    keys = ("stretches",) if report.get("stretches") is not None else ("dropped", "skipped")
    for key in keys:
        for e in report.get(key) or []:
            if not isinstance(e, Mapping):
                continue
            if key == "stretches" and (e.get("kept") is True or e.get("status") == "kept"):
                continue
            sec = e.get("seconds", e.get("duration_s", e.get("duration")))
            out.append({"file": str(e.get("file", "")), "car": str(e.get("car", "")),
                        "reason": str(e.get("reason", "dropped by the loader")),
                        "seconds": _fin(sec), "by": "loader"})
    return out


def openacc_study(
    path: str | Path | Sequence[Run],
    *,
    model: str = "proposed",
    models: Sequence[str] = _MODELS,
    seed: int = 0,
    threads: int = 0,
    progress: bool | str = False,
    log: Callable[[str], Any] | None = None,
    max_generations: int | None = None,
    pop_size: int | None = None,
    starts: int | None = None,
    band: Sequence[float] = DEFAULT_BAND,
    n_boot: int = N_BOOT,
    block: float = BLOCK,
    gmin_max: float = GMIN_MAX,
    acc_unknown: str = "exclude",
    figures: bool = True,
    out_of_sample: bool = True,
    intervals: Any = True,
    structures: bool | Sequence[str] = True,
    min_gain: float = SELECT_MIN_GAIN,
    alpha: float = SELECT_ALPHA,
    max_structures: int = MAX_STRUCTURES,
    **load_options: Any,
) -> OpenACCStudy:
    """Runs the study (see the module doc) on native OpenACC data at ``path`` (a
    file, a campaign folder as distributed, or a folder of several campaigns), or
    on runs already loaded (a sequence of :class:`~avll.data.Run`; their ``meta``
    read by :func:`run_meta`). ``model`` is the lower-level model of the contract's
    ``params``, ``Tg`` and ``amplification_predicted``; ``models`` are compared
    (``model`` is added if missing). ``max_generations``, ``pop_size`` and
    ``starts`` set the GA budget (``None``: :data:`avll.defaults.GA_OPTIONS` and
    :data:`avll.defaults.DEFAULT_STARTS` independent starts per car);
    ``load_options`` go to the loader (``setting``, ``car``, ``track``, ...).

    ACC state (``meta["acc"]``): runs under ACC (True) are the study's cars; human
    runs (False) are calibrated with the same closed-loop structure and reported
    as a **control** (never counted as ACC: not in the ACC comparisons nor in the
    setting-order check); runs of unknown state (None) are left out and counted
    with ``acc_unknown="exclude"`` (default) or treated as ACC with
    ``"include"``. Ctrl-C raises ``KeyboardInterrupt`` (no partial result).
    ``log`` receives progress lines. ``intervals`` (``True``, ``False`` or an
    :class:`avll.Intervals`) gives the main model's calibrations (in-sample and out
    of sample) their block-bootstrap uncertainty (:mod:`avll.uncertainty`): the
    ``*_ci``, ``params_ci``, ``identified`` and ``string_stable_probability`` keys
    (``null`` with a ``_reason`` without).

    ``structures`` (``True``: :data:`avll.studies.openacc_select.CANDIDATES`, a list
    of candidate names, or ``False``) runs the cross-validated structure selection
    after the out-of-sample step (:func:`avll.studies.openacc_select.select_structures`:
    per car and setting, leave one file out, accepted when the held-out error falls by
    at least ``min_gain`` in most folds and significantly at ``alpha``, greedily up to
    ``max_structures``): the contract's predictions then come from the final model
    (``final_model_effects``), the base model's numbers beside them under
    ``base_model``, and ``structure_selection`` in the summary (its cost in
    ``seconds``)."""
    from ..uncertainty import Intervals

    say = log or (lambda s: None)
    t0 = time.perf_counter()
    iopts = Intervals.of(intervals)
    max_generations = GA_OPTIONS["max_generations"] if max_generations is None else max_generations
    pop_size = GA_OPTIONS["pop_size"] if pop_size is None else pop_size
    starts = DEFAULT_STARTS if starts is None else starts
    models = list(dict.fromkeys([model, *models]))
    for m in models:
        model_class(m)
    if not isinstance(out_of_sample, bool):
        raise ValueError(f"out_of_sample: must be True or False, got {out_of_sample!r}")
    if acc_unknown not in ACC_UNKNOWN:
        raise ValueError(f"acc_unknown: must be one of {', '.join(ACC_UNKNOWN)}, got "
                         f"{acc_unknown!r}")
    if not (isinstance(gmin_max, (int, float)) and gmin_max > 0 and math.isfinite(gmin_max)):
        raise ValueError(f"gmin_max: must be a finite number > 0, got {gmin_max!r}")
    if int(n_boot) < 100:
        raise ValueError(f"n_boot: must be >= 100, got {n_boot!r}")
    if not (block > 0):
        raise ValueError(f"block: must be > 0 s, got {block!r}")
    root: str | Path | None
    if isinstance(path, (str, Path)):
        from ..io.openacc_native import openacc_native_report

        say(f"loading {path}")
        loaded, load_report = openacc_native_report(path, **load_options)
        loaded, load_report = list(loaded), dict(load_report or {})
        root, data = path, str(path)
    else:
        if load_options:
            raise ValueError(f"{', '.join(load_options)}: loader options need a path, not "
                             "runs")
        loaded, load_report, root = list(path), {}, None
        data = f"{len(loaded)} runs given"
        if not all(isinstance(r, Run) for r in loaded):
            raise TypeError("path: expected a file, a folder or a sequence of avll.Run")
    runs: list[Run] = []
    metas: list[dict[str, Any]] = []
    left_out: list[dict[str, Any]] = []
    for r in loaded:
        rm = run_meta(r, root)
        why = None
        if r.lead_x is None or r.lead_v is None or r.v is None or r.x is None:
            why = "no recorded predecessor (lead_x, lead_v) or no own speed and position"
        elif rm["acc"] is None and acc_unknown == "exclude":
            why = "ACC state unknown (left out: --acc-unknown exclude)"
        if why is not None:
            left_out.append({"file": rm["file"], "car": rm["car"], "run_id": r.run_id,
                             "campaign": rm["campaign"], "setting": rm["setting"],
                             "seconds": round((len(r) - 1) * r.dt, 1), "reason": why,
                             "by": "study"})
            continue
        runs.append(r)
        metas.append(rm)
    if not runs:
        n_unk = sum("unknown" in e["reason"] for e in left_out)
        raise ValueError(f"{data}: no run left to study: {len(loaded)} runs loaded, "
                         f"{len(left_out)} left out ({n_unk} of unknown ACC state"
                         + ("; --acc-unknown include would study them" if n_unk else "")
                         + ")")
    for r in runs:
        check_band(band, r.dt)
    runs = [replace(r, upper=UPPER_PLACEHOLDER) for r in runs]
    dropped = _loader_dropped(load_report)
    say(f"{len(runs)} runs in {len({m['file'] for m in metas})} files; {len(left_out)} runs "
        f"left out by the study, {len(dropped)} stretches dropped by the loader")
    # the study's calibration options (closed loop, box, objective, GA budget)
    kw: dict[str, Any] = dict(
        bounds={"Gmin": (0.0, float(gmin_max))}, closed_loop=True, upper_free=_UPPER,
        weights=WEIGHTS, init="rest", max_generations=max_generations, pop_size=pop_size)
    results: dict[str, list[Any]] = {}
    for k, m in enumerate(models):
        say(f"calibrating {m}: {len(runs)} cars in one parallel call "
            f"(GA {max_generations} generations, {starts} start(s) per car)")
        results[m] = _checked(calibrate_many(
            m, runs, "per_run", seed=int(seed) + 1000 * k, threads=threads, progress=progress,
            starts=starts, intervals=iopts if m == model else None, **kw))
    say("measuring and predicting the amplification")
    cars = [_car_entry(i, r, meta, models, model, results, band, n_boot, block, seed)
            for i, (r, meta) in enumerate(zip(runs, metas, strict=True))]
    oos_plan = _oos_plan(metas) if out_of_sample else None
    oos_res: list[Any] = []
    if oos_plan is not None and oos_plan["subsets"]:
        say(f"out of sample: calibrating {model} on each car's other files of its setting "
            f"({len(oos_plan['subsets'])} problems, leave one file out)")
        from ..calibration import start_row

        # each problem starts from its runs' own in-sample optima (finite on each run):
        # a short GA budget then does not end without a finite fit on a problem whose
        # runs each have one
        oos_res = _checked(calibrate_many(
            model, runs, oos_plan["subsets"], seed=int(seed) + 7919, threads=threads,
            progress=progress, starts=starts,
            initial_per_problem=[[start_row(results[model][j]) for j in sub]
                                 for sub in oos_plan["subsets"]],
            intervals=iopts, **kw))  # fmt: skip
    for i, (r, c) in enumerate(zip(runs, cars, strict=True)):
        c.update(_oos_entry(i, r, c, model, oos_plan, oos_res, runs, band))
    for c in cars:
        c["base_model"] = {k: c.get(k) for k in BASE_KEYS}
    selection = None
    if structures is not False and oos_plan is not None and oos_plan["subsets"]:
        selection = _select(model, runs, metas, cars, oos_plan, oos_res, results[model],
                            structures, band=band, seed=seed, threads=threads,
                            progress=progress, iopts=iopts, say=say, kw=kw,
                            min_gain=min_gain, alpha=alpha,
                            max_structures=max_structures)  # fmt: skip
    acc_rows = [{"campaign": c["campaign"], "car": c["car"],
                 "setting": c["setting"] if c["_in_order"] else None,
                 "setting_rank": c["setting_rank"], "Tg": c["Tg"],
                 "time_gap_effective": c["time_gap_effective"],
                 "headway_measured": c["headway_measured"]} for c in cars]
    order = setting_order(acc_rows, "Tg")
    order_eff = setting_order(acc_rows, "time_gap_effective")
    order_meas = setting_order(acc_rows, "headway_measured")
    mixed_rows = [{"campaign": c["campaign"], "car": c["car"],
                   "setting": c["setting"] if c["_acc"] else None,
                   "setting_rank": c["setting_rank"], "Tg": c["Tg"]} for c in cars]
    order_all = setting_order(mixed_rows, "Tg")
    for chk in order["checks"]:
        if not chk["held"]:
            chk["why"] = _why_not(chk, cars)
    comparison = _comparison(cars, models)
    summary: dict[str, Any] = {
        "study": "openacc", "data": data, "model": model, "models": models, "seed": int(seed),
        "ga": {"max_generations": int(max_generations), "pop_size": int(pop_size),
               "starts": int(starts)},
        "objective_weights": list(WEIGHTS), "bounds": {"Gmin": [0.0, float(gmin_max)]},
        "band_hz": [float(band[0]), float(band[1])],
        "trim_s": TRIM, "bootstrap": {"n": int(n_boot), "block_s": float(block),
                                      "level": LEVEL, "min_blocks": MIN_BLOCKS},
        "min_excitation_m_s": MIN_EXCITATION, "acc_unknown": acc_unknown,
        "campaigns": sorted({c["campaign"] for c in cars}),
        "cars": [_public(c) for c in cars],
        "setting_order": {**order,
                          "campaigns": _per_campaign(order),
                          "excluded": "human runs (the control), runs in a folder named "
                                      "'mixed', runs whose setting has no order"},
        "setting_order_effective_time_gap": _short(order_eff),
        "setting_order_measured_headway": _short(order_meas),
        "setting_order_with_mixed": _short(order_all),
        "model_comparison": comparison,
        "estimates": {
            "amplification_measured": "band RMS ratio (follower / predecessor speed), "
                                      "block-bootstrap interval; compared with replays",
            "amplification_measured_h1": "H1 cross-spectral band gain, power-weighted over "
                                         "the band, with coherence and analytic interval "
                                         "(avll.spectral.h1_band_gain); compared with abs H",
            "amplification_predicted": "in-sample: abs H of the model calibrated on this "
                                       "run, on its predecessor's spectrum",
            "amplification_replay": "in-sample: that model replayed on this run",
            "amplification_predicted_oos": "out of sample: abs H of the model calibrated "
                                           "on the car's other files of the same setting",
            "amplification_replay_oos": "out of sample: that model replayed on this run",
        },
        "out_of_sample": _oos_summary(cars, out_of_sample),
        "structure_selection": _selection_summary(cars, selection, structures),
        "car_overview": _car_overview(cars, left_out, dropped),
        "left_out": left_out, "dropped_by_loader": dropped,
        "skipped": load_report.get("skipped", []),
        "non_data_files": [str(e.get("file", e)) if isinstance(e, Mapping) else str(e)
                           for e in load_report.get("non_data") or []],
        "loader_time_s": load_report.get("time_s"),
        "files": _files_summary(runs, cars),
        "name_check": _name_check(runs),
        "poor_fits": _poor_fits(runs, cars),
    }
    tables = _tables(cars, models, model, order, comparison, summary["files"])
    figs = _figures(cars, models, model) if figures else {}
    summary["seconds"] = round(time.perf_counter() - t0, 1)
    report = _report(summary, tables)
    return OpenACCStudy(summary, tables, figs, report, runs, results)


#: The contract's keys of a car computed from the study's model; the base model's
#: values are kept under ``base_model`` (the final model may carry structures).
BASE_KEYS: tuple[str, ...] = (
    "params", "Tg", "cal_mse", "at_bound", "amplification_predicted",
    "amplification_predicted_ci", "amplification_replay", "time_gap_effective",
    "time_gap_effective_ci", "string_stable_probability", "params_ci", "identified",
    "amplification_predicted_oos", "amplification_predicted_oos_ci",
    "amplification_predicted_oos_error", "amplification_replay_oos",
    "amplification_replay_oos_error", "time_gap_effective_oos", "time_gap_effective_oos_ci",
    "string_stable_probability_oos", "oos_params")


def _replace_entry(c: dict[str, Any], new: Mapping[str, Any]) -> None:
    """Updates car ``c`` with ``new``, dropping the stale ``_reason``/``_note`` of every
    key ``new`` recomputes."""
    for k in list(c):
        for sfx in ("_reason", "_note", "_test"):
            if k.endswith(sfx) and k[: -len(sfx)] in new:
                del c[k]
    c.update(new)


def _final_in_sample(i: int, r: Run, fit: Any, main: str, band: Sequence[float]
                     ) -> dict[str, Any]:
    """The in-sample contract keys of run ``i`` from the final model's calibration
    ``fit`` on this run (as :func:`_car_entry` does for the base model)."""
    short = _short_record(len(r), r.dt, band)
    effs, code, a_h, a_r, tge = _predict(main, fit, r, band, short)
    params = dict(fit.params)
    e: dict[str, Any] = {
        "params": params, "Tg": _fin(params["Tg"]), "cal_mse": _fin(float(fit.cost)),
        "at_bound": list(fit.at_bound), "amplification_predicted": _fin(a_h),
        "amplification_replay": _fin(a_r), "time_gap_effective": tge,
        "final_model_effects": list(effs)}
    if e["amplification_predicted"] is None:
        e["amplification_predicted_reason"] = (
            short or ("the final closed loop is locally unstable (every delay exact): abs "
                      "H(jω) is not its gain" if not code else "no periodogram bin"))
    if e["amplification_replay"] is None:
        e["amplification_replay_reason"] = short or "the final closed loop diverges in replay"
    e.update(_interval_entry(fit, r, band, short, ""))
    return e


def _checked(res: list[Any]) -> list[Any]:
    """``res``, the results of a calibration; KeyboardInterrupt when it or an interval's
    resampling was interrupted."""
    if any(r.interrupted or (r.uncertainty is not None and r.uncertainty.interrupted)
           for r in res):
        raise KeyboardInterrupt
    return res


def _select(model: str, runs: Sequence[Run], metas: Sequence[Mapping[str, Any]],
            cars: list[dict[str, Any]], plan: Mapping[str, Any], oos_res: Sequence[Any],
            base_in: Sequence[Any], structures: bool | Sequence[str], *,
            band: Sequence[float], seed: int, threads: int, progress: Any, iopts: Any,
            say: Callable[[str], Any], kw: Mapping[str, Any], min_gain: float, alpha: float,
            max_structures: int) -> Any:
    """The structure stage (``kw``: the study's calibration options): the selection,
    then the final model's fits (out of sample: the selection's fold fits, re-entered
    for their intervals; in sample: each run calibrated with its group's structures,
    warm-started from its base fit and its fold's fit) and the cars' contract keys
    recomputed from them."""
    from ..calibration import start_row
    from .openacc_select import CANDIDATES, select_structures

    cands = CANDIDATES if structures is True else tuple(structures)  # type: ignore[arg-type]
    say(f"structures: cross-validated selection over {', '.join(cands)} "
        f"({len(plan['subsets'])} folds)")
    sel = select_structures(model, runs, plan, oos_res, [_oos_key(m) for m in metas],
                            calibrate_kw={**kw, "progress": progress}, weights=WEIGHTS,
                            candidates=cands, min_gain=min_gain, alpha=alpha,
                            max_structures=max_structures, seed=int(seed) + 3571,
                            threads=threads, log=say)  # fmt: skip
    final_oos = list(oos_res)
    by: dict[tuple[str, ...], list[int]] = {}
    for k, effs in enumerate(sel.effects):
        if effs:
            by.setdefault(effs, []).append(k)
    t0 = time.perf_counter()
    for effs, ks in by.items():
        res = calibrate_many(
            model, runs, [plan["subsets"][k] for k in ks], effects=list(effs),
            initial_per_problem=[[sel.fold_fits[k].x] for k in ks],
            seed=int(seed) + 7927, threads=threads, progress=progress, starts=1,
            intervals=iopts, **{**kw, "max_generations": 1})  # fmt: skip
        for k, f in zip(ks, res, strict=True):
            final_oos[k] = f
    byi: dict[tuple[str, ...], list[int]] = {}
    for i, k in enumerate(plan["problem"]):
        if k is not None and sel.effects[k]:
            byi.setdefault(sel.effects[k], []).append(i)
    final_in: dict[int, Any] = {}
    for effs, idx in byi.items():
        say(f"structures: the final model {'+'.join(effs)} in sample ({len(idx)} runs)")
        res = calibrate_many(
            model, runs, [[i] for i in idx], effects=list(effs),
            initial_per_problem=[[start_row(base_in[i], effs),
                                  sel.fold_fits[plan["problem"][i]].x] for i in idx],
            seed=int(seed) + 15485863, threads=threads, progress=progress, starts=1,
            intervals=iopts, **kw)  # fmt: skip
        if any(f.interrupted for f in res):
            raise KeyboardInterrupt
        for i, f in zip(idx, res, strict=True):
            final_in[i] = f
    for i, (r, c) in enumerate(zip(runs, cars, strict=True)):
        if i in final_in:
            _replace_entry(c, _final_in_sample(i, r, final_in[i], model, band))
            _replace_entry(c, _oos_entry(i, r, c, model, plan, final_oos, runs, band))
        step = [s.to_dict() for s in sel.steps if (s.campaign, s.car, s.setting) ==
                tuple(_oos_key(metas[i]) or (None, None, None))[:3]]
        c["structures"] = {"accepted": list(c["final_model_effects"]), "steps": step}
    return sel, time.perf_counter() - t0


def _selection_summary(cars: Sequence[Mapping[str, Any]], sel: Any,
                       structures: bool | Sequence[str]) -> dict[str, Any]:
    """The structure stage in the summary: the selection's settings and steps, which
    structures were accepted for which cars, and the out-of-sample amplification
    bias before (base model) and after (final model)."""
    if sel is None:
        return {"enabled": False, "reason": (
            "not run (structures=False)" if structures is False
            else "not run: no car has another file of its setting (no fold), or the "
                 "out-of-sample step is off (out_of_sample=False)")}
    s, final_seconds = sel
    out: dict[str, Any] = {"enabled": True, **s.to_dict(),
                           "final_fits_seconds": round(final_seconds, 1)}
    out["accepted"] = [{"campaign": c["campaign"], "car": c["car"], "setting": c["setting"],
                        "file": c["file"], "effects": c["final_model_effects"]}
                       for c in cars if c["final_model_effects"]]
    flat = [{**c, **c["base_model"]} for c in cars]
    for grp in ("acc", "human"):
        out[grp] = {
            "base_oos_H_vs_h1": _vs(flat, "amplification_predicted_oos", *_H1, grp,
                                    "amplification_predicted_oos_ci"),
            "final_oos_H_vs_h1": _vs(cars, "amplification_predicted_oos", *_H1, grp,
                                     "amplification_predicted_oos_ci")}
    return out


def _per_campaign(order: Mapping[str, Any]) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for c in order["checks"]:
        d = out.setdefault(c["campaign"], {"checked": 0, "held": 0})
        d["checked"] += 1
        d["held"] += int(c["held"])
    return out


def _car_overview(cars: Sequence[Mapping[str, Any]], left_out: Sequence[Mapping[str, Any]],
                  dropped: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per campaign and car model: the raw settings and their order, the ACC state
    of the runs studied, the runs (stretches) studied and those left out or dropped,
    with the reasons."""
    camp_of_file = {c["file"]: c["campaign"] for c in cars}
    camp_of_file.update({e["file"]: e["campaign"] for e in left_out})
    keys = ({(c["campaign"], c["car"]) for c in cars}
            | {(e["campaign"], e["car"]) for e in left_out}
            | {(camp_of_file.get(e["file"], ""), e["car"]) for e in dropped})
    out = []
    for camp, car in sorted(keys):
        mine = [c for c in cars if (c["campaign"], c["car"]) == (camp, car)]
        gone = [e for e in left_out if (e["campaign"], e["car"]) == (camp, car)]
        gone += [e for e in dropped
                 if (camp_of_file.get(e["file"], ""), e["car"]) == (camp, car)]
        settings = sorted({(c["setting"], c["setting_rank"]) for c in mine},
                          key=lambda sr: (-1 if sr[1] is None else sr[1], str(sr[0])))
        out.append({"campaign": camp, "car": car,
                    "settings": [{"setting": st, "setting_rank": rk} for st, rk in settings],
                    "acc": dict(Counter(_acc_label(c["acc"]) for c in mine)),
                    "runs_studied": len(mine),
                    "seconds_studied": round(sum(c["duration_s"] for c in mine), 1),
                    "runs_left_out": len(gone),
                    "seconds_left_out": round(sum(e["seconds"] or 0.0 for e in gone), 1),
                    "reasons_left_out": dict(Counter(e["reason"] for e in gone))})
    return out


def _name_check(runs: Sequence[Run]) -> dict[str, Any]:
    """Evidence that the vehicle numbers index ``Vehicle_order``: the constant
    ``distance − IVS`` of a pair of named cars, compared across the files where the
    same two names follow each other (consistent: within 5 cm)."""
    by: dict[str, list[tuple[str, float]]] = {}
    for r in runs:
        off = r.meta.get("ivs_offset")
        if off is None:
            continue
        key = f"{r.meta.get('lead_car')} -> {r.meta.get('car')}"
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
               if c["_acc"] == acc and c["cal_mse"] is not None]
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


def _short_record(n: int, dt: float, band: Sequence[float]) -> str | None:
    """Why a record of ``n`` samples is too short for the band's measures (None if
    it is not): after :data:`TRIM` seconds cut at each end it must hold one period
    of the band's low edge."""
    k = int(round(TRIM / dt))
    m = n - 2 * k
    need = max(int(math.ceil(1.0 / (float(band[0]) * dt))), 21)
    if m >= need:
        return None
    return (f"the run is too short: {(n - 1) * dt:.1f} s, {max(m - 1, 0) * dt:.1f} s after cutting "
            f"{TRIM:g} s at each end (filter edges), less than one period of the band's low "
            f"edge ({1.0 / float(band[0]):g} s)")


def measured_amplification(v: np.ndarray, lead_v: np.ndarray, dt: float, *,
                           band: Sequence[float] = DEFAULT_BAND, block: float = BLOCK,
                           n_boot: int = N_BOOT, seed: Any = 0) -> dict[str, Any]:
    """The measured amplification with its bootstrap interval, for a record of any
    length: ``{"amplification", "ci", "rms_follower", "rms_predecessor"}`` plus
    ``amplification_reason`` / ``ci_reason`` where a value is None. No amplification
    when the record is too short (:func:`_short_record`) or the predecessor does not
    excite (:data:`MIN_EXCITATION`); no interval when the trimmed record holds fewer
    than :data:`MIN_BLOCKS` blocks of ``block`` seconds (every resample would be
    nearly the record itself) or the resamples' interval collapses."""
    out: dict[str, Any] = {"amplification": None, "ci": [None, None],
                           "rms_follower": None, "rms_predecessor": None}
    short = _short_record(len(v), dt, band)
    if short is not None:
        out["amplification_reason"] = out["ci_reason"] = short
        return out
    bf, bp = bandpass(v, dt, band), bandpass(lead_v, dt, band)
    rf, rp = _rms(bf), _rms(bp)
    out["rms_follower"], out["rms_predecessor"] = _fin(rf), _fin(rp)
    if not (rp >= MIN_EXCITATION):
        out["amplification_reason"] = out["ci_reason"] = (
            f"the predecessor does not excite: its band RMS speed is {rp:.3f} m/s < "
            f"{MIN_EXCITATION:g} m/s (GNSS speed noise level)")
        return out
    out["amplification"] = _fin(rf / rp)
    lb = max(1, int(round(block / dt)))
    if bf.shape[0] < MIN_BLOCKS * lb:
        out["ci_reason"] = (f"too short for the block bootstrap: {bf.shape[0] * dt:.1f} s "
                            f"after the trim, fewer than {MIN_BLOCKS} blocks of {block:g} s")
        return out
    lo, hi = bootstrap_ci(bf, bp, dt, block=block, n=n_boot, seed=seed)
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        out["ci_reason"] = f"the bootstrap interval collapsed ({lo:.6g}, {hi:.6g})"
        return out
    out["ci"] = [lo, hi]
    return out


def _h1_entry(r: Run, band: Sequence[float], short: str | None,
              reasons: dict[str, str]) -> dict[str, Any]:
    """The H1 band gain of the car's predecessor -> own speed
    (:func:`avll.spectral.h1_band_gain`): ``amplification_measured_h1``, its 95 %
    interval ``amplification_measured_h1_ci`` and the band's power-weighted
    ``coherence``; each None with its reason in ``reasons``."""
    from ..spectral import h1_band_gain

    out: dict[str, Any] = {"amplification_measured_h1": None,
                           "amplification_measured_h1_ci": None, "coherence": None}
    if short is not None:
        reasons.update(dict.fromkeys(out, short))
        return out
    assert r.v is not None and r.lead_v is not None
    g = h1_band_gain(r.lead_v, r.v, r.dt, band)
    gain = out["amplification_measured_h1"] = _fin(g.gain)
    if gain is None:
        reasons["amplification_measured_h1"] = g.reason or "the H1 band gain is not finite"
    ci = g.ci
    if gain is not None and ci is not None and all(_fin(x) is not None for x in ci):
        out["amplification_measured_h1_ci"] = [float(ci[0]), float(ci[1])]
    else:
        reasons["amplification_measured_h1_ci"] = (
            g.ci_reason or g.reason or "no interval for the H1 band gain")
    out["coherence"] = _fin(g.coherence)
    if out["coherence"] is None:
        reasons["coherence"] = g.reason or "the band's coherence is not finite"
    return out


def _car_entry(i: int, r: Run, meta: Mapping[str, Any], models: Sequence[str], main: str,
               results: Mapping[str, list[Any]], band: Sequence[float], n_boot: int,
               block: float, seed: int) -> dict[str, Any]:
    assert r.v is not None and r.lead_v is not None
    is_acc = meta["acc"] is not False
    e: dict[str, Any] = {
        "file": meta["file"], "run_id": r.run_id, "campaign": meta["campaign"],
        "car": meta["car"], "setting": meta["setting"], "setting_rank": meta["setting_rank"],
        "acc": meta["acc"], "group": "acc" if is_acc else "human",
        "position": meta["position"], "track": meta["track"], "folder": meta["folder"],
        "lead_car": meta["lead_car"], "vehicle_index": meta["vehicle_index"],
        "lead_index": meta["lead_index"], "duration_s": round((len(r) - 1) * r.dt, 1),
        "speed_mean": float(np.mean(r.v)), "speed_std": float(np.std(r.v)),
        "_acc": is_acc,
        "_in_order": bool(is_acc and meta["setting_rank"] is not None
                          and str(meta["folder"]).lower() != "mixed"),
    }
    reasons: dict[str, str] = {}
    ma = measured_amplification(r.v, r.lead_v, r.dt, band=band, block=block, n_boot=n_boot,
                                seed=[int(seed), i])
    e["rms_follower"], e["rms_predecessor"] = ma["rms_follower"], ma["rms_predecessor"]
    for key, src in (("amplification_measured", "amplification"),
                     ("amplification_measured_ci", "ci")):
        e[key] = ma[src]
        if f"{src}_reason" in ma:
            reasons[key] = ma[f"{src}_reason"]
    short = _short_record(len(r), r.dt, band)
    e.update(_h1_entry(r, band, short, reasons))
    e["headway_measured"] = _headway(r)
    per: dict[str, Any] = {}
    for m in models:
        res = results[m][i]
        effs, code, a_h, a_r, tge = _predict(m, res, r, band, short)
        cost = float(res.cost)
        d: dict[str, Any] = {
            "params": dict(res.params), "cal_mse": _fin(cost), "at_bound": list(res.at_bound),
            "amplification_H": _fin(a_h), "amplification_replay": _fin(a_r),
            "time_gap_effective": tge,
            "per_run_mse": _fin(res.per_run_mse.get(r.run_id, math.nan)),
            "local_stable": code > 0, "string_stable": (code == 2) if code else None,
        }
        if not code:
            d["string_stable_reason"] = "the calibrated closed loop is locally unstable"
        if not math.isfinite(cost):
            d["cal_mse_reason"] = "every parameter set of the search was unstable"
        if short is not None:
            d["amplification_replay_reason"] = d["amplification_H_reason"] = short
        else:
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
        if m == main:
            main_effs = list(effs)
    mm = per[main]
    e["params"] = mm["params"]
    e["Tg"] = _fin(mm["params"]["Tg"])
    for key, src in (("cal_mse", "cal_mse"), ("amplification_predicted", "amplification_H"),
                     ("amplification_replay", "amplification_replay")):
        e[key] = mm[src]
        if e[key] is None:
            reasons[key] = mm.get(f"{src}_reason", "not finite")
    e["time_gap_effective"] = mm["time_gap_effective"]
    e["at_bound"] = mm["at_bound"]
    e["final_model_effects"] = main_effs
    e.update(_interval_entry(results[main][i], r, band, short, ""))
    e["models"] = per
    e.update({f"{k}_reason": v for k, v in reasons.items()})
    return e


#: Why a prediction has no interval when the study runs without intervals.
INTERVALS_OFF = "intervals not estimated (the study ran with intervals=False)"
#: The method of the predictions' intervals.
OOS_CI_REASON = ("95 % intervals of a moving-block bootstrap over time of the calibration "
                 "(blocks from the fit's score series), each resample refit by a local "
                 "search from the full-data optimum, the deviations widened by the "
                 "small-sample correction for the parameters fitted (avll.uncertainty)")


def _oos_key(meta: Mapping[str, Any]) -> tuple[Any, ...] | None:
    """The car's out-of-sample group: campaign, car, setting (its rank, else the raw
    setting) and ACC state; None when the setting is unknown."""
    st = meta["setting_rank"] if meta["setting_rank"] is not None else meta["setting"]
    if st is None:
        return None
    return (meta["campaign"], meta["car"], st, meta["acc"] is not False)


def _oos_plan(metas: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Leave one file out: per run, the runs of the same group (:func:`_oos_key`)
    from OTHER files (``others``, None with ``reasons`` when there is none), and
    the distinct calibration problems (``subsets``, run indices) with each run's
    problem (``problem``)."""
    groups: dict[tuple[Any, ...], list[int]] = {}
    for i, m in enumerate(metas):
        k = _oos_key(m)
        if k is not None:
            groups.setdefault(k, []).append(i)
    subsets: list[list[int]] = []
    index: dict[tuple[int, ...], int] = {}
    problem: list[int | None] = []
    reasons: list[str | None] = []
    for m in metas:
        k = _oos_key(m)
        if k is None:
            problem.append(None)
            reasons.append("the run's setting is unknown: no other file of the same setting")
            continue
        others = tuple(j for j in groups[k] if metas[j]["file"] != m["file"])
        if not others:
            problem.append(None)
            reasons.append(f"no other file of the same setting for this car ({m['car']}, "
                           f"setting {m['setting']}, {_acc_label(m['acc'])}, campaign "
                           f"{m['campaign'] or '–'}) to calibrate on")
            continue
        if others not in index:
            index[others] = len(subsets)
            subsets.append(list(others))
        problem.append(index[others])
        reasons.append(None)
    return {"subsets": subsets, "problem": problem, "reasons": reasons}


def _oos_entry(i: int, r: Run, car: Mapping[str, Any], main: str,
               plan: Mapping[str, Any] | None, res: Sequence[Any], runs: Sequence[Run],
               band: Sequence[float]) -> dict[str, Any]:
    """The held-out prediction of run ``i`` from the model calibrated on its car's
    other files of the same setting: ``amplification_predicted_oos`` (abs H of that
    model on this run's predecessor spectrum, to compare with the H1 measured gain),
    ``amplification_replay_oos`` (that model replayed behind this run's predecessor,
    to compare with the measured RMS ratio), ``time_gap_effective_oos`` (its
    ``Tg + Gmin / v̄`` at this run's mean speed), their errors and ``_ci`` (None
    with a reason), ``oos_files`` and ``oos_params``; each None with a ``_reason``."""
    keys = ("amplification_predicted_oos", "amplification_replay_oos", "time_gap_effective_oos",
            "amplification_predicted_oos_ci", "time_gap_effective_oos_ci")
    e: dict[str, Any] = {**dict.fromkeys((*keys, "amplification_predicted_oos_error",
                                          "amplification_replay_oos_error")),
                         "oos_files": [], "oos_params": None}
    why = ("out-of-sample step not run (out_of_sample=False)" if plan is None
           else plan["reasons"][i])
    if why is not None:
        e.update({f"{k}_reason": why for k in keys})
        return e
    assert plan is not None
    k = plan["problem"][i]
    fit = res[k]
    short = _short_record(len(r), r.dt, band)
    effs, code, a_h, a_r, tge = _predict(main, fit, r, band, short)
    e["final_model_effects_oos"] = list(effs)
    e["oos_files"] = sorted({str(runs[j].meta.get("file") or runs[j].run_id)
                             for j in plan["subsets"][k]})
    e["oos_params"] = dict(fit.params)
    e["oos_at_bound"] = list(fit.at_bound)
    e["time_gap_effective_oos"] = tge
    if tge is None:
        e["time_gap_effective_oos_reason"] = "not finite"
    e["string_stable_oos"] = (code == 2) if code else None
    e["amplification_predicted_oos"] = _fin(a_h)
    e["amplification_replay_oos"] = _fin(a_r)
    if short is not None:
        e["amplification_predicted_oos_reason"] = e["amplification_replay_oos_reason"] = short
    else:
        if not code:
            e["amplification_predicted_oos_reason"] = (
                "the out-of-sample closed loop is locally unstable (true delay): abs H(jω) "
                "is not its gain")
            e["string_stable_oos_reason"] = "the out-of-sample closed loop is locally unstable"
        elif e["amplification_predicted_oos"] is None:
            e["amplification_predicted_oos_reason"] = "no periodogram bin in the band"
        if e["amplification_replay_oos"] is None:
            e["amplification_replay_oos_reason"] = ("the out-of-sample closed loop diverges "
                                                    "in replay")
    h1, ratio = car["amplification_measured_h1"], car["amplification_measured"]
    if e["amplification_predicted_oos"] is not None and h1:
        e["amplification_predicted_oos_error"] = e["amplification_predicted_oos"] / h1 - 1.0
    if e["amplification_replay_oos"] is not None and ratio:
        e["amplification_replay_oos_error"] = e["amplification_replay_oos"] / ratio - 1.0
    iv = _interval_entry(fit, r, band, short, "_oos")
    for key in ("amplification_predicted_oos_ci", "time_gap_effective_oos_ci"):
        e[key] = iv[key]
        if f"{key}_reason" in iv:
            e[f"{key}_reason"] = iv[f"{key}_reason"]
    if e["amplification_predicted_oos"] is None and e["amplification_predicted_oos_ci"]:
        e["amplification_predicted_oos_ci"] = None
        e["amplification_predicted_oos_ci_reason"] = e.get(
            "amplification_predicted_oos_reason", "no prediction")
    e["string_stable_probability_oos"] = iv["string_stable_probability_oos"]
    return e


def _predict(name: str, fit: Any, r: Run, band: Sequence[float], short: str | None
             ) -> tuple[tuple[str, ...], int, float, float, float | None]:
    """A calibration's predictions for run ``r``: the effects its model carries (empty:
    the base model), the stability code (:func:`_stability_code`), the band
    amplification of ``|H|`` (NaN when locally unstable or ``short``) and of the replay
    (NaN when ``short``), and the effective time gap at ``r``'s mean speed (None when
    not finite). The one place the study turns a calibration into the closed loop it
    predicts with: the lower-level model, or an :class:`avll.WithEffects` when the
    calibration carries structures, behind the calibrated upper law."""
    assert r.lead_v is not None and r.v is not None
    mod: Any = _model_of(name, fit.params)
    up, effs = _upper_of(fit.params), ()
    if getattr(fit, "with_effects", None) is not None and fit.with_effects.effect_names:
        mod, effs = fit.with_effects, tuple(fit.with_effects.effect_names)
    code = _stability_code(mod, up, float(np.mean(r.lead_v)))
    a_h = (predicted_amplification(mod, up, r.lead_v, r.dt, band)
           if code and short is None else math.nan)
    a_r = replay_amplification(mod, up, r, band)[0] if short is None else math.nan
    return effs, code, a_h, a_r, _fin(time_gap_effective(mod, up, float(np.mean(r.v))))


def time_gap_effective(model: Any, up: UpperLevel, v: float) -> float:
    """``Tg + Gmin / v̄`` of the law ``up`` at the mean speed ``v`` (at least 0.1 m/s):
    with structures (``model`` an :class:`avll.WithEffects`), their equilibrium time gap
    (:meth:`avll.WithEffects.upper_linear`'s ``Tg_eq``, e.g. ``Tg + ch v`` of
    ``speed_gains``) in place of ``Tg``. The one definition the study reports and the
    synthetic truths and validations (:mod:`avll.synth_platoon`) use;
    :meth:`avll.Uncertainty.time_gap_effective` gives the same of a calibration with
    its resamples."""
    from ..effects import WithEffects

    vv = max(float(v), 0.1)
    if isinstance(model, WithEffects) and model.effects:
        return float(model.upper_linear(up, v=vv)["Tg_eq"] + up.Gmin / vv)
    return float(up.Tg + up.Gmin / vv)


def _stability_code(model: Any, up: UpperLevel, v: float) -> int:
    """The closed loop's stability code (0 locally unstable, 1 string unstable, 2
    string stable): the exact one-delay test for a base model, the certified test of
    every delay (linearised at ``v``) with structures; an undecided test gives 0 or 1."""
    from ..effects import WithEffects

    if isinstance(model, WithEffects) and model.effects:
        from ..effect_stability import stability_codes_rows

        row = np.concatenate([model.to_array(), up.to_array()])[None, :]
        c, _ = stability_codes_rows(model.base, row, effects=list(model.effect_names),
                                    v=float(v))
        return int(c[0])
    base = model.base if isinstance(model, WithEffects) else model
    codes, _settled = exact_delay_codes(base, up.kg, up.Tg, up.kv)
    return int(codes[0])


def _interval_entry(fit: Any, r: Run, band: Sequence[float], short: str | None,
                    sfx: str) -> dict[str, Any]:
    """The 95 % intervals of a calibration's predictions for run ``r`` from its
    uncertainty (:attr:`avll.CalibrationResult.uncertainty`): the band amplification
    on ``r``'s predecessor spectrum, the effective time gap at ``r``'s mean speed, the
    probability of string stability, and (in-sample, ``sfx == ""``) ``params_ci`` and
    ``identified``; each None with a ``_reason`` where none can be computed."""
    keys = [f"amplification_predicted{sfx}_ci", f"time_gap_effective{sfx}_ci",
            "string_stable_probability" + sfx]
    if not sfx:
        keys += ["params_ci", "identified"]
    e: dict[str, Any] = dict.fromkeys(keys)
    u = getattr(fit, "uncertainty", None)
    if u is None:
        e.update({f"{k}_reason": INTERVALS_OFF for k in keys})
        return e
    assert r.v is not None and r.lead_v is not None
    ok = np.isfinite(u.samples).all(axis=1)
    if not ok.any():
        why = ("undetermined: the record holds fewer effective blocks than fitted "
               f"parameters ({u.blocks:.1f} blocks, {u.fitted} parameters)"
               if not math.isfinite(u.widening) else "no resample could be refit")
        e.update({f"{k}_reason": why for k in keys})
        return e
    tge0, tge = u.time_gap_effective(float(np.mean(r.v)))
    e[f"time_gap_effective{sfx}_ci"] = _ci(tge0, tge, u.level)
    if e[f"time_gap_effective{sfx}_ci"] is None:
        e[f"time_gap_effective{sfx}_ci_reason"] = (
            u.gap_loop_reason() if u.gap_loop_too_slow() else "not finite")
    key = f"amplification_predicted{sfx}_ci"
    if short is not None:
        e[f"{key}_reason"] = short
    else:
        amp0, amp = u.band_amplification(r.lead_v, r.dt, band)
        e[key] = _ci(amp0, amp, u.level)
        if e[key] is None:
            bad = int(np.isnan(amp).sum())
            e[f"{key}_reason"] = (f"{bad} of {amp.size} resampled closed loops are locally "
                                  "unstable (an interval needs two stable ones)")
        elif np.isnan(amp).any():
            e[f"{key}_note"] = (f"{int(np.isnan(amp).sum())} of {amp.size} resampled closed "
                                "loops are locally unstable and left out")
    p = u.string_stable_probability
    e["string_stable_probability" + sfx] = _fin(p) if p is not None else None
    if p is None:
        e[f"string_stable_probability{sfx}_reason"] = "not computed (open loop)"
    else:
        e[f"string_stable_probability{sfx}_test"] = u.string_test
    if not sfx:
        e["params_ci"] = dict(u.to_dict()["params_ci"])
        e["identified"] = u.identified()
    return e


def _ci(estimate: float, samples: np.ndarray, level: float) -> list[float] | None:
    """The symmetric interval about ``estimate`` of the finite samples
    (:func:`avll.uncertainty.symmetric_interval`), or None with fewer than two."""
    if int(np.isfinite(np.asarray(samples, dtype=np.float64)).sum()) < 2:
        return None
    lo, hi = symmetric_interval(float(estimate), samples, level)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    return [lo, hi]


#: The measurements (and their intervals) the predictions are compared with: the H1
#: band gain for ``|H|``, the band RMS ratio for a replay.
_H1 = ("amplification_measured_h1", "amplification_measured_h1_ci")
_RATIO = ("amplification_measured", "amplification_measured_ci")


def _vs(cars: Sequence[Mapping[str, Any]], pred: str, meas: str, ci: str | None,
        group: str, pred_ci: str | None = None) -> dict[str, Any]:
    """A prediction ``pred`` against a measurement ``meas`` (its interval ``ci``) over
    the cars of ``group`` with both: ``n``, ``mean_error`` (bias of
    ``pred / meas - 1``), ``median_abs_error``, ``within_10pct`` and
    ``inside_measured_ci`` (shares; None when n is 0), ``underestimated`` (count);
    with ``pred_ci`` (the prediction's interval) ``measured_inside_predicted_ci``, the
    share of the measurements inside it."""
    cs = [c for c in cars if c["group"] == group and c.get(pred) is not None
          and c.get(meas)]
    err = np.asarray([c[pred] / c[meas] - 1.0 for c in cs], dtype=float)
    with_ci = [c for c in cs if ci is not None and c.get(ci) is not None
               and c[ci][0] is not None]
    inside = [c[ci][0] <= c[pred] <= c[ci][1] for c in with_ci] if ci else []
    return {"prediction": pred, "measurement": meas, "interval": ci, "group": group,
            "n": int(err.size),
            "mean_error": _fin(np.mean(err)) if err.size else None,
            "median_abs_error": _fin(np.median(np.abs(err))) if err.size else None,
            "within_10pct": _fin(np.mean(np.abs(err) <= 0.10)) if err.size else None,
            "within_10pct_count": int(np.sum(np.abs(err) <= 0.10)),
            "underestimated": int(np.sum(err < 0)),
            "n_with_interval": len(with_ci),
            "inside_measured_ci": _fin(np.mean(inside)) if inside else None,
            "inside_measured_ci_count": int(np.sum(inside)) if inside else 0,
            **_inside_predicted(cs, pred_ci, meas)}


def _inside_predicted(cs: Sequence[Mapping[str, Any]], pred_ci: str | None, meas: str
                      ) -> dict[str, Any]:
    """The share (and count) of measurements ``meas`` inside the prediction's interval
    ``pred_ci`` over the cars ``cs`` that have one; the intervals' median relative width."""
    if pred_ci is None:
        return {}
    w = [c for c in cs if c.get(pred_ci) is not None]
    inside = [c[pred_ci][0] <= c[meas] <= c[pred_ci][1] for c in w]
    width = [(c[pred_ci][1] - c[pred_ci][0]) / c[meas] for c in w]
    return {"prediction_interval": pred_ci, "n_with_prediction_interval": len(w),
            "measured_inside_predicted_ci": _fin(np.mean(inside)) if inside else None,
            "measured_inside_predicted_ci_count": int(np.sum(inside)),
            "prediction_interval_median_rel_width": _fin(np.median(width)) if width else None}


def _rel(cars: Sequence[Mapping[str, Any]], a: str, b: str, group: str,
         a_ci: str | None = None, b_identified: bool = False) -> dict[str, Any]:
    """``a / b - 1`` over the cars of ``group`` with both finite: ``n``, ``mean`` and
    ``median_abs``; with ``a_ci`` (``a``'s interval) the share of ``b`` inside it. With
    ``b_identified`` only the cars whose ``b`` the data determine (``b`` in the car's
    ``identified``; a car without intervals is kept): a value the data leave open, e.g.
    a corner fit's ``Tg + Gmin / v̄`` near zero, is no reference, and one such ratio
    outweighs all others in the mean (``left_out_unidentified`` counts them)."""
    both = [c for c in cars if c["group"] == group and c.get(a) is not None
            and c.get(b) is not None and math.isfinite(c[b]) and c[b] > 0]
    cs = [c for c in both if not b_identified or c.get("identified") is None
          or b in c["identified"]]
    d = np.asarray([c[a] / c[b] - 1.0 for c in cs], dtype=float)
    return {"a": a, "b": b, "n": int(d.size), "mean_rel_diff": _fin(np.mean(d)) if d.size
            else None, "median_abs_rel_diff": _fin(np.median(np.abs(d))) if d.size else None,
            "within_10pct_count": int(np.sum(np.abs(d) <= 0.10)),
            "left_out_unidentified": len(both) - len(cs),
            **_inside_predicted(cs, a_ci, b)}


def _oos_summary(cars: Sequence[Mapping[str, Any]], enabled: bool) -> dict[str, Any]:
    """The out-of-sample headline and its in-sample counterparts, like with like:
    abs H of the model on the predecessor's spectrum vs the H1 measured gain; a
    replay vs the measured band RMS ratio; per group (ACC, human)."""
    out: dict[str, Any] = {
        "enabled": bool(enabled),
        "method": "leave one file out: one model per car (campaign, car, setting, ACC "
                  "state) calibrated on the car's other files of the same setting, all "
                  "together, predicting the held-out file",
        "cars_with_prediction": sum(c["amplification_predicted_oos"] is not None
                                    for c in cars),
        "cars_with_time_gap_oos": sum(c["time_gap_effective_oos"] is not None for c in cars),
        "cars_without_other_file": sum(not c["oos_files"] for c in cars),
        "interval_method": OOS_CI_REASON,
    }
    for grp in ("acc", "human"):
        out[grp] = {
            "oos_H_vs_h1": _vs(cars, "amplification_predicted_oos", *_H1, grp,
                               "amplification_predicted_oos_ci"),
            "in_sample_H_vs_h1": _vs(cars, "amplification_predicted", *_H1, grp,
                                     "amplification_predicted_ci"),
            "oos_replay_vs_ratio": _vs(cars, "amplification_replay_oos", *_RATIO, grp),
            "in_sample_replay_vs_ratio": _vs(cars, "amplification_replay", *_RATIO, grp),
        }
        out[grp]["time_gap_effective_oos_vs_in_sample"] = _rel(
            cars, "time_gap_effective_oos", "time_gap_effective", grp, b_identified=True)
        # the model-free counterpart: the median measured time headway (gap / speed)
        out[grp]["time_gap_effective_oos_vs_headway_measured"] = _rel(
            cars, "time_gap_effective_oos", "headway_measured", grp,
            "time_gap_effective_oos_ci")
        out[grp]["time_gap_effective_in_sample_vs_headway_measured"] = _rel(
            cars, "time_gap_effective", "headway_measured", grp, "time_gap_effective_ci")
    return out


def _oos_lines(s: Mapping[str, Any]) -> list[str]:
    """The report's out-of-sample section (the headline), with its in-sample
    counterparts, like with like."""
    o = s["out_of_sample"]
    lines = ["## Out of sample (headline)", ""]
    if not o["enabled"]:
        return lines + ["Not run (out_of_sample=False).", ""]
    lines += [
        f"Method: {o['method']}. Cars with a held-out prediction: "
        f"{o['cars_with_prediction']}; without another file of their setting: "
        f"{o['cars_without_other_file']}. Like with like: abs H(jω) of a model on the "
        "held-out run's predecessor spectrum is compared with the H1 cross-spectral band "
        "gain (95 % analytic interval); a model's replay with the band RMS ratio (95 % "
        f"block-bootstrap interval). The predictions' intervals: {o['interval_method']}.",
        ""]
    labels = (("oos_H_vs_h1", "out of sample: abs H vs H1"),
              ("in_sample_H_vs_h1", "in-sample: abs H vs H1"),
              ("oos_replay_vs_ratio", "out of sample: replay vs RMS ratio"),
              ("in_sample_replay_vs_ratio", "in-sample: replay vs RMS ratio"))
    rows = [[grp, lab, d["n"], _f(d["mean_error"], 3), _f(d["median_abs_error"], 3),
             d["within_10pct_count"],
             f"{d['inside_measured_ci_count']} of {d['n_with_interval']}"
             if d["n_with_interval"] else "–",
             f"{d['measured_inside_predicted_ci_count']} of {d['n_with_prediction_interval']}"
             if d.get("n_with_prediction_interval") else "–", d["underestimated"]]
            for grp in ("acc", "human") for key, lab in labels
            for d in (o[grp][key],) if d["n"]]
    lines.append(md_table(
        ["cars", "comparison", "n", "mean error (bias)", "median abs error", "within 10 %",
         "inside the measured 95 % interval", "measured inside the predicted 95 % interval",
         "under-estimated"], rows))
    tl = (("time_gap_effective_oos_vs_headway_measured", "out of sample vs the measured "
           "headway (median gap / speed, no model)"),
          ("time_gap_effective_in_sample_vs_headway_measured", "in-sample vs the measured "
           "headway"),
          ("time_gap_effective_oos_vs_in_sample", "out of sample vs in-sample"))
    parts = [f"{lab}: n {t['n']}, mean relative difference {_f(t['mean_rel_diff'], 3)}, "
             f"median absolute {_f(t['median_abs_rel_diff'], 3)}, within 10 % "
             f"{t['within_10pct_count']}"
             + (f", measured inside the predicted 95 % interval "
                f"{t['measured_inside_predicted_ci_count']} of "
                f"{t['n_with_prediction_interval']}" if t.get("n_with_prediction_interval")
                else "")
             + (f" ({t['left_out_unidentified']} cars whose in-sample value the data do not "
                "determine left out)" if t.get("left_out_unidentified") else "")
             for key, lab in tl
             for t in (o["acc"][key],) if t["n"]]
    if parts:
        lines += ["", "Effective time gap Tg + Gmin/v̄ at the held-out run's mean speed (ACC "
                  "cars): " + "; ".join(parts) + "."]
    return lines + [""]


def _public(c: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in c.items() if not k.startswith("_")}


def _why_not(chk: Mapping[str, Any], cars: Sequence[Mapping[str, Any]]) -> str:
    """A reason, from the numbers, why a setting check failed."""
    car, camp = chk["car"], chk["campaign"]
    ranks = {chk["longer"]: chk["rank_longer"], chk["shorter"]: chk["rank_shorter"]}
    mine = [c for c in cars if c["car"] == car and c["campaign"] == camp and c["_in_order"]
            and c["setting_rank"] in ranks.values()]
    parts = []
    for st in (chk["longer"], chk["shorter"]):
        cs = [c for c in mine if c["setting_rank"] == ranks[st]]
        desc = ", ".join(
            f"{c['run_id']} Tg {_f(c['Tg'])} s, Gmin {_f(c['params']['Gmin'], 1)} m, "
            f"Tg+Gmin/v {_f(c['time_gap_effective'])} s, measured headway "
            f"{_f(c['headway_measured'])} s, speed {c['speed_mean']:.1f}±{c['speed_std']:.1f} "
            f"m/s" + (f", at bound: {'/'.join(c['at_bound'])}" if c["at_bound"] else "")
            for c in cs)
        parts.append(f"{st}: {desc}")

    def med(key: str) -> dict[str, Any]:
        return {st: np.median([c[key] for c in mine if c["setting_rank"] == ranks[st]
                               and c[key] is not None and math.isfinite(c[key])] or [np.nan])
                for st in (chk["longer"], chk["shorter"])}

    eff, hw = med("time_gap_effective"), med("headway_measured")
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
    acc = [c for c in cars if c["_acc"] and c["amplification_measured"] is not None]
    human = [c for c in cars if not c["_acc"] and c["amplification_measured"] is not None]
    for m in models:
        d: dict[str, Any] = {}
        for key in ("amplification_H", "amplification_replay"):
            for grp, cs in (("acc", acc), ("human", human)):
                have = [c for c in cs if c["models"][m][f"{key}_error"] is not None]
                errs = [c["models"][m][f"{key}_error"] for c in have]
                am = [c["amplification_measured"] for c in have]
                inside = [c for c in cs if c["models"][m][key] is not None
                          and c["amplification_measured_ci"][0] is not None
                          and c["amplification_measured_ci"][0] <= c["models"][m][key]
                          <= c["amplification_measured_ci"][1]]
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
            "model_string_unstable_all": sum(1 for c in cars if c["_acc"]
                                             and c["models"][m]["string_stable"] is False),
            "model_locally_unstable_all": sum(1 for c in cars if c["_acc"]
                                              and not c["models"][m]["local_stable"]),
            "cars_acc": sum(1 for c in cars if c["_acc"]),
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
    files = [c["file"] for c in cars]
    fg = np.linspace(0.005, 0.5, 400)
    for f in dict.fromkeys(files):
        rs = [r for r, fc in zip(runs, files, strict=True) if fc == f]
        m0 = rs[0].meta
        # where the platoon oscillates: mean periodogram of the predecessors' speeds
        mean = np.mean([np.interp(fg, *signal.periodogram(signal.detrend(r.lead_v), fs=1 / r.dt,
                                                          window="hann")) for r in rs], axis=0)
        c0 = next(c for c in cars if c["file"] == f)
        out.append({"file": f, "campaign": c0["campaign"], "folder": c0["folder"],
                    "track": m0.get("track"), "setting": c0["setting"],
                    "setting_rank": c0["setting_rank"], "acc": c0["acc"],
                    "date": m0.get("date"), "followers": len(rs),
                    "n_vehicles": m0.get("n_vehicles"),
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
        rows.append({"campaign": c["campaign"], "file": Path(c["file"]).stem,
                     "run_id": c["run_id"], "car": c["car"],
                     "setting": c["setting"] or "none", "setting_rank": c["setting_rank"],
                     "acc": _acc_label(c["acc"]), "group": c["group"],
                     "duration_s": c["duration_s"], "position": c["position"],
                     "track": c["track"], "Tg": c["Tg"], "Gmin": c["params"]["Gmin"],
                     "kg": c["params"]["kg"], "kv": c["params"]["kv"],
                     "time_gap_effective": c["time_gap_effective"],
                     "headway_measured": c["headway_measured"], "cal_mse": c["cal_mse"],
                     "A_measured": c["amplification_measured"], "A_ci_low": ci[0],
                     "A_ci_high": ci[1], "A_predicted_H": c["amplification_predicted"],
                     "A_replay": c["amplification_replay"],
                     "A_measured_h1": c["amplification_measured_h1"],
                     "A_h1_ci_low": (c["amplification_measured_h1_ci"] or [None])[0],
                     "A_h1_ci_high": (c["amplification_measured_h1_ci"] or [None, None])[1],
                     "coherence": c["coherence"],
                     "A_predicted_H_oos": c["amplification_predicted_oos"],
                     "A_replay_oos": c["amplification_replay_oos"],
                     "time_gap_effective_oos": c["time_gap_effective_oos"],
                     "oos_files": len(c["oos_files"]),
                     "at_bound": "/".join(c["at_bound"])})
    per_model = []
    for c in cars:
        for m in models:
            d = c["models"][m]
            per_model.append({"campaign": c["campaign"], "file": Path(c["file"]).stem,
                              "run_id": c["run_id"], "car": c["car"],
                              "setting": c["setting"] or "none", "position": c["position"],
                              "model": m, "cal_mse": d["cal_mse"], "Tg": d["params"]["Tg"],
                              "A_measured": c["amplification_measured"],
                              "A_H": d["amplification_H"], "A_replay": d["amplification_replay"],
                              "error_H": d["amplification_H_error"],
                              "error_replay": d["amplification_replay_error"],
                              **{f"p_{k}": v for k, v in d["params"].items()}})
    cars_df = pd.DataFrame(rows)
    label = [("human" if not c["_acc"] else "none" if c["setting"] is None else
              f"{c['setting']} (folder mixed)" if str(c["folder"]).lower() == "mixed"
              else f"{c['setting']} (order {c['setting_rank']})"
              if c["setting_rank"] is not None else f"{c['setting']} (no order)")
             for c in cars]
    tg = (cars_df.assign(setting=label)
          .pivot_table(index=["campaign", "car"], columns="setting", values="Tg",
                       aggfunc="median"))
    order_df = pd.DataFrame(order["checks"]) if order["checks"] else pd.DataFrame(
        columns=["campaign", "car", "longer", "shorter", "rank_longer", "rank_shorter",
                 "value_longer", "value_shorter", "held"])
    comp = [{"model": m, "prediction": lab, "cars": grp, **comparison[m][f"{key}_{grp}"]}
            for m in models
            for key, lab in (("amplification_H", "|H(jw)|"), ("amplification_replay", "replay"))
            for grp in ("acc", "human")]
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
    return md_table([str(c) for c in df.columns], [
        [_f(v, floatfmt) if isinstance(v, (float, np.floating)) else str(v) for v in row]
        for _, row in df.iterrows()])


def _findings(s: Mapping[str, Any]) -> list[str]:
    """The main numbers of the study as Markdown bullets (generated, not typed)."""
    main = s["model"]
    comp = s["model_comparison"]
    so = s["setting_order"]
    eff = s["setting_order_effective_time_gap"]
    hw = s["setting_order_measured_headway"]
    multi = len(s["campaigns"]) > 1
    fails = [(f"{c['car']} ({c['campaign']})" if multi else c["car"])
             for c in so["checks"] if not c["held"]]
    camps = "; ".join(f"{k}: {v['held']} of {v['checked']}"
                      for k, v in so["campaigns"].items())
    out = []
    o = s["out_of_sample"]["acc"]["oos_H_vs_h1"] if s["out_of_sample"]["enabled"] else None
    if o is not None and o["n"]:
        ins = s["out_of_sample"]["acc"]["in_sample_H_vs_h1"]
        out.append(f"- **Out of sample** ({main} model calibrated on each car's other files "
                   f"of its setting; abs H(jω) vs the H1 measured gain, ACC cars): n "
                   f"{o['n']}, mean error {_f(o['mean_error'], 3)}, within 10 % for "
                   f"{o['within_10pct_count']}, inside the measured 95 % interval for "
                   f"{o['inside_measured_ci_count']} of {o['n_with_interval']} (in-sample: "
                   f"mean error {_f(ins['mean_error'], 3)}, within 10 % for "
                   f"{ins['within_10pct_count']} of {ins['n']}).")
    out += [f"- **Setting order**: the calibrated Tg ({main} model) is longer for the longer "
           f"ACC setting in {so['held']} of {so['checked']} checks (car model × pair of "
           "settings, each campaign's own order of its settings"
           + (f"; per campaign: {camps}" if multi and camps else "") + ")"
           + (f"; not for {', '.join(fails)}" if fails else "") + "; file by "
           f"file, in {so['file_pairs_held']} of {so['file_pairs_checked']} pairs of files. "
           f"The effective time gap Tg + Gmin/v̄ follows the setting in {eff['held']} of "
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
                   f"amplification at {_f(d['corr_error_vs_measured'])}"
                   + (": the more a car amplifies, the more the calibrated model "
                      "underestimates it" if d["corr_error_vs_measured"] < 0 else "."))
    q = comp[main]["string_stability"]
    out.append(f"- **String stability**: the measured amplification's 95 % CI is above 1 "
               f"for {q['measured_unstable']} ACC cars and below 1 for "
               f"{q['measured_stable']} ({q['undecided']} undecided); the calibrated "
               f"{main} closed loops are string-unstable (max abs H > 1, true delay) for "
               f"{q['model_string_unstable_all']} of {q['cars_acc']} ACC cars, locally "
               f"unstable for {q['model_locally_unstable_all']}.")
    hum = [c for c in s["cars"] if c["group"] == "human"]
    if hum:
        dh = comp[main]["amplification_replay_human"]
        tgs = [c["Tg"] for c in hum if c["Tg"] is not None]
        rng = f"{min(tgs):.2f}–{max(tgs):.2f} s" if tgs else "none finite"
        out.append(f"- **Human control** ({len(hum)} human-driven runs, calibrated with the "
                   f"same closed-loop structure, never counted as ACC): calibrated Tg "
                   f"{rng}; replay within 10 % for {dh['within_10pct']} of {dh['n']}.")
    unk = [e for e in s["left_out"] if "unknown" in e["reason"]]
    inc = [c for c in s["cars"] if c["acc"] is None]
    if unk or inc:
        out.append(f"- **Unknown ACC state**: {len(unk)} runs left out "
                   f"({sum(e['seconds'] for e in unk):.0f} s); {len(inc)} studied as ACC "
                   f"(--acc-unknown {s['acc_unknown']}).")
    return out


def _overview_lines(ov: Sequence[Mapping[str, Any]]) -> list[str]:
    if not ov:
        return ["No car."]
    rows = [[o["campaign"] or "–", o["car"],
             ", ".join(f"{d['setting'] if d['setting'] is not None else 'none'} "
                       f"({d['setting_rank'] if d['setting_rank'] is not None else '–'})"
                       for d in o["settings"]) or "–",
             ", ".join(f"{k} {v}" for k, v in o["acc"].items()) or "–",
             f"{o['runs_studied']} ({o['seconds_studied']:.0f})",
             f"{o['runs_left_out']} ({o['seconds_left_out']:.0f})",
             "; ".join(f"{r} ({n})" for r, n in o["reasons_left_out"].items()) or "–"]
            for o in ov]
    return [md_table(["campaign", "car", "settings (order)", "ACC state of the runs studied",
                      "runs studied (s)", "left out / dropped (s)", "reasons"], rows)]


def _report(s: Mapping[str, Any], tables: Mapping[str, Any]) -> str:
    main = s["model"]
    cars = s["cars"]
    acc = [c for c in cars if c["group"] == "acc"]
    hum = [c for c in cars if c["group"] == "human"]
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
        f"Data: `{s['data']}` ({len(s['campaigns'])} campaign(s): "
        f"{', '.join(s['campaigns']) or '–'}); {len(cars)} runs (stretches of a follower "
        f"with a recorded predecessor) in {len(s['files'])} files ({len(acc)} studied as "
        f"ACC, {sum(c['acc'] is None for c in acc)} of them of unknown ACC state; "
        f"{len(hum)} human-driven, the control); {len(s['left_out'])} runs left out by "
        f"the study and {len(s['dropped_by_loader'])} stretches dropped by the loader (see "
        f"'Cars'). "
        + (f"Files recognised as not data and skipped: "
           f"{', '.join(Path(f).name for f in s['non_data_files'])}. "
           if s["non_data_files"] else "")
        + f"Main model: **{main}**; "
        f"compared: {', '.join(s['models'])}. GA: {s['ga']['max_generations']} generations, "
        f"population {s['ga']['pop_size'] or 'automatic'}, {s['ga']['starts']} start(s) per "
        f"car; seed {s['seed']}; objective weights (a, v, x) = "
        f"{tuple(s['objective_weights'])}; Gmin in [0, {s['bounds']['Gmin'][1]:g}] m. "
        f"Amplification band {s['band_hz'][0]:g}–{s['band_hz'][1]:g} Hz, block bootstrap "
        f"{s['bootstrap']['n']} × {s['bootstrap']['block_s']:g} s blocks (no interval "
        f"for a run shorter than {s['bootstrap']['min_blocks']} blocks after the trim). "
        f"Wall time {s.get('seconds', 0):.0f} s.",
        "",
        "## Files",
        "",
        _md_table(tables["files"][["campaign", "file", "folder", "track", "setting",
                                   "setting_rank", "acc", "followers", "excited_followers",
                                   "peak_hz", "band_power_share"]]),
        "",
        "`peak_hz`: peak of the mean periodogram of the predecessors' speeds; "
        "`band_power_share`: its share in the amplification band; `followers`: runs "
        "studied.",
        "",
        "## Cars",
        "",
        "Per campaign and car model: the raw settings as in the files with their order "
        "within the campaign (larger = longer time gap), the ACC state of the runs "
        "studied, and the runs (stretches) studied and left out, with the reasons (the "
        "loader's and the study's).",
        "",
        *_overview_lines(s["car_overview"]),
        "",
        "## Setting order (calibrated Tg)",
        "",
        f"Checks held: **{so['held']} of {so['checked']}** (per campaign, car model and "
        f"pair of settings in the campaign's own order, medians over runs; "
        f"{so['excluded']} excluded); per campaign: "
        + ("; ".join(f"{k} {v['held']} of {v['checked']}"
                     for k, v in so["campaigns"].items()) or "no check") + "; run by run: "
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
        lines += [f"- **{c['car']}**, {c['campaign']} ({c['longer']} {c['value_longer']:.2f} s vs "
                  f"{c['shorter']} {c['value_shorter']:.2f} s): {c['why']}" for c in fails]
        lines.append("")
    if hum:
        lines += ["Human control (no ACC): Tg " + ", ".join(
            f"{c['car']} {_f(c['Tg'])} s" for c in hum) + ".", ""]
    lines += _oos_lines(s)
    lines += ["## Amplification: measured vs predicted (in-sample)", "",
              "In-sample: each car's model is calibrated on the run it is compared on. "
              "The measured amplification here is the band RMS ratio with its block-"
              "bootstrap interval (for abs H against the H1 gain, like with like, see "
              "'Out of sample').", ""]
    best = comp["best"]
    lines.append(md_table(
        ["model", "prediction", "cars", "n", "median abs error", "mean error", "within 10 %",
         "inside CI", "under-estimated", "corr(error, measured)"],
        [[m, lab, grp, d["n"], _f(d["median_abs_error"], 3), _f(d["mean_error"], 3),
          d["within_10pct"], d["inside_ci"], d["underestimated"],
          _f(d["corr_error_vs_measured"])]
         for m in s["models"]
         for key, lab in (("amplification_H", "abs H(jω)"), ("amplification_replay", "replay"))
         for grp in ("acc", "human") for d in (comp[m][f"{key}_{grp}"],) if d["n"]]))
    lines += ["", "String stability per car (ACC cars with a measured amplification; "
              "measured string-unstable: CI above 1, stable: CI below 1):", ""]
    lines.append(md_table(
        ["model", "measured unstable", "model says unstable there", "measured stable",
         "model says stable there", "undecided", "model string-unstable (all ACC cars)",
         "model locally unstable"],
        [[m, q["measured_unstable"], q["model_unstable_where_measured_unstable"],
          q["measured_stable"], q["model_stable_where_measured_stable"], q["undecided"],
          f"{q['model_string_unstable_all']} of {q['cars_acc']}",
          q["model_locally_unstable_all"]]
         for m in s["models"] for q in (comp[m]["string_stability"],)]))
    lines += ["", f"Best predictor of the measured amplification (smallest median absolute "
              f"error over the ACC cars): from abs H(jω): **{best['amplification_H']}**; by "
              f"replay: **{best['amplification_replay']}**.", ""]
    lines += ["Per car (main model):", "",
              _md_table(tables["cars"][["file", "car", "setting", "position", "Tg", "Gmin",
                                        "time_gap_effective", "headway_measured", "cal_mse",
                                        "A_measured", "A_ci_low", "A_ci_high",
                                        "A_predicted_H", "A_replay"]], 2), "",
              "Per car, like with like (main model; `_oos`: out of sample, from the car's "
              "other files of its setting; `oos_files`: how many):", "",
              _md_table(tables["cars"][["file", "car", "setting", "A_measured_h1",
                                        "A_h1_ci_low", "A_h1_ci_high", "coherence",
                                        "A_predicted_H", "A_predicted_H_oos", "A_measured",
                                        "A_replay", "A_replay_oos", "time_gap_effective",
                                        "time_gap_effective_oos", "headway_measured",
                                        "oos_files"]], 2), ""]
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
                  + (f"[{c['amplification_measured_ci'][0]:.2f}, "
                     f"{c['amplification_measured_ci'][1]:.2f}]"
                     if c["amplification_measured_ci"][0] is not None else "(no interval)")
                  + ", replay "
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
    gone = [*s["left_out"], *s["dropped_by_loader"]]
    if gone:
        lines += ["## Runs left out and stretches dropped", ""]
        lines += [f"- {Path(k['file']).stem} {k['car']} ({k['by']}"
                  + (f", {k['seconds']:.1f} s" if k.get("seconds") is not None else "")
                  + f"): {k['reason']}" for k in gone]
        lines.append("")
    return "\n".join(lines) + "\n"
