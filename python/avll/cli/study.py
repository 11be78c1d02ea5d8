"""``avll study NAME``: studies on measured data.

* ``avll study openacc PATH --out DIR --json OUT.json``: every follower of native
  OpenACC files (e.g. ZalaZone) calibrated in closed loop, the calibrated time gap
  against the known ACC setting, and the measured against the predicted
  amplification of the predecessor's speed oscillations
  (:func:`avll.studies.openacc.openacc_study`).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .._limits import check_int
from ._common import (
    add_ga_budget,
    add_json,
    add_model,
    add_models,
    add_progress,
    add_seed,
    add_threads,
    declare_io,
    models_of,
)


def _openacc(args: argparse.Namespace) -> int:
    from ..progress import messages
    from ..spectral import check_band
    from ..studies.openacc import openacc_study

    log = messages("avll study openacc", args.progress)
    try:  # (also a ValueError for more or fewer than two numbers)
        lo, hi = map(float, args.band.split(","))
    except ValueError:
        raise ValueError(f"--band: expected LOW,HIGH in Hz, got {args.band!r}") from None
    check_band((lo, hi), 0.1)
    if not Path(args.path).exists():
        raise FileNotFoundError(f"{args.path}: no such file or folder")
    load: dict[str, Any] = {
        key: [v.strip() for v in val.split(",") if v.strip()]
        for key in ("setting", "car", "track") if (val := getattr(args, key)) is not None}
    st = openacc_study(args.path, model=args.model, models=models_of(args), seed=args.seed,
                       threads=args.threads, progress=args.progress, log=log,
                       max_generations=args.max_generations, pop_size=args.pop_size,
                       starts=args.starts, band=(lo, hi), n_boot=args.bootstrap,
                       gmin_max=args.gmin_max, acc_unknown=args.acc_unknown,
                       out_of_sample=not args.no_out_of_sample,
                       intervals=_intervals(args.resamples),
                       structures=_structures(args.structures), **load)  # fmt: skip
    log(f"writing {args.out}" + (f" and {args.json}" if args.json else ""))
    st.save(args.out, args.json)
    s = st.summary
    so = s["setting_order"]
    best = s["model_comparison"]["best"]
    camps = "; ".join(f"{k} {v['held']} of {v['checked']}" for k, v in so["campaigns"].items())
    print(f"{len(s['cars'])} runs of {len({(c['campaign'], c['car']) for c in s['cars']})} "
          f"cars in {len(s['campaigns'])} campaign(s) ({len(s['left_out'])} left out); "
          f"setting order held {so['held']} of {so['checked']}"
          + (f" ({camps})" if len(so["campaigns"]) > 1 else "")
          + f"; best amplification predictor: |H| {best['amplification_H'] or 'none'}, "
          f"replay {best['amplification_replay'] or 'none'}; wrote {args.out}")
    oos = s["out_of_sample"]["acc"]["oos_H_vs_h1"]
    if oos["n"]:
        inside = oos["inside_measured_ci"]
        print(f"out of sample (ACC cars, abs H vs H1): n {oos['n']}, mean error "
              f"{oos['mean_error']:+.3f}, within 10 % {oos['within_10pct']:.2f}, inside the "
              "measured 95 % interval "
              + ("n/a" if inside is None else f"{inside:.2f} of {oos['n_with_interval']}"))
    return 0


def _structures(text: str) -> Any:
    """The study's ``structures`` from ``--structures`` (``auto``, ``none`` or names)."""
    from ..effects import EFFECTS

    t = text.strip().lower()
    if t in ("auto", "none"):
        return t == "auto"
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in EFFECTS]
    if bad or not names:
        raise ValueError(f"--structures: expected auto, none or effect names "
                         f"({', '.join(EFFECTS)}), got {text!r}")
    return names


def _intervals(n: int | None) -> Any:
    """The study's ``intervals`` from ``--resamples``."""
    from ..uncertainty import Intervals

    if n is None:
        return True
    return False if check_int(n, "--resamples", min=0) == 0 else Intervals(n=n)


def register_openacc(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll study openacc``."""
    from ..paper import MODELS
    from ..studies.openacc import ACC_UNKNOWN, DEFAULT_BAND, GMIN_MAX, N_BOOT

    p = sub.add_parser(
        "openacc", help="native OpenACC files: closed-loop calibration per car, Tg vs the "
        "ACC setting, measured vs predicted string stability",
        description="Calibrate every follower of native OpenACC files (a file, a campaign "
        "folder as the JRC distributes it, or a folder of several campaigns) in "
        "closed loop behind its measured predecessor, check the calibrated time gap "
        "against the known ACC setting, and compare the measured amplification of the "
        "predecessor's speed oscillations with what the calibrated models predict. Writes "
        "tables (CSV), figures (PNG), report.md and summary.json into --out, as a whole "
        "with a manifest (an interrupted run leaves the old folder).")
    p.add_argument("path", metavar="PATH",
                   help="a native OpenACC data file, a campaign folder as distributed, or "
                   "a folder of several campaigns (required)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (required; no default)")
    add_json(p, "the summary (also written to DIR/summary.json)")
    add_model(p, "proposed", "lower-level model of the contract's params, Tg and prediction")
    add_models(p, MODELS, what="models compared")
    add_seed(p, "GA and the bootstrap")
    add_threads(p)
    add_ga_budget(p, pop_size=True, what="each car")
    p.add_argument("--band", default=f"{DEFAULT_BAND[0]:g},{DEFAULT_BAND[1]:g}",
                   metavar="LOW,HIGH",
                   help=f"amplification band in Hz (default: {DEFAULT_BAND[0]:g},"
                   f"{DEFAULT_BAND[1]:g})")
    p.add_argument("--bootstrap", type=int, default=N_BOOT,
                   help=f"bootstrap resamples (default: {N_BOOT})")
    p.add_argument("--gmin-max", type=float, default=GMIN_MAX,
                   help=f"upper bound of Gmin in m (default: {GMIN_MAX:g})")
    p.add_argument("--acc-unknown", choices=ACC_UNKNOWN, default="exclude",
                   help="runs whose ACC state the file does not give: left out and counted "
                   "(exclude, the default) or studied as ACC (include); human-driven runs "
                   "are always a separate control")
    p.add_argument("--setting", default=None,
                   help="keep these ACC settings, in the spellings of the campaigns' "
                   "notes, e.g. L,S or min (none: runs without a setting; default: all)")
    p.add_argument("--car", default=None,
                   help="keep these car models, comma-separated (default: all)")
    p.add_argument("--track", default=None,
                   help="keep these tracks, e.g. dynamic,handling (default: all)")
    p.add_argument("--resamples", type=int, default=None, metavar="N",
                   help="resamples of the intervals of the main model's calibrations "
                   "(block bootstrap over time refit from the optimum; 0: no intervals; "
                   "default: avll.Intervals().n)")
    p.add_argument("--no-out-of-sample", action="store_true",
                   help="skip the out-of-sample step (one model per car and setting "
                   "calibrated on the car's other files, predicting the held-out file; "
                   "default: run it)")
    p.add_argument("--structures", default="auto", metavar="auto|none|NAMES",
                   help="the cross-validated structure selection after the out-of-sample "
                   "step: auto (its default candidates), none, or candidate names "
                   "comma-separated, e.g. perception,closing (default: auto)")
    add_progress(p)
    declare_io(p, inputs=("path",), files=("json",), folders=("out",))
    p.set_defaults(func=_openacc)


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll study`` and its studies."""
    p = sub.add_parser("study", help="studies on measured data (openacc)",
                       description="Studies on measured data; see `avll study NAME -h`.")
    studies = p.add_subparsers(dest="study", required=True, metavar="STUDY")
    register_openacc(studies)
