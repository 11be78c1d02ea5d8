"""The out-of-sample amplification prediction on every shared OpenACC campaign
(``docs/_generated/openacc_campaigns.md``, shown in ``docs/findings-campaigns.md``):
``avll study openacc`` with its defaults (intervals, leave one file out) but a reduced
GA budget and fewer resamples, with the cross-validated structure selection
(:data:`BUDGET`, stated on the page) and the main lower-level model only (the model
comparison is the ZalaZone findings page's), on each campaign folder under
``../shared/data`` as the JRC ships it. Per campaign: the ACC cars, how many have another
file of their setting (an out-of-sample prediction), the bias (mean error) of the
prediction against the measured H1 band gain with the base model and with the final
model (the structures the selection accepted), the share of measurements inside the
predictions' 95 % intervals and of predictions inside the measurements' 95 % intervals,
whatever they turn out to be. The studies' outputs go to ``out/openacc_campaigns``
(git-ignored); the numbers to the fragment's JSON sidecar.

    MPLBACKEND=Agg python -m docs.gen --only openacc-campaigns     # hours

``AVLL_DOCS_CAMPAIGNS=Casale,ZalaZone`` (labels of :data:`CAMPAIGNS`) runs only those;
the others are listed on the page as not run in this generation.
``AVLL_DOCS_STRUCTURES=0`` runs the studies without the structure selection (minutes
instead of hours on a 2-core machine); the page says which.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from avll import Intervals, _atomic
from avll.studies.openacc import openacc_study

from . import ROOT, head_commit

#: (label, folder under the data root) of the shared campaigns in the native format.
CAMPAIGNS = (
    ("Casale", "openacc-jrc/Casale"),
    ("JRC low speed", "openacc-jrc/JRC low speed"),
    ("ZalaZone", "openacc-zalazone"),
)
OUT = ROOT / "out" / "openacc_campaigns"
SEED = 0
#: The study's GA budget and resamples here: reduced from the study's defaults
#: (:data:`avll.defaults.GA_OPTIONS`, :data:`avll.defaults.DEFAULT_STARTS`,
#: ``avll.Intervals().n``) for the run time; the structure selection on (``structures``,
#: the study's default; the page's study time per campaign says what it costs). The
#: page states all three.
BUDGET: dict[str, Any] = {"max_generations": 100, "starts": 1, "resamples": 100,
                          "structures": True}


def _budget() -> dict[str, Any]:
    """:data:`BUDGET` with ``structures`` off when ``AVLL_DOCS_STRUCTURES=0``."""
    flag = os.environ.get("AVLL_DOCS_STRUCTURES", "1").strip()
    if flag not in ("0", "1"):
        raise ValueError(f"AVLL_DOCS_STRUCTURES: must be 0 or 1, got {flag!r}")
    return {**BUDGET, "structures": BUDGET["structures"] and flag == "1"}


def _log(msg: str) -> None:
    print(f"[openacc-campaigns] {msg}", file=sys.stderr, flush=True)


def _keep(vs: dict[str, Any] | None) -> dict[str, Any] | None:
    """The comparison's numbers the page shows (from the study's ``_vs`` record)."""
    if not vs:
        return None
    keys = ("n", "mean_error", "median_abs_error", "within_10pct_count", "underestimated",
            "n_with_interval", "inside_measured_ci_count", "n_with_prediction_interval",
            "measured_inside_predicted_ci_count", "prediction_interval_median_rel_width")
    return {k: vs.get(k) for k in keys}


def _reason_kinds(acc: list[dict[str, Any]]) -> dict[str, int]:
    """How many ACC cars lack an out-of-sample prediction, per kind of reason (the
    reason's text before its details: the run's length, the car's name, ...)."""
    kinds: dict[str, int] = {}
    for c in acc:
        if c["amplification_predicted_oos"] is None:
            why = str(c.get("amplification_predicted_oos_reason"))
            kind = why.split(":")[0].split(" (")[0].strip()
            kinds[kind] = kinds.get(kind, 0) + 1
    return dict(sorted(kinds.items(), key=lambda kv: (-kv[1], kv[0])))


def campaign_numbers(label: str, path: Path, seed: int = SEED) -> dict[str, Any]:
    """One campaign's study (:data:`BUDGET`, main model only) and the numbers of the
    page; kept in ``out/openacc_campaigns/SLUG.numbers.json`` and reused by a later
    run with the same settings (the commit each campaign ran at is in its numbers)."""
    slug = label.lower().replace(" ", "-")
    cache = OUT / f"{slug}.numbers.json"
    budget = _budget()
    settings = {"seed": seed, **budget}
    if cache.exists():
        old = json.loads(cache.read_text(encoding="utf-8"))
        if old.get("settings") == settings:
            _log(f"{label}: reusing {cache} (commit {old.get('commit')})")
            saved = OUT / f"{slug}.json"
            if "no_prediction_reason_kinds" not in old and saved.exists():
                # numbers kept before the reasons were counted: from the same study
                cars = json.loads(saved.read_text(encoding="utf-8"))["cars"]
                old["no_prediction_reason_kinds"] = _reason_kinds(
                    [c for c in cars if c["group"] == "acc"])
            return dict(old)
    commit = head_commit()
    t0 = time.perf_counter()
    study = openacc_study(path, seed=seed, models=("proposed",), figures=False, log=_log,
                          max_generations=budget["max_generations"],
                          starts=budget["starts"],
                          intervals=Intervals(n=budget["resamples"]),
                          structures=budget["structures"])  # fmt: skip
    seconds = time.perf_counter() - t0
    study.save(OUT / slug, OUT / f"{slug}.json")
    s = study.summary
    o, sel = s["out_of_sample"], s["structure_selection"]
    acc = [c for c in s["cars"] if c["group"] == "acc"]
    with_oos = [c for c in acc if c["amplification_predicted_oos"] is not None]
    out = {
        "campaign": label,
        "settings": settings,
        "commit": commit,
        "seconds": round(seconds, 1),
        "model": s["model"],
        "acc_cars": len(acc),
        "acc_cars_with_other_file": sum(bool(c["oos_files"]) for c in acc),
        "acc_cars_with_prediction": len(with_oos),
        "acc_cars_with_prediction_interval": sum(
            c["amplification_predicted_oos_ci"] is not None for c in with_oos),
        "no_prediction_reasons": sorted({str(c.get("amplification_predicted_oos_reason"))
                                         for c in acc
                                         if c["amplification_predicted_oos"] is None}),
        "no_prediction_reason_kinds": _reason_kinds(acc),
        "final_oos": _keep(o["acc"]["oos_H_vs_h1"]),
        "in_sample": _keep(o["acc"]["in_sample_H_vs_h1"]),
        "base_oos": _keep(sel["acc"]["base_oos_H_vs_h1"]) if sel["enabled"] else None,
        "selection_enabled": bool(sel["enabled"]),
        "selection_reason": sel.get("reason"),
        "accepted": sorted({"+".join(a["effects"]) for a in sel.get("accepted", [])
                            if a["effects"]}),
        "accepted_cars": len(sel.get("accepted", [])),
        "time_gap_oos_vs_headway": o["acc"]["time_gap_effective_oos_vs_headway_measured"],
    }
    _atomic.write_json(cache, _atomic.json_safe(out))
    return out


def compute(data_root: Path, seed: int = SEED) -> dict[str, Any]:
    """Every shared campaign present under ``data_root`` (absent ones are listed)."""
    from avll.defaults import DEFAULT_STARTS, GA_OPTIONS

    only = [c.strip() for c in os.environ.get("AVLL_DOCS_CAMPAIGNS", "").split(",")
            if c.strip()]
    unknown = set(only) - {label for label, _ in CAMPAIGNS}
    if unknown:
        raise ValueError(f"AVLL_DOCS_CAMPAIGNS: unknown campaign(s) {sorted(unknown)}; "
                         f"known: {', '.join(label for label, _ in CAMPAIGNS)}")
    out: dict[str, Any] = {"seed": seed, "budget": _budget(), "campaigns": [], "absent": [],
                           "failed": [], "not_run": [],
                           "study_defaults": {"max_generations": GA_OPTIONS["max_generations"],
                                              "starts": DEFAULT_STARTS,
                                              "resamples": Intervals().n}}
    for label, rel in CAMPAIGNS:
        path = data_root / rel
        if only and label not in only:
            out["not_run"].append(label)
            continue
        if not path.is_dir():
            out["absent"].append(label)
            continue
        _log(f"{label}: {path}")
        try:
            out["campaigns"].append(campaign_numbers(label, path, seed))
        except (ValueError, RuntimeError) as e:  # a study that fails is reported, not hidden
            _log(f"{label}: the study failed: {e}")
            out["failed"].append({"campaign": label, "error": str(e)})
            continue
        _log(f"{label}: {out['campaigns'][-1]['seconds']:.0f} s")
    return out


def _pct(x: float | None, sign: bool = True) -> str:
    if x is None:
        return "–"
    return f"{100 * x:+.1f} %" if sign else f"{100 * x:.1f} %"


def _share(k: int | None, n: int | None) -> str:
    return "–" if not n else f"{k} of {n}"


def render(numbers: dict[str, Any]) -> str:
    """The Markdown body."""
    b, d = numbers["budget"], numbers["study_defaults"]
    lines = [
        f"Seed {numbers['seed']}, main lower-level model only; GA {b['max_generations']} "
        f"generations x {b['starts']} start per car and {b['resamples']} resamples per "
        f"interval (the study's defaults: {d['max_generations']} x {d['starts']}, "
        f"{d['resamples']}; reduced for the run time, see the study time per campaign); "
        "structure selection "
        f"{'on' if b.get('structures', True) else 'off (base model only)'}"
        ". "
        "Prediction: abs H(jω) of the model calibrated on the car's *other* files of the "
        "same setting, on the held-out run's predecessor spectrum; measurement: the H1 "
        "cross-spectral band gain of the held-out run. Error: prediction / measurement − 1.",
        "",
        "| campaign | ACC cars | with an out-of-sample prediction | bias, base model | "
        "bias, final model | median abs error | within 10 % | under-estimated | measured "
        "inside the predicted 95 % interval | prediction inside the measured 95 % interval "
        "| median predicted interval width | structures accepted | in-sample bias | study "
        "time | commit |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in numbers["campaigns"]:
        f, i = c["final_oos"] or {}, c["in_sample"] or {}
        # without the selection the final model is the base model
        b = c["base_oos"] or (f if not c["selection_enabled"] else {})
        acc = (", ".join(c["accepted"]) + f" ({c['accepted_cars']} cars)"
               if c["accepted"] else ("none" if c["selection_enabled"] else "not run"))
        lines.append(
            f"| {c['campaign']} | {c['acc_cars']} | {c['acc_cars_with_prediction']} | "
            f"{_pct(b.get('mean_error'))} | {_pct(f.get('mean_error'))} | "
            f"{_pct(f.get('median_abs_error'), False)} | "
            f"{_share(f.get('within_10pct_count'), f.get('n'))} | "
            f"{_share(f.get('underestimated'), f.get('n'))} | "
            f"{_share(f.get('measured_inside_predicted_ci_count'), f.get('n_with_prediction_interval'))} | "  # noqa: E501
            f"{_share(f.get('inside_measured_ci_count'), f.get('n_with_interval'))} | "
            f"{_pct(f.get('prediction_interval_median_rel_width'), False)} | {acc} | "
            f"{_pct(i.get('mean_error'))} | {c['seconds'] / 60:.0f} min | {c['commit']} |")
    lines.append("")
    for c in numbers["campaigns"]:
        missing = c["acc_cars"] - c["acc_cars_with_prediction"]
        if missing:
            kinds = c.get("no_prediction_reason_kinds") or dict.fromkeys(
                c["no_prediction_reasons"], None)
            why = "; ".join(k if n is None else f"{n} x {k}" for k, n in kinds.items())
            lines.append(f"- {c['campaign']}: {missing} ACC car(s) without an out-of-sample "
                         f"prediction ({why}).")
        if not c["selection_enabled"]:
            lines.append(f"- {c['campaign']}: structure selection {c['selection_reason']}.")
    for f in numbers.get("failed", []):
        lines.append(f"- {f['campaign']}: the study failed: {f['error']}")
    if numbers.get("not_run"):
        lines.append(f"- Not run in this generation: {', '.join(numbers['not_run'])} (the "
                     "study with intervals on every car of a large campaign takes hours "
                     "here; run the generator without AVLL_DOCS_CAMPAIGNS).")
    if numbers["absent"]:
        lines.append(f"- Not in the data folder: {', '.join(numbers['absent'])}.")
    return "\n".join(lines).rstrip() + "\n"
