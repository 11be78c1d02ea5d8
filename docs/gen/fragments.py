"""The docs' own fragments: tables formatted from what the code computes (the default
boxes, the GA options, the effects registry, Section IV, the reproduction tables, the
README's blocks). Registered and written by :mod:`docs.gen`; no stamping or writing here.

Formerly ``benches/docs_numbers.py`` and ``benches/readme_numbers.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from avll.report import num as _f

ROOT = Path(__file__).resolve().parents[2]


# --------------------------------------------------------------------------- README blocks

_MODELS = ("second", "proposed", "first")

#: Where each sub-command is explained in the docs (commands not listed link to the
#: command-line reference page).
GUIDES: dict[str, str] = {
    "simulate": "docs/guide/simulate.md",
    "synth": "docs/guide/simulate.md",
    "load": "docs/guide/field-data.md",
    "calibrate": "docs/guide/calibrate.md",
    "stability-map": "docs/guide/stability.md",
    "diagnose": "docs/guide/diagnose.md",
    "reproduce": "docs/guide/reproduce.md",
    "data": "docs/data.md",
}


def section_iv_numbers(threads: int = 0) -> dict[str, Any]:
    """Section IV numbers of the paper's Table II models on ``avll reproduce``'s default
    grids: ``{"models": {name: {"kv_threshold", "min_tg", "capacity"}}, "ratios": {...},
    "settings": Settings, "paper": PAPER, "length", "speed"}`` (the last two: the
    capacity formula's constants)."""
    import avll
    from avll.reproduce import PAPER, SETTINGS, capacity_ratios, stability_summary

    settings = SETTINGS["default"]
    models = {}
    for m in _MODELS:
        s = stability_summary(avll.PAPER_TABLE_II[m], settings, threads=threads)
        models[m] = {k: s[k] for k in ("kv_threshold", "min_tg", "capacity")}
    ratios = capacity_ratios(models)
    from avll.stability import CAPACITY_LENGTH, CAPACITY_SPEED

    return {"models": models, "ratios": ratios, "settings": settings, "paper": PAPER,
            "length": CAPACITY_LENGTH, "speed": CAPACITY_SPEED}


def _fn(x: float | None, fmt: str, none: str = "none") -> str:
    return none if x is None else format(x, fmt)


def render_section_iv(n: dict[str, Any]) -> str:
    """The README's ``section-iv`` block (Markdown) from :func:`section_iv_numbers`."""
    p, m, r, s = n["paper"], n["models"], n["ratios"], n["settings"]

    def three(src: dict[str, Any], key: str, fmt: str) -> str:
        return " / ".join(_fn(src[k][key] if key in src[k] else None, fmt)
                          for k in _MODELS)

    paper3 = {k: {"min_tg": p["min_tg"][k], "capacity": p["capacity"][k]} for k in _MODELS}
    none_kv = f"none up to kv = {s.kv_max:g}"
    rows = [
        ("kv threshold, second-order (1/s)", _fn(p["kv_threshold"]["second"], ".4f"),
         _fn(m["second"]["kv_threshold"], ".4f", none_kv)),
        ("kv threshold, proposed (1/s)", _fn(p["kv_threshold"]["proposed"], ".4f"),
         _fn(m["proposed"]["kv_threshold"], ".4f", none_kv)),
        ("kv threshold, first-order lag", "none",
         _fn(m["first"]["kv_threshold"], ".4f", none_kv)),
        ("min stable Tg, second / proposed / first (s)", three(paper3, "min_tg", ".1f"),
         three(m, "min_tg", ".1f")),
        ("capacity at that Tg (veh/h)", three(paper3, "capacity", ".1f"),
         three(m, "capacity", ".1f")),
        ("capacity, proposed vs second-order",
         f"{p['capacity_proposed_vs_second_pct']:.2f} % lower",
         _fn(r["capacity_proposed_vs_second_pct"], ".2f") + " % lower"),
        ("capacity, first-order lag vs proposed",
         f"{p['capacity_first_vs_proposed_pct']:.2f} % larger",
         _fn(r["capacity_first_vs_proposed_pct"], ".2f") + " % larger"),
    ]
    lines = ["| Section IV, Table II parameters | paper | avll |", "|---|---|---|"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    lines.append("")
    lines.append(
        f"Grid: kg log-spaced {s.kg_min:g}..{s.kg_max:g} ({s.kg_n} points) × Tg "
        f"0..{s.tg_max:g} s step {s.tg_step:g} × kv 0..{s.kv_max:g} step {s.kv_step:g}, "
        f"Padé order {s.pade_order}; kv threshold by bisection to {s.kv_tol:g} on a "
        f"{s.kv_tg_step:g} s Tg grid; capacity `3600 / (Tg + {n['length']:g}/{n['speed']:g})`"
        " veh/h (an effective vehicle length of "
        f"{n['length']:g} m at {n['speed']:g} m/s, inferred from the paper's capacities)."
    )
    return "\n".join(lines)


def cli_commands() -> list[tuple[str, str]]:
    """``(name, help)`` of every ``avll`` sub-command, in ``avll --help`` order."""
    from avll.cli import build_parser

    parser = build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return [(a.dest, " ".join((a.help or "").split())) for a in action._choices_actions]
    raise RuntimeError("avll's parser has no sub-commands")


def render_cli(commands: list[tuple[str, str]]) -> str:
    """The ``cli`` block (Markdown) from :func:`cli_commands`'s result."""
    lines = ["| command | does | guide |", "|---|---|---|"]
    for name, text in commands:
        guide = GUIDES.get(name, "docs/cli.md")
        lines.append(f"| `avll {name}` | {text} | [{Path(guide).stem}]({guide}) |")
    return "\n".join(lines)


# --------------------------------------------------------------------------- docs fragments


def bounds() -> str:
    """The default search boxes of ``avll.calibrate`` with the reason for each."""
    from avll.calibration import DEFAULT_BOUNDS, UPPER_BOUNDS
    from avll.defaults import BOUND_REASONS

    def why(model: str, p: str) -> str:
        return BOUND_REASONS.get(f"{model}.{p}", BOUND_REASONS.get(p, ""))

    lines = ["| model | parameter | lower | upper | search scale | why |",
             "|---|---|---|---|---|---|"]
    for model, box in DEFAULT_BOUNDS.items():
        for p, (lo, hi, scale) in box.items():
            lines.append(f"| {model} | `{p}` | {lo:g} | {hi:g} | {scale} | {why(model, p)} |")
    for p, (lo, hi, scale) in UPPER_BOUNDS.items():
        lines.append(f"| upper level (when calibrated) | `{p}` | {lo:g} | {hi:g} | {scale} | "
                     f"{why('upper', p)} |")
    return "\n".join(lines)


def ga_options() -> str:
    """The GA options of ``avll.calibrate`` and their defaults (0: chosen from the size
    of the problem, see the calibration guide)."""
    from avll.calibration import DEFAULT_STARTS, GA_OPTIONS

    lines = ["| option | default |", "|---|---|", f"| `starts` | {DEFAULT_STARTS} |"]
    lines += [f"| `{k}` | {v!r} |" for k, v in GA_OPTIONS.items()]
    return "\n".join(lines)


def effects() -> str:
    """The effects registry: class, parameters and their calibration bounds."""
    import dataclasses

    import avll

    lines = ["| effect | level | class | parameters (calibration bounds) |",
             "|---|---|---|---|"]
    for name, cls in avll.EFFECTS.items():
        params = [f.name for f in dataclasses.fields(cls)]
        cells = ", ".join(f"`{p}` ({lo:g} to {hi:g})" for p, (lo, hi) in zip(params, cls.bounds,
                                                                             strict=True))
        lines.append(f"| `{name}` | {cls.level} | `avll.{cls.__name__}` | {cells} |")
    return "\n".join(lines)


def section_iv() -> str:
    """Section IV with Table II: the README's table, grid and Padé sensitivity (the docs'
    ``section-iv`` fragment)."""
    import avll
    from avll import stability as S
    from avll.paper import SECTION_IV_GRID as G
    from avll.paper import section_iv_axis

    out = [render_section_iv(section_iv_numbers())]
    P = avll.PAPER_TABLE_II
    (kg_lo, kg_hi, kg_n), (tg_lo, tg_hi, _) = G["kg"], G["Tg"]
    step, tol = G["kv_tg_step"], G["kv_tol"]
    tg = section_iv_axis(tg_lo, tg_hi, round((tg_hi - tg_lo) / step) + 1)
    out += ["", f"kv threshold (1/s) against the smallest kg of the grid (kg log-spaced up to "
            f"{kg_hi:g}, {kg_n} points; Tg {tg_lo:g}..{tg_hi:g} s step {step:g}; Padé "
            f"{G['pade_order']}; bisection to {tol:g}):", "",
            "| smallest kg | second-order | proposed |", "|---|---|---|"]
    for kg_min in (1e-2, 1e-3, 1e-4):
        kg = section_iv_axis(kg_min, kg_hi, kg_n, log=True)
        row = [S.kv_threshold(P[n], kg, tg, 0.5, 1.0, G["pade_order"], tol=tol)
               for n in ("second", "proposed")]
        out.append(f"| {kg_min:g} | {row[0]:.4f} | {row[1]:.4f} |")
    kg = section_iv_axis(kg_lo, kg_hi, kg_n, log=True)
    out += ["", f"kv threshold (1/s) against the Padé order of the delay (kg {kg_lo:g}..{kg_hi:g}, "
            "same Tg grid):", "", "| Padé order | second-order | proposed |", "|---|---|---|"]
    for order in (1, 2, 3, 4, 5, 8):
        row = [S.kv_threshold(P[n], kg, tg, 0.3, 1.2, order, tol=tol)
               for n in ("second", "proposed")]
        out.append(f"| {order} | {row[0]:.4f} | {row[1]:.4f} |")
    return "\n".join(out)


def _reproduce_summary(seed: int, path: Path | None) -> dict[str, Any]:
    if path is not None:
        return json.loads(path.read_text(encoding="utf-8"))
    from avll.reproduce import reproduce

    with tempfile.TemporaryDirectory() as tmp:
        return reproduce(tmp, seed=seed, progress=False)


def reproduce_table(summary: dict[str, Any]) -> str:
    """The reproduction table (paper vs avll) of one ``avll reproduce`` summary."""
    p, cal, st, stc = (summary["paper"], summary["calibration"], summary["stability"],
                       summary["stability_calibrated"])
    ratios, ratios_c = summary["stability_ratios"], summary["stability_calibrated_ratios"]
    order = ("proposed", "second", "first")

    def three(src: dict[str, Any], key: str, fmt: str, ms: tuple[str, ...] = order) -> str:
        return " / ".join(_f(src[m][key], fmt) for m in ms)

    pap = {m: {"cal_mse": p["cal_mse"][m], "val_mse": p["val_mse"][m]} for m in order}
    vr = {m: cal[m]["val_mse"] / cal["proposed"]["val_mse"] for m in ("second", "first")}
    pvr = {m: p["val_mse"][m] / p["val_mse"]["proposed"] for m in ("second", "first")}
    st4 = ("second", "proposed", "first")
    pst = {m: {"min_tg": p["min_tg"][m], "kv_threshold": p["kv_threshold"][m],
               "capacity": p["capacity"][m]} for m in st4}
    rows = [
        ("kv threshold second / proposed (1/s)", three(pst, "kv_threshold", ".4f", st4[:2]),
         three(st, "kv_threshold", ".4f", st4[:2]), "yes"),
        ("min stable Tg second / proposed / first (s)", three(pst, "min_tg", ".1f", st4),
         three(st, "min_tg", ".1f", st4), "yes"),
        ("capacity second / proposed / first (veh/h)", three(pst, "capacity", ".1f", st4),
         three(st, "capacity", ".1f", st4), "yes"),
        ("capacity, proposed vs second-order (% lower)",
         _f(p["capacity_proposed_vs_second_pct"], ".2f"),
         _f(ratios["capacity_proposed_vs_second_pct"], ".2f"), "yes"),
        ("capacity, first-order vs proposed (% larger)",
         _f(p["capacity_first_vs_proposed_pct"], ".2f"),
         _f(ratios["capacity_first_vs_proposed_pct"], ".2f"), "yes"),
        ("average calibration MSE proposed / second / first ((m/s²)²)",
         three(pap, "cal_mse", '.4g'), three(cal, "cal_mse", ".3g"), "no (synthetic data)"),
        ("average validation MSE proposed / second / first ((m/s²)²)",
         three(pap, "val_mse", '.4g'), three(cal, "val_mse", ".3g"), "no"),
        ("ranking, calibration / validation", " < ".join(summary["ranking"]["paper"]),
         " < ".join(summary["ranking"]["cal"]) + " / " + " < ".join(summary["ranking"]["val"]),
         "yes" if summary["ranking"]["cal"] == summary["ranking"]["val"]
         == summary["ranking"]["paper"] else "**no**"),
        ("validation MSE ratio second / proposed, first / proposed",
         f"{pvr['second']:.2f}, {pvr['first']:.2f}", f"{vr['second']:.1f}, {vr['first']:.1f}",
         "direction only"),
        ("calibrated models: min stable Tg second / proposed / first (s)",
         "(Table II: " + three(pst, "min_tg", ".1f", st4) + ")",
         three(stc, "min_tg", ".1f", st4), "see the finding below"),
        ("calibrated models: kv threshold second / proposed (1/s)",
         "(Table II: " + three(pst, "kv_threshold", ".4f", st4[:2]) + ")",
         three(stc, "kv_threshold", ".4f", st4[:2]), ""),
        ("calibrated models: capacity proposed vs second-order (% lower)", "",
         _f(ratios_c["capacity_proposed_vs_second_pct"], ".1f"), ""),
        ("calibrated models: capacity first-order vs proposed (% larger)", "",
         _f(ratios_c["capacity_first_vs_proposed_pct"], ".1f"), ""),
    ]
    diag = summary.get("diagnosis") or {}
    if diag.get("available", True) and "effects" in diag:
        rows.append(("residual loop on the calibrated proposed model: effects accepted", "—",
                     ", ".join(diag["effects"]) or "none", ""))
    lines = ["| quantity | paper | avll | comparable? |", "|---|---|---|---|"]
    lines += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows]
    # parameter errors of the calibrated proposed model against Table II
    tp = p["params"]["proposed"] if "params" in p else None
    fitted = cal["proposed"]["params"]
    if tp:
        errs = ", ".join(f"{k} {100 * (fitted[k] - v) / v:+.1f} %" for k, v in tp.items()
                         if k in fitted and v)
        lines += ["", f"Calibrated proposed model against Table II: {errs}."]
    return "\n".join(lines)


def reproduce(summary_path: Path | None = None) -> str:
    """The ``reproduce`` fragment (seed 0)."""
    s = _reproduce_summary(0, summary_path)
    st = s.get("settings", {})
    return (f"Seed {s.get('seed', 0)}, GA budget {st.get('max_generations')} "
            f"generations × {st.get('starts')} starts, {s['data']['runs']} synthetic runs "
            f"({len(s['data']['cal_runs'])} calibrate, {len(s['data']['val_runs'])} "
            "validate).\n\n" + reproduce_table(s))


def seeds(which: tuple[int, ...] = (0, 1, 2)) -> str:
    """The calibrated Section IV numbers for several data seeds."""
    lines = ["| seed | val MSE proposed / second / first | calibrated min Tg proposed / "
             "second / first (s) | calibrated kv threshold proposed / second (1/s) | "
             "effects accepted |", "|---|---|---|---|---|"]
    for seed in which:
        s = _reproduce_summary(seed, None)
        cal, stc = s["calibration"], s["stability_calibrated"]
        m3 = ("proposed", "second", "first")
        eff = ", ".join((s.get("diagnosis") or {}).get("effects", [])) or "none"
        lines.append(
            f"| {seed} | {' / '.join(_f(cal[m]['val_mse'], '.3g') for m in m3)} | "
            f"{' / '.join(_f(stc[m]['min_tg'], '.1f') for m in m3)} | "
            f"{' / '.join(_f(stc[m]['kv_threshold'], '.4f') for m in m3[:2])} | {eff} |")
    return "\n".join(lines)


def blind() -> str:
    """The blind-test table of :mod:`avll.studies.blind.library` without its timing column."""
    from avll.studies.blind import library

    rows = []
    for line in library.table():
        if line.startswith("|"):
            cells = line.strip().strip("|").split("|")
            rows.append("|" + "|".join(cells[:-1]) + "|")
    return "\n".join(rows)


def _freq_response(m: Any, w: np.ndarray) -> np.ndarray:
    """``G_fb(jw)`` of a model, from Eq. 5 (its ``linear()`` coefficients)."""
    c = m.linear()
    s = 1j * w
    g = (c["b1"] * s + c["b0"]) * np.exp(-c["Td"] * s) / (c["a2"] * s * s + c["a1"] * s + 1)
    return g / (1 - c["K"] * g)


def _low_freq_delay(m: Any) -> float:
    """``-d arg G_fb / dw`` at 0: ``(Td + a1 - b1/b0) / (1 - K b0)``."""
    c = m.linear()
    return (c["Td"] + c["a1"] - c["b1"] / c["b0"]) / (1 - c["K"] * c["b0"])


#: Datasets of the recovery table: data seeds and the run length (s).
RECOVERY_SEEDS = (100, 101, 102, 103, 104)
RECOVERY_DURATION = 180.0


def recovery() -> str:
    """Recovery and identifiability: each model calibrated (default settings, seed =
    dataset index) on five synthetic datasets of the paper's calibration runs generated
    by Table II's model of the same kind; what is identified (largest error over the
    datasets) and what is not (range of the fits)."""
    import avll
    from avll.paper import TABLE_II
    from avll.synth import PAPER_CAL_RUNS, paper_experiment

    w_all = np.linspace(0.05, 1.0, 20)
    w_band = np.linspace(0.1, 1.0, 10)
    rows = []
    for name in ("first", "second", "proposed"):
        true = TABLE_II[name]
        fits = []
        for k, seed in enumerate(RECOVERY_SEEDS):
            runs = paper_experiment(true, seed=seed, runs=PAPER_CAL_RUNS,
                                    duration=RECOVERY_DURATION)
            fits.append(avll.calibrate(name, runs, seed=k).model)

        def err(f: Callable[[Any], float], fits: list[Any] = fits, true: Any = true) -> str:
            return f"{100 * max(abs(f(m) / f(true) - 1) for m in fits):.2g} %"

        def span(p: str, fits: list[Any] = fits) -> str:
            v = [getattr(m, p) for m in fits]
            return f"{p} {min(v):.3g}–{max(v):.3g}"

        def freq(w: np.ndarray, fits: list[Any] = fits, true: Any = true) -> str:
            h0 = _freq_response(true, w)
            mag = max(float(np.max(np.abs(np.abs(_freq_response(m, w)) / np.abs(h0) - 1)))
                      for m in fits)
            ph = max(float(np.max(np.abs(np.angle(_freq_response(m, w) / h0)))) for m in fits)
            return (f"\\|H(jω)\\| {100 * mag:.2g} %, phase {ph:.2g} rad for "
                    f"{w[0]:g} ≤ ω ≤ {w[-1]:g} rad/s")

        truth = ", ".join(f"{p} = {getattr(true, p):.4g}" for p in true.param_names())
        if name == "first":
            ident, not_ident = f"Td {err(lambda m: m.Td)}", "—"
        elif name == "second":
            ident = (f"K0 {err(lambda m: m.K0)}; low-frequency delay Td + m3 "
                     f"{err(_low_freq_delay)}; {freq(w_all)}")
            not_ident = ", ".join(span(p) for p in ("Td", "m2", "m3"))
        else:
            ident = (f"DC gain K0/(1 − K K0) {err(lambda m: m.dc_gain)}; low-frequency delay "
                     f"{err(_low_freq_delay)}; {freq(w_band)}")
            not_ident = ", ".join(span(p) for p in true.param_names())
        rows.append(f"| {name} ({truth}) | {ident} | {not_ident} |")
    head = [
        f"{len(RECOVERY_SEEDS)} synthetic datasets (the paper's {len(PAPER_CAL_RUNS)} "
        f"calibration runs, {RECOVERY_DURATION:g} s each, default noise, data seeds "
        f"{', '.join(map(str, RECOVERY_SEEDS))}), generated by Table II's model of each "
        "kind; one default calibration per dataset (seed = dataset index).",
        "",
        "| true model | identified (largest error over the datasets) | not identified "
        "(range of the fits) |",
        "|---|---|---|",
    ]
    return "\n".join(head + rows)


def reproduce_data(data_root: Path) -> str:
    """``avll reproduce --data carma`` and ``--data openacc-astazero`` on the shared field
    data: what each prints, and the residual loop's verdict from its summary."""
    out = []
    for name, sub in (("carma", "carma"), ("openacc-astazero", "openacc-astazero")):
        path = data_root / sub
        if not path.exists():
            raise SystemExit(f"reproduce-data: {path} is missing (pass --data-root)")
        with tempfile.TemporaryDirectory() as tmp:
            dest = Path(tmp) / "out"
            r = subprocess.run([sys.executable, "-m", "avll", "reproduce", "--data", name,
                                "--data-path", str(path), "--out", str(dest), "-q"],
                               cwd=ROOT, capture_output=True, text=True,
                               env=os.environ | {"MPLBACKEND": "Agg"})  # fmt: skip
            if r.returncode != 0:
                raise SystemExit(f"reproduce-data: avll reproduce --data {name} failed:\n"
                                 f"{r.stderr}")
            summary = json.loads((dest / "summary.json").read_text())
            printed = r.stdout.replace(str(dest), "OUT").rstrip()
        diag = summary.get("diagnosis") or {}
        if diag.get("available", True) and "effects" in diag:
            runs = diag.get("runs") or {}
            label = runs.get("label", "one vehicle") if isinstance(runs, dict) else "one vehicle"
            verdict = (f"residual loop on {label}: effects accepted: "
                       f"{', '.join(diag['effects']) or 'none'}; flags: "
                       f"{', '.join(sorted({f['kind'] for f in diag.get('flags', [])})) or 'none'}")
        else:
            verdict = "residual loop: not run"
        out += [f"`avll reproduce --data {name}` ({verdict}):", "", "```text", printed, "```",
                ""]
    return "\n".join(out)
