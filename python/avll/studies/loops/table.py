"""The table row of one residual-loop result (the JSON of ``avll diagnose``), shared by
the generated measured-data tables (:mod:`avll.studies.loops.carma`,
:mod:`avll.studies.loops.openacc`)."""

from __future__ import annotations

from typing import Any

#: Columns of :func:`row` after the case's own.
HEADER = ("added (parameters) | fold selection per candidate | validation gain | test gain "
          "| flags | unexplained")

#: What the columns mean (one paragraph for the generated page).
LEGEND = (
    "Gains: final model against the baseline fit (acceleration MSE; negative: the final "
    "model is worse). Fold selection: the fraction of the cross-validation folds in which "
    "each cross-validated candidate met the minimum gain (5 %), with its pooled "
    "out-of-fold gain and block-bootstrap p (acceptance needs more than half of the folds, "
    "a pooled gain of 5 % and p < 0.01). Flags: at_bound (a parameter at the edge of its "
    "search box: not an estimate), test_gain_not_held / test_gain_far_smaller (the gain "
    "does not hold on the untouched test data), validation_gain_not_held / "
    "validation_gain_far_smaller. Unexplained: the share of the final residual's variance "
    "that its dependence on speed, time and command explains where that dependence is "
    "significant, and the signals it depends on (no offered effect captures it)."
)


def pct(x: float | None) -> str:
    """A signed percentage, or a dash."""
    return "—" if x is None else f"{100 * x:+.1f} %"


def gain(before: float | None, after: float | None) -> float | None:
    """``1 - after / before`` (None when either is missing)."""
    if before is None or after is None or not before:
        return None
    return 1.0 - after / before


def row(d: dict[str, Any]) -> str:
    """The cells of :data:`HEADER` for one loop result ``d``."""
    steps = d["steps"]
    added = ", ".join(
        f"{s['effect']} ({', '.join(f'{k} {v:.3g}' for k, v in s['params'].items())})"
        for s in steps) or "none"
    folds = "; ".join(f"{t['effect']} {t['fold_selection']:.2f} ({pct(t.get('gain'))}, "
                      f"p {t['p_value']:.2g})" for t in d.get("trials", [])) or "—"
    if steps:
        s0, s1 = steps[0], steps[-1]
        val = pct(gain(s0.get("val_mse_before"), s1.get("val_mse_after")))
        test = pct(gain(s0.get("test_mse_before"), s1.get("test_mse_after")))
    else:
        val = test = "—"
    flags = ", ".join(sorted({f["kind"] for f in d.get("flags", [])})) or "—"
    un = d.get("unexplained", {})
    share = un.get("unexplained_share")
    keeps = ", ".join(x["signal"] for x in un.get("signals", []) if x.get("keeps_structure"))
    unexpl = "—" if share is None else f"{100 * share:.1f} %"
    return (f"{added} | {folds} | {val} | {test} | {flags} | {unexpl}"
            f"{f' ({keeps})' if keeps else ''}")


def summary(results: dict[str, dict[str, Any]]) -> str:
    """One generated sentence over the cases that ran: how many accepted an effect,
    on how many the test gain held, and how many residuals keep structure no effect
    explains."""
    n = len(results)
    if not n:
        return "No case has run yet."
    added = {c: d for c, d in results.items() if d["steps"]}
    bad = {"test_gain_not_held", "test_gain_far_smaller"}
    tested = {c: d for c, d in added.items()
              if d["steps"][0].get("test_mse_before") is not None
              and d["steps"][-1].get("test_mse_after") is not None}
    held = [c for c, d in tested.items() if not ({f["kind"] for f in d.get("flags", [])} & bad)]
    keeps = [c for c, d in results.items()
             if any(x.get("keeps_structure") for x in d.get("unexplained", {}).get("signals", []))]
    which = "; ".join(f"{c}: {', '.join(d['effects'])}" for c, d in added.items())
    return (f"Of {n} case(s), {len(added)} accepted at least one effect"
            + (f" ({which})" if which else "")
            + f"; the test gain held (no test flag) in {len(held)} of the {len(tested)} with "
            f"test data; "
            f"in {len(keeps)} of {n} the final residual keeps a significant dependence that "
            "no offered effect explains.")
