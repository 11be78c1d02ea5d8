"""Tables, figures and the report of the residual loop (written with
:class:`avll.report.Report`). The wording follows the JSON: a parameter at a bound
of the search box is "at bound", a gain that does not hold on the test runs is
flagged, and structure the effects leave in the residual is said plainly."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from .loop import LoopResult, _gain, _mean
from .signatures import Diagnosis

__all__ = ["REFERENCE_UPPER", "mse_table", "plot_diagnosis", "plot_unexplained",
           "stability_section", "write_report"]

#: Upper-level law at which the report evaluates the stability consequences of the
#: accepted effects when the data have no calibrated one (a recorded command): a
#: constant-time-gap law inside the paper's box, string stable for the paper's
#: calibrated second-order model at 15 m/s.
REFERENCE_UPPER = {"kg": 0.2, "kv": 0.3, "Tg": 1.5, "Gmin": 2.0}


def mse_table(rows: dict[str, dict[str, float]], title: str, per_line: int = 6) -> str:
    """A Markdown table in the paper's format (Tables III/IV): runs across, models
    down, wrapped every ``per_line`` runs, with the average last."""
    runs = list(next(iter(rows.values())).keys())
    out = [f"**{title}** (unit: (m/s²)²)", ""]
    for i in range(0, len(runs), per_line):
        chunk = runs[i : i + per_line]
        last = i + per_line >= len(runs)
        head = ["Run No.", *chunk] + (["Average"] if last else [])
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for name, vals in rows.items():
            cells = [f"{vals[r]:.4f}" for r in chunk]
            if last:
                cells.append(f"{_mean(vals):.4f}")
            out.append(f"| {name} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


#: Captions of the diagnosis figures, by the names :func:`plot_diagnosis` gives them.
CAPTIONS = {
    "residual_vs_signals": "the residual (m/s²) binned against each candidate signal, "
                           "with 95 % bands (effective sample sizes); the share of its "
                           "variance each signal explains and the p-value above each panel",
    "residual_spectrum": "the residual's power spectral density ((m/s²)²/Hz against Hz), "
                         "its autocorrelation and its cross-correlation with the command "
                         "rate (against the lag in s)",
}


def plot_diagnosis(d: Diagnosis) -> list[tuple[str, Any]]:
    """Figures of a diagnosis (:func:`avll.plotting.residual_diagnosis`): the
    residual against each candidate signal, and its spectrum and correlations."""
    from ..plotting import residual_diagnosis

    return residual_diagnosis(d)


def plot_unexplained(unexplained: dict[str, Any]) -> Any:
    """The final residual against speed, time and command
    (:func:`avll.plotting.residual_unexplained`)."""
    from ..plotting import residual_unexplained

    return residual_unexplained(unexplained)


def model_text(model: Any, digits: int = 4) -> str:
    """``Name(p=value, ...)`` with ``digits`` significant digits (a fitted parameter
    does not carry 16; the JSON keeps the full values)."""
    import dataclasses

    if not dataclasses.is_dataclass(model):
        return str(model)
    vals = ", ".join(f"{f.name}={getattr(model, f.name):.{digits}g}"
                     if isinstance(getattr(model, f.name), float)
                     else f"{f.name}={getattr(model, f.name)}"
                     for f in dataclasses.fields(model))
    return f"{type(model).__name__}({vals})"


def _pct(x: Any) -> str:
    return "—" if x is None or not math.isfinite(float(x)) else f"{100 * float(x):+.1f} %"


def _num(x: Any) -> str:
    from ..report import fmt

    return fmt(x)


def stability_section(result: LoopResult, v0: float = 15.0) -> dict[str, Any] | None:
    """What the accepted effects do to the stability conclusions:
    :func:`avll.effect_stability.effect_stability` of the baseline fit and of the
    final model (with its effects), each under its calibrated upper-level law (or
    :data:`REFERENCE_UPPER` when there is none), at ``v0``. ``None`` when no effect
    was accepted. Returns ``{"upper", "upper_source", "v0", "baseline", "final"}``
    (the two results)."""
    if not result.steps:
        return None
    from ..effect_stability import effect_stability

    if result.upper is not None:
        up: Any = result.upper
        src = "the calibrated upper-level law"
    else:
        up = dict(REFERENCE_UPPER)
        src = ("a reference law (the runs have a recorded command, no upper level): "
               + ", ".join(f"{k} = {v:g}" for k, v in REFERENCE_UPPER.items()))
    amps = (0.25, 0.5, 1.0, 2.0, 4.0)
    # the baseline fit with its own calibrated upper law where it has one
    up0 = result.baseline_upper if result.baseline_upper is not None else up
    base = effect_stability(result.baseline, up0, v0=v0, amplitudes=amps)
    final = effect_stability(result.final, up, v0=v0, amplitudes=amps)
    return {"upper": up, "upper_source": src, "v0": v0, "baseline": base, "final": final}


def _stability_report(rep: Any, sec: dict[str, Any], stage: Path) -> None:
    from .. import _atomic

    base, final = sec["baseline"], sec["final"]
    rep.heading("What the accepted effects do to stability")
    rep.para(f"Evaluated at {sec['v0']:g} m/s under {sec['upper_source']}. Linearised "
             "(smooth effects; for asymmetric each side): the stability code at these gains "
             "(0 locally unstable, 1 string unstable, 2 string stable), the smallest "
             "string-stable Tg at these kg, kv, the paper's thresholds over the kg-kv box "
             "(minimum stable Tg, kv threshold) and |H(jω)| at the disturbance frequency. "
             "— means not computable for that form (see the notes).")
    rows = []
    for label, es in (("baseline fit", base), ("final", final)):
        for e in es.linear:
            rows.append([f"{label}: {e.label}", "—" if e.code is None else e.code,
                         _num(e.tg_min_at_gains), _num(e.min_stable_tg),
                         _num(e.kv_threshold), _num(e.gain_at_omega),
                         "; ".join(e.notes)])
    rep.table(["model", "code", "smallest stable Tg (s)", "min stable Tg, box (s)",
               "kv threshold", "|H(jω)|", "notes"], rows)
    rep.para("In the time domain (nonlinear effects included): a platoon of "
             f"{final.amplification.shape[1]} followers behind a leader oscillating with "
             f"period {final.period:.1f} s; the geometric-mean amplification per car of the "
             "speed's fundamental, per leader amplitude. A linear model's does not depend "
             "on the amplitude.")
    mb, mf = base.mean_amplification(), final.mean_amplification()
    rep.table(["leader amplitude (m/s)", "baseline fit", "final model"],
              [[f"{a:g}", _num(float(x)), _num(float(y))]
               for a, x, y in zip(final.amplitudes, mb, mf, strict=True)])  # fmt: skip
    notes = [*(f"baseline: {n}" for n in base.notes), *(f"final: {n}" for n in final.notes)]
    if notes:
        rep.bullets(notes)
    fig = final.plot()
    _atomic.savefig(fig, stage / "stability.png", dpi=90)
    rep.figure("stability.png", "Final model: amplification per car (1) against the "
               "leader's amplitude (m/s)")


#: What the report says of each flag of a step.
_FLAG_WORDS = {
    "test_gain_not_held": "**The gain does not hold on the test runs.**",
    "test_gain_far_smaller": "**The test gain is far smaller than the validation (or "
                             "cross-validated) gain.**",
    "validation_gain_not_held": "**The validation error does not fall.**",
    "validation_gain_far_smaller": "**The validation gain is far smaller than the "
                                   "cross-validated gain.**",
    "at_bound": "Some parameters are at a bound of the search box.",
}


def write_report(result: LoopResult, out_dir: str | Path, title: str = "avll diagnosis",
                 *, stability: bool = True, v0: float | None = None) -> Path:
    """Writes ``report.md``, ``report.html`` and PNG figures into ``out_dir`` as one
    unit (built in a hidden temporary folder inside it, committed with a ``MANIFEST.json``
    written last: see :mod:`avll._atomic`). Every text, run ids included, is escaped
    in the HTML. With ``stability`` (and an accepted effect) the report adds what the
    effects do to the stability conclusions (:func:`stability_section`) at ``v0``
    (m/s; default 15; ``avll diagnose`` passes the mean speed of the calibration
    runs where they have one)."""
    from .. import _atomic
    from ..report import Report

    rep = Report(title)
    sp, st = result.splits, result.settings
    rep.heading("Splits and rule")
    rep.table(["set", "runs", "role"], [
        ["calibration", ", ".join(sp.cal_runs),
         "fits every model; its folds decide what is accepted"],
        ["validation", ", ".join(sp.val_runs) or "—", "reported only"],
        ["test", ", ".join(sp.test_runs) or "—", "simulated only after the loop finished"],
    ])  # fmt: skip
    kind = ("contiguous blocks of the single calibration run" if st.fold_kind == "blocks"
            else "groups of calibration runs")  # fmt: skip
    rep.para(f"Selection: {st.folds} cross-validation folds ({kind}). An effect is accepted "
             f"only if it lowers the held-out MSE by at least {100 * st.min_gain:.0f} % in "
             "more than half of the folds, the pooled out-of-fold gain is at least that, a "
             "moving-block bootstrap of the per-sample loss difference gives p < "
             f"{st.cv_alpha:g}, and the refit on all calibration runs lowers their error. "
             "Validation and test runs decide nothing.")
    rep.heading("Baseline")
    rep.para(f"Baseline: `{model_text(result.baseline.base)}`"
             + (f", upper law {result.baseline_upper}" if result.baseline_upper else ""))
    bm = result.baseline_mse
    rep.table(["set", "MSE (m/s²)²"], [[k, _num(_mean(v)) if v else "—"]
                                        for k, v in bm.items()])  # fmt: skip
    if result.baseline_at_bound:
        rep.para("At bound (the edge of the search box, not an estimate): "
                 + ", ".join(f"`{a.param}` = {_num(a.value)} ({a.bound} bound)"
                             for a in result.baseline_at_bound))  # fmt: skip
    rep.heading("Accepted effects")
    if not result.steps:
        rep.para("No effect was accepted: none passed the cross-validated selection.")
    for k, s in enumerate(result.steps, 1):
        rep.heading(f"Step {k}: add `{s.effect}`", level=3)
        ab = {a.param.split(".", 1)[-1]: a for a in s.at_bound
              if a.param.startswith(s.effect + ".")}  # fmt: skip
        rep.table(["parameter", "value", "note"],
                  [[p, _num(v), f"at {ab[p].bound} bound" if p in ab else ""]
                   for p, v in s.params.items()])  # fmt: skip
        others = [a for a in s.at_bound if not a.param.startswith(s.effect + ".")]
        if others:
            rep.para("Also at a bound of the search box (not estimates): "
                     + ", ".join(f"`{a.param}` = {_num(a.value)}" for a in others))
        cv = s.cv
        lo, hi = cv.boot.ci
        rep.para(f"Selected in {100 * s.fold_selection:.0f} % of {cv.folds} folds "
                 f"(held-out gains " + ", ".join(_pct(g) for g in cv.fold_gains)
                 + f"); pooled out-of-fold gain {_pct(cv.gain)} "
                 f"(block-bootstrap 95 % interval {_pct(lo)} to {_pct(hi)}, p = "
                 f"{s.p_value:.2g}; t-test with {cv.test.n_eff:.0f} effective of "
                 f"{cv.test.n:.0f} samples: p = {cv.test.p_value:.2g}).")
        sets = [(n, b, a) for n, b, a in (("calibration", s.cal_before, s.cal_after),
                                          ("validation", s.val_before, s.val_after),
                                          ("test", s.test_before, s.test_after))
                if b or n == "calibration"]  # fmt: skip
        rep.table(["set", "MSE before (m/s²)²", "MSE after (m/s²)²", "gain"],
                  [[n, _num(_mean(b)), _num(_mean(a)), _pct(_gain(b, a))] for n, b, a in sets])
        for fl in s.flags:
            rep.para(_FLAG_WORDS.get(fl, fl))
        for n, b, a in sets:
            rep.code(mse_table({"before": b, "after": a},
                               f"{n.capitalize()} MSE of acceleration"))
    if result.trials:
        rep.heading("Every cross-validated candidate")
        rep.table(["iteration", "effect", "fold selection", "pooled gain", "p", "decision"],
                  [[t.iteration, t.effect, f"{100 * t.fold_selection:.0f} %", _pct(t.gain),
                    f"{t.p_value:.2g}",
                    "accepted" if t.passed and any(s.effect == t.effect for s in result.steps)
                    else "; ".join(t.reasons) or "passed, not the best"]
                   for t in result.trials])  # fmt: skip
    if result.flags:
        rep.heading("Flags")
        rep.bullets([f.message for f in result.flags])
    sec = None
    if stability and result.steps:
        sec = stability_section(result, v0=15.0 if v0 is None else float(v0))
    out = Path(out_dir)
    with _atomic.output_dir(out, meta={"command": "avll diagnose"}) as stage:
        if sec is not None:
            _stability_report(rep, sec, stage)
        un = result.unexplained
        rep.heading("What the residual keeps")
        if un.get("signals"):
            rep.para(un.get("message", ""))
            rep.table(["signal", "share of residual variance", "p (effective n)",
                       "keeps structure"],
                      [[s["signal"], f"{100 * s['explained']:.2f} %", f"{s['p_value']:.2g}",
                        s["keeps_structure"]] for s in un["signals"]])  # fmt: skip
            rep.para(f"Unexplained structured share: {100 * un['unexplained_share']:.1f} % of "
                     f"the residual variance; residual lag-1 autocorrelation "
                     f"{un['lag1_autocorrelation']:.2f}, {un['n_eff']:.0f} effective of "
                     f"{un['n']} samples (descriptive).")
            fig = plot_unexplained(un)
            _atomic.savefig(fig, stage / "unexplained.png", dpi=90)
            rep.figure("unexplained.png", "Final residual (m/s²) binned against speed (m/s), "
                       "time in run (s) and command, with 95 % bands")
        else:
            rep.para(un.get("reason", "not computed"))
        for k, d in enumerate(result.diagnoses):
            rep.heading(f"Diagnosis {k + 1} of `{d.model.name}`")
            rep.para(f"residual RMS {d.residual_rms:.4f} m/s², lag-1 autocorrelation "
                     f"{d.lag1:.3f}, effective samples {d.n_eff:.0f}, xcorr peak with the "
                     f"command rate at {d.best_lag:+.2f} s. The ranking only chooses which "
                     "effects are cross-validated.")
            rep.table(["effect", "explained", "F", "df", "p (Bonferroni)", "ranked"],
                      [[c.effect, f"{100 * c.explained:.2f} %", f"{c.F:.1f}", c.df,
                        f"{c.p_value:.2g}", "yes" if c.significant else "no"]
                       for c in d.candidates])  # fmt: skip
            for name, fig in plot_diagnosis(d):
                fn = f"diag{k + 1}_{name}.png"
                _atomic.savefig(fig, stage / fn, dpi=90)
                rep.figure(fn, f"Diagnosis {k + 1}: {CAPTIONS.get(name, name)}")
        rep.write(stage)
    return out / "report.md"
