"""Road grade in free flow: the AstaZero free-flow stretches (the
platoon leader alone under its ACC, a constant set speed as the speed command, the road
grade from ``Slope.csv``) are where the grade shows without a predecessor in the way.
Does the residual of the calibrated base model depend on the grade, what grade gain does
a fit give, and does the cross-validated loop accept ``grade``?

Split: calibration on the three 70 km/h stretches of platoons 5-7 (leave-one-run-out),
validation on the 60 and 50 km/h stretches, test on platoon 8's 70 km/h stretch. Base
model ``second``; every effect that applies to a speed command is offered.

:func:`compute` returns the numbers, :func:`render` the table;
``python -m docs.gen --only grade-freeflow`` writes ``docs/_generated/grade_freeflow.md``
and its numbers ``grade_freeflow.json`` (what the data test recomputes).

    MPLBACKEND=Agg python -m avll.studies.grade_freeflow [--data ../shared/data]
        [--max-generations 100]                  # prints the table
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from avll.calibration import calibrate
from avll.data import Run
from avll.diagnose import calibrate_kw, effect_loop, effective_sample_size, simulate_runs
from avll.effects import WithEffects
from avll.io import read_runs
from avll.paper import G

BASE = "second"


def split(data: Path) -> tuple[list[Run], list[Run], list[Run]]:
    """(calibration, validation, test) free-flow stretches."""
    rs = read_runs(data / "openacc-astazero" / "freeflow", format="openacc-astazero")
    cal = [r for r in rs if r.run_id.endswith("V70") and "platoon8" not in r.run_id]
    test = [r for r in rs if r.run_id.endswith("V70") and "platoon8" in r.run_id]
    val = [r for r in rs if not r.run_id.endswith("V70")]
    return cal, val, test


def grade_fit(cal: list[Run], max_generations: int) -> dict[str, Any]:
    """The base model's residual against the grade, and base + grade fitted."""
    kw = dict(seed=0, max_generations=max_generations, **calibrate_kw(cal))
    base = calibrate(BASE, cal, **kw).model
    res = [r.a - s for r, s in zip(cal, simulate_runs(WithEffects(base), cal), strict=True)]
    e = np.concatenate(res)
    g = np.concatenate([r.exo["grade"] for r in cal])
    corr = float(np.corrcoef(e, g)[0, 1])
    # the correlation's standard error from the effective sample size of the residual
    n_eff = float(effective_sample_size(res))
    with_grade = calibrate(BASE, cal, effects=("grade",), **kw).with_effects
    g_eff = float(with_grade.effects[0].to_dict()["g_eff"])
    return {"corr_residual_grade": corr, "n_eff": n_eff,
            "corr_se": float(1.0 / np.sqrt(max(n_eff - 3.0, 1.0))),
            "grade_std": float(g.std()), "g_eff": g_eff,
            "samples": int(e.size)}  # fmt: skip


def conclusion(d: dict[str, Any]) -> str:
    """What the numbers say, worded from the numbers."""
    fit, loop = d["fit"], d["loop"]
    depends = abs(fit["corr_residual_grade"]) > 2 * fit["corr_se"]
    share = 100 * abs(fit["g_eff"]) / G
    sign = "the physical one (a climb slows the car)" if fit["g_eff"] > 0 else (
        "opposite to the physical one (the car accelerates slightly more on what Slope.csv "
        "calls a climb)")
    accepted = "grade" in loop["effects"]
    return (
        ("The residual depends on the grade (the correlation is more than twice its standard "
         "error); " if depends else "The residual shows no clear dependence on the grade; ")
        + f"the fitted gain is {share:.1f} % of what an uncompensated grade would give and its "
        f"sign is {sign}"
        + (": the ACC's speed controller compensates the grade almost entirely"
           if share < 10 else "")
        + ("; the loop accepts grade." if accepted else
           "; the loop does not accept grade (see its fold selection and pooled gain above).")
        + " These files carry no altitude, so whether the sign comes from the controller "
        "(e.g. its integral action lagging the grade) or from the sign convention of "
        "Slope.csv cannot be settled from them."
    )


def render(d: dict[str, Any]) -> str:
    """The Markdown table and conclusion of :func:`compute`'s result."""
    fit, loop = d["fit"], d["loop"]
    tr = [t for t in loop["trials"] if t["effect"] == "grade"]
    grade_cv = ("grade was not among the candidates the loop cross-validated" if not tr else
                "; ".join(f"grade selected in {t['fold_selection']:.2f} of the folds, pooled "
                          f"out-of-fold gain {100 * t['gain']:+.1f} % (block-bootstrap p "
                          f"{t['p_value']:.2g})" for t in tr))  # fmt: skip
    accepted = ", ".join(loop["effects"]) or "none"
    return "\n".join([
        f"*Base `{BASE}`, GA {d['max_generations']} generations per start, seed 0.*",
        "",
        f"Calibration: {', '.join(d['cal'])}; validation: {', '.join(d['val'])}; test: "
        f"{', '.join(d['test'])}.",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| correlation of the base model's residual with the grade ({fit['samples']} "
        f"samples, effective {fit['n_eff']:.0f}) | {fit['corr_residual_grade']:+.3f} "
        f"(± {fit['corr_se']:.3f}) |",
        f"| grade along the stretches (standard deviation) | {fit['grade_std']:.4f} |",
        f"| fitted grade gain `g_eff` (`a -= g_eff · grade`; {G:g} m/s² if nothing "
        f"compensated it) | {fit['g_eff']:+.3f} m/s² ({100 * fit['g_eff'] / G:+.1f} % of g) |",
        f"| cross-validated loop | {grade_cv}; effects accepted: {accepted} |",
        "",
        conclusion(d),
        "",
    ])


def compute(data: Path, max_generations: int = 100) -> dict[str, Any]:
    """The split, the grade fit and the cross-validated loop on the field data in
    ``data`` (minutes): the numbers :func:`render` shows."""
    cal, val, test = split(Path(data))
    fit = grade_fit(cal, max_generations)
    res = effect_loop(BASE, cal, val, test_runs=test, seed=0, max_generations=max_generations,
                      max_effects=2)  # fmt: skip
    ld = res.to_dict()
    return {"max_generations": max_generations, "cal": [r.run_id for r in cal],
            "val": [r.run_id for r in val], "test": [r.run_id for r in test], "fit": fit,
            "loop": {"effects": ld["effects"], "trials": ld["trials"], "flags": ld["flags"]}}


def main(argv: list[str] | None = None) -> int:
    """Prints the table (``python -m docs.gen --only grade-freeflow`` writes it)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="../shared/data")
    ap.add_argument("--max-generations", type=int, default=100)
    a = ap.parse_args(argv)
    print(render(compute(Path(a.data), a.max_generations)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
