"""The OpenACC ZalaZone findings page (``docs/findings-openacc.md``; hours): ``avll
study openacc`` with its default settings (full GA budget, three lower-level models,
seed 0) on ``../shared/data/openacc-zalazone`` (outputs saved to ``out/openacc``,
git-ignored), the sensitivity of the setting order to the bound of Gmin
(``gmin_max=30``, the default box of :func:`avll.calibrate`; main model only) and the
effects that close the amplification gaps
(:func:`avll.studies.openacc_effects.effect_gaps`). No number in the page is typed by
hand.

    MPLBACKEND=Agg python -m docs.gen --only findings-openacc
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

from avll import _atomic
from avll.studies.openacc import GMIN_MAX, openacc_study
from avll.studies.openacc_effects import effect_gaps

from . import ROOT, Generated

OUT = ROOT / "out" / "openacc"
#: GA generations of each car + effect fit.
EFFECT_GENERATIONS = 150


def _log(msg: str) -> None:
    print(f"[findings-openacc] {msg}", file=sys.stderr, flush=True)


def generate(data: Path, seed: int = 0) -> Generated:
    """Runs the study, its Gmin sensitivity and the effect gaps; the page."""
    data_rel = os.path.relpath(data, ROOT)  # the page shows it relative to the repository
    t0 = time.perf_counter()
    study = openacc_study(data, seed=seed, log=_log)
    study.save(OUT, OUT / "openacc.json")
    _log(f"main study: {time.perf_counter() - t0:.0f} s")
    wide = openacc_study(data, seed=seed, models=(study.summary["model"],), gmin_max=30.0,
                         figures=False, log=_log)  # fmt: skip
    gaps = effect_gaps(study, seed=seed, max_generations=EFFECT_GENERATIONS, log=_log)
    _atomic.write_json(OUT / "effect_gaps.json", _atomic.json_safe(gaps))
    s, w = study.summary, wide.summary
    so, wo = s["setting_order"], w["setting_order"]
    fails = ", ".join(c["car"] for c in wo["checks"] if not c["held"]) or "none"
    atb = sum("Gmin" in c["at_bound"] for c in s["cars"])
    atb_w = sum("Gmin" in c["at_bound"] for c in w["cars"])
    # drop the report's own title; the data folder relative to the repository, as above
    report = study.report.split("\n", 1)[1].replace(str(data), data_rel)
    page = [
        "(findings-openacc)=",
        "# Findings: OpenACC ZalaZone — time gaps and measured string stability",
        "",
        f"From the output of `avll study openacc {data_rel} --out DIR --seed {seed}` (default "
        "settings: full GA budget, two starts per car, the three lower-level models); the "
        "numbers below are the study's, not typed by hand. Figures (measured vs predicted "
        "amplification per car, Tg per car model and setting) and the CSV tables are in the "
        "study's output folder. Method: see {mod}`avll.studies.openacc` and the loader "
        "{mod}`avll.io.openacc_native`.",
        "",
        "The study runs on any OpenACC campaign as the JRC distributes it (`avll study "
        "openacc PATH` on a data file, a campaign folder, or a folder of several campaigns). "
        "The setting order is checked within each campaign, in the campaign's own order of "
        "its settings (the loader's `setting_rank`), and reported per car model and campaign;"
        " human-driven runs are calibrated as a control and never counted as ACC; runs of "
        "unknown ACC state are left out and counted unless `--acc-unknown include`; a run too"
        " short for the band or for the block bootstrap gets no value or no interval (`null` "
        "with a `_reason`). The report's *Cars* section lists per campaign and car model the "
        "raw settings and their order, the ACC state of the runs studied, and the stretches "
        "studied and left out with the reasons. The output folder is written as a whole with "
        "its manifest.",
        "",
        "## Sensitivity of the setting order to the box of Gmin",
        "",
        f"With Gmin in [0, {GMIN_MAX:g}] m (the study's default) the calibrated Tg follows "
        f"the setting in {so['held']} of {so['checked']} checks, and {atb} of "
        f"{len(s['cars'])} cars have Gmin at its bound. With the library's default box "
        f"[0, 30] m ({s['model']} model, same seed): {wo['held']} of {wo['checked']} "
        f"(not held: {fails}); {atb_w} cars at the bound. The effective time gap "
        f"Tg + Gmin/v̄ follows the setting in "
        f"{w['setting_order_effective_time_gap']['held']} of "
        f"{w['setting_order_effective_time_gap']['checked']} there: at the near-constant "
        "speeds of the dynamic platform only Gmin + Tg v is identified.",
        "",
        *_gap_section(gaps),
        "",
        report,
    ]
    return Generated("\n".join(page))


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:+.0f} %"


def _gap_section(g: dict[str, Any]) -> list[str]:
    eff = g["effects"]
    lines = [
        "## Which effect closes the amplification gap?",
        "",
        f"Cars whose measured amplification no lower-level model replays within "
        f"{100 * g['tol']:.0f} %: **{g['n_gap']}** of {g['n_cars']}. For each, the best of "
        "the three models plus one effect at a time and the upper-level law were "
        f"calibrated again behind the measured predecessor (GA "
        f"{g['ga']['max_generations']} generations, {g['ga']['starts']} start) and replayed "
        "({func}`avll.studies.openacc_effects.effect_gaps`). An effect *closes* a gap when "
        f"its replay is within {100 * g['tol']:.0f} % of the measurement and it lowers the "
        f"calibration cost by at least {100 * g['min_gain']:.0f} %. Caveat: {g['caveat']}.",
        "",
        "Gaps closed per effect: " + ", ".join(
            f"{e} {g['closed_by'][e]}" for e in eff) + f"; closed by none: "
        f"{len(g['not_closed'])} of {g['n_gap']}.",
        "",
        "| car | measured | best model, replay error | " + " | ".join(eff) + " |",
        "|---|---|---|" + "---|" * len(eff),
    ]
    for c in g["cars"]:
        cells = []
        for e in eff:
            d = c["effects"][e]
            if "skipped" in d:
                cells.append("n/a")
                continue
            mark = " ✔" if d["closes_gap"] else ""
            cells.append(f"{_pct(d['amplification_replay_error'])} "
                         f"(cost {_pct(-d['cost_gain'] if d['cost_gain'] is not None else None)})"
                         f"{mark}")
        lines.append(f"| {c['run_id']} ({c['car']}, {c['setting']}) | "
                     f"{c['amplification_measured']:.2f} | {c['base_model']}, "
                     f"{_pct(c['base_amplification_replay_error'])} | " + " | ".join(cells) + " |")
    lines += ["", "Each cell: replay error of the amplification with the effect (cost change "
              "of the fit); ✔ closes the gap. n/a: the effect needs a signal the run lacks."]
    return lines
