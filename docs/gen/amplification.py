"""The validation table of the two measured-amplification estimators on synthetic
platoons with a known truth (``docs/_generated/amplification.md``, minutes).

For every scenario, :func:`avll.synth_platoon.validate_amplification` simulates
:data:`N_PLATOONS` platoons of :data:`CARS` random followers (first-order,
second-order and proposed lower levels in turn, constant-time-gap upper levels drawn
at random; seeds :data:`SEEDS`; the estimators' problems were diagnosed on other
seeds, 200-205, though a first version of this table was seen on these)
and scores the band RMS ratio with its circular block bootstrap interval, as the
study measures it (:func:`avll.studies.openacc.measured_amplification`), and the H1 band gain
(:func:`avll.spectral.h1_band_gain`) against each car's true band gain.

    python -m docs.gen --only amplification
"""

from __future__ import annotations

from typing import Any

from avll.report import num
from avll.synth_platoon import Equipment, validate_amplification

from . import Generated

CARS = 5
N_PLATOONS = 8
SEEDS = tuple(range(9100, 9100 + N_PLATOONS))

#: Noisy speed (slow 0.1 m/s on every car) for the input-noise scenario.
NOISY = Equipment("noisy-speed", speed_white=0.05, speed_coloured=0.1, speed_tau=3.0)

#: name -> (description, options of synth_platoon)
SCENARIOS: dict[str, tuple[str, dict[str, Any]]] = {
    "zalazone": ("VBOX-like noise, 600 s, follower disturbance 0.05 m/s²",
                 {"equipment": "zalazone"}),
    "jrc": ("u-blox-like noise, 600 s, follower disturbance 0.05 m/s²", {"equipment": "jrc"}),
    "short": ("u-blox-like noise, 130 s records (a ZalaZone dynamic file's length)",
              {"equipment": "jrc", "duration": 130.0}),
    "disturbed": ("u-blox-like noise, strong follower disturbance 0.3 m/s²",
                  {"equipment": "jrc", "disturbance_std": 0.3}),
    "noisy-input": ("slow speed noise 0.1 m/s on every car, weak excitation (band RMS "
                    "0.3 m/s)", {"equipment": NOISY, "band_rms": 0.3}),
}


def _pct(x: float | None, signed: bool = True) -> str:
    return num(None if x is None else 100 * x, "+.1f" if signed else ".1f") + (
        "" if x is None else " %")


def collect() -> dict[str, dict[str, Any]]:
    """Runs every scenario; returns name -> the validation summary."""
    out = {}
    for name, (_, kw) in SCENARIOS.items():
        v = validate_amplification(SEEDS, cars=CARS, **kw)
        out[name] = {"rms_ratio": v["rms_ratio"], "h1": v["h1"]}
    return out


def render(res: dict[str, dict[str, Any]]) -> str:
    """The fragment's body from :func:`collect`'s numbers."""
    lines = [f"{N_PLATOONS} platoons of {CARS} random followers per scenario (seeds "
             f"{SEEDS[0]}-{SEEDS[-1]}); error = estimate / true band gain - 1.", "",
             *[f"* **{n}**: {d}" for n, (d, _) in SCENARIOS.items()], "",
             "| scenario | estimator | cars (no estimate) | median error | mean error | "
             "median abs. error | within 10 % | 95 % interval coverage | median coherence |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, d in res.items():
        for key, label in (("rms_ratio", "band RMS ratio"), ("h1", "H1 band gain")):
            s = d[key]
            coh = num(s.get("median_coherence"), ".2f") if key == "h1" else "—"
            lines.append(
                f"| {name} | {label} | {s['n']} ({s['missing']}) | {_pct(s['median_error'])} | "
                f"{_pct(s['mean_error'])} | {_pct(s['median_abs_error'], False)} | "
                f"{num(s['within_10pct'], '.2f')} | {num(s['coverage'], '.2f')} | {coh} |")
    return "\n".join(lines) + "\n"


def generate() -> Generated:
    """The fragment: every scenario run, its table and numbers."""
    res = collect()
    return Generated(render(res), res)
