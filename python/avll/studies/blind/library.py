"""Reproduces the blind-test table of the diagnosis guide: for each generator effect,
the diagnosis's first candidate, the cross-validation record of every candidate tried
(fold selection, pooled out-of-fold gain), the added effects, their parameters (with
"at bound" where a parameter sits at its search bound) and the calibration /
validation / test MSE before and after (seed 0; runs 1, 3, 8 calibrate — three
leave-one-run-out folds —, 12, 15 validate, 19, 5 test; default rule of
:func:`avll.diagnose.effect_loop`)."""

from __future__ import annotations

import time
from typing import Any

import avll
from avll.diagnose import effect_loop
from avll.synth_effects import expected_params, paper_experiment_effects

SECOND = avll.PAPER_TABLE_II["second"]
FIRST = avll.FirstOrderLag(Td=0.6)
#: (label, true model, base model name, generator effects, leader speed-up) per case.
CASES: list[tuple[str, Any, str, dict[str, dict[str, float] | None], float]] = [
    ("asymmetric", SECOND, "second", {"asymmetric": None}, 1.0),
    ("saturation", SECOND, "second", {"saturation": None}, 1.0),
    ("rate_limit", FIRST, "first", {"rate_limit": {"j": 1.0}}, 3.0),
    ("deadband", SECOND, "second", {"deadband": None}, 1.0),
    ("speed_drag", SECOND, "second", {"speed_drag": None}, 1.0),
    ("grade", SECOND, "second", {"grade": None}, 1.0),
    ("delay", FIRST, "first", {"delay": None}, 1.0),
    ("none (+ exo_grade, exo_wind)", SECOND, "second", {}, 1.0),
    ("none (+ exo_grade, exo_wind)", FIRST, "first", {}, 1.0),
    ("saturation + grade", SECOND, "second", {"saturation": None, "grade": None}, 1.0),
]


def table() -> list[str]:
    """The table's Markdown lines (the last column: the loop's wall time per case)."""
    lines = ["| true effect | base | ranked first | cross-validated: fold selection, gain | "
             "added | fitted (expected) | cal MSE before → after | val MSE before → after | "
             "test MSE before → after | flags | time |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for label, true, base, effs, sp in CASES:
        extra = ("grade", "wind") if not effs else ()
        runs = paper_experiment_effects(true, effs, seed=0, leader_speedup=sp, extra_exo=extra,
                                        runs=(1, 3, 8, 12, 15, 19, 5))  # fmt: skip
        t = time.perf_counter()
        res = effect_loop(base, runs[:3], runs[3:5], test_runs=runs[5:], seed=1)
        el = time.perf_counter() - t
        first = res.diagnoses[0].ranked[0].effect if res.diagnoses[0].ranked else "—"
        rec = []
        for s in res.steps:
            if s.effect in effs:
                exp = expected_params(s.effect, effs[s.effect] or {})
            else:
                exp = expected_params(s.effect) if s.effect in (
                    "asymmetric", "saturation", "grade") else {}
            bound = {a.param.split(".", 1)[1] for a in s.at_bound
                     if a.param.startswith(s.effect + ".")}  # fmt: skip
            rec.append(", ".join(
                f"{k} {v:.4g}" + (" at bound" if k in bound else "")
                + (f" ({exp[k]:.4g})" if k in exp else "")
                for k, v in s.params.items()))  # fmt: skip
        if res.steps:
            d0, d1 = res.steps[0].to_dict(), res.steps[-1].to_dict()
            cal = f"{d0['cal_mse_before']:.4f} → {d1['cal_mse_after']:.4f}"
            val = f"{d0['val_mse_before']:.4f} → {d1['val_mse_after']:.4f}"
            test = f"{d0['test_mse_before']:.4f} → {d1['test_mse_after']:.4f}"
        else:
            cal = val = test = "—"
        cv = "; ".join(f"{t.effect} {t.fold_selection:.2f}, {100 * t.gain:+.1f} %"
                       for t in res.trials) or "—"  # fmt: skip
        flags = ", ".join(sorted({f.kind for f in res.flags})) or "—"
        added = ", ".join(s.effect for s in res.steps) or "none"
        lines.append(f"| {label} | {base} | {first} | {cv} | {added} | "
                     f"{'; '.join(rec) or '—'} | {cal} | {val} | {test} | {flags} | "
                     f"{el:.0f} s |")  # fmt: skip
    return lines


def main() -> None:
    """Prints the table."""
    print("\n".join(table()))


if __name__ == "__main__":
    main()
