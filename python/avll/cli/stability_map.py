"""``avll stability-map``: local and exact string stability over a kg x Tg x kv grid,
for the paper's Table II models or the models of a calibration JSON (``--from``)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._limits import check_int, check_memory, check_number
from ..paper import SECTION_IV_GRID, section_iv_axis
from ..report import num
from ._common import add_json, add_models, add_progress, add_threads, declare_io, models_of


def _range(spec: Sequence[str], name: str, log: bool = False) -> np.ndarray:
    try:
        lo, hi, n = float(spec[0]), float(spec[1]), int(spec[2])
    except (ValueError, IndexError):
        raise ValueError(f"--{name}: expected MIN MAX N, got {' '.join(spec)}") from None
    check_int(n, f"--{name}: N", min=2)
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise ValueError(f"--{name}: need finite MIN <= MAX, got {lo:g} {hi:g}")
    if hi == lo:
        raise ValueError(f"--{name}: MIN and MAX are both {lo:g}; an axis needs MIN < MAX")
    check_memory(8.0 * n, f"--{name}: N = {n} points", "use a smaller N")
    if log and lo <= 0:
        raise ValueError(f"--{name}: a log-spaced axis needs MIN > 0, got {lo}")
    return section_iv_axis(lo, hi, n, log)  # the default axes are reproduce's, bit for bit


def models_from_json(path: str | Path, names: Sequence[str] | None = None) -> dict[str, Any]:
    """The calibrated models of a calibration JSON (what ``avll calibrate --json``
    writes: ``{"models": {name: {"params": {...}}}}``), by model name; ``names``
    keeps only those. A ``ValueError`` naming the file and the entry when it is not
    such a file."""
    from .. import _atomic
    from ..defaults import UPPER_NAMES
    from ..models import model_class

    p = Path(path)
    try:
        doc = _atomic.loads(p.read_text(encoding="utf-8"))
    except ValueError as e:  # not strict JSON, not UTF-8, an integer too long
        raise ValueError(f"--from: {p}: {e}") from None
    except OSError as e:  # missing, a folder, unreadable
        raise OSError(f"--from: {p}: {e.strerror or e}") from None
    entries = doc.get("models") if isinstance(doc, dict) else None
    if not isinstance(entries, dict) or not entries:
        raise ValueError(f"--from: {p}: expected a calibration JSON with a \"models\" object "
                         "(as written by avll calibrate --json)")
    out: dict[str, Any] = {}
    for name, entry in entries.items():
        if names and name not in names:
            continue
        try:
            cls = model_class(name)
        except ValueError as e:
            raise ValueError(f"--from: {p}: models.{name}: {e}") from None
        params = entry.get("params") if isinstance(entry, dict) else None
        if not isinstance(params, dict):
            raise ValueError(f"--from: {p}: models.{name}: has no \"params\" object")
        # a closed-loop calibration also holds the free upper-level gains: the map
        # sweeps kg, Tg and kv itself, so they are not used
        unknown = [k for k in params if k not in cls.param_names() + UPPER_NAMES]
        if unknown:
            raise ValueError(f"--from: {p}: models.{name}.params.{unknown[0]}: not a parameter "
                             f"of the {name} model ({', '.join(cls.param_names())}) nor an "
                             f"upper-level gain ({', '.join(UPPER_NAMES)})")
        vals = {k: check_number(params.get(k), f"--from: {p}: models.{name}.params.{k}")
                for k in cls.param_names()}
        try:
            out[name] = cls(**vals)
        except ValueError as e:  # a value out of the model's range
            raise ValueError(f"--from: {p}: models.{name}.params.{e}") from None
    if names:
        missing = [n for n in names if n not in out]
        if missing:
            raise ValueError(f"--models: {', '.join(missing)} not in {p} (it has "
                             f"{', '.join(entries)})")
    return out


def _cmd(args: argparse.Namespace) -> int:
    from .. import PAPER_TABLE_II
    from ..plotting import model_label
    from ..stability import (
        capacity,
        kv_supremum,
        min_stable_tg,
        plot_regions,
        plot_thresholds,
        stability_map,
        thresholds,
    )

    check_int(args.panels, "--panels", min=1)
    check_number(args.length, "--length", nonneg=True)
    check_number(args.speed, "--speed", positive=True)
    kg = _range(args.kg, "kg", log=args.kg_log)
    tg = _range(args.tg, "tg")
    kv = _range(args.kv, "kv")
    if args.source:
        models = list(models_from_json(args.source, args.models).values())
        source = f"calibrated ({Path(args.source).name})"
    else:
        models = [PAPER_TABLE_II[n] for n in models_of(args)]
        source = "Table II"
    labels = [f"{model_label(m.name)}, {source}" for m in models]
    # every model's map is kept (a byte a point), plus what each derives from its map
    n_pts = float(kg.size) * tg.size * kv.size
    check_memory(n_pts * (len(models) + 1.0),
                 f"--kg x --tg x --kv: {kg.size} x {tg.size} x {kv.size} = {n_pts:.0f} points "
                 f"x {len(models)} map(s)", "use a smaller N in --kg, --tg or --kv",
                 per=len(models) + 1.0, unit="points")
    show = args.progress if kg.size * tg.size * kv.size >= 2_000_000 else "none"
    if args.scheduler:
        from ..maps import sweep

        swept = sweep({m.name: m for m in models}, kg, tg, kv, (args.pade_order,),
                      client=args.scheduler, threads=args.threads)
        maps = [np.asarray(swept.values[i, 0]) for i in range(len(models))]
    else:
        maps = [stability_map(m, kg, tg, kv, args.pade_order, threads=args.threads,
                              progress=show) for m in models]
    ths = [thresholds(mp, kg, tg, kv) for mp in maps]
    print(f"models: {source}")
    print(
        f"grid: kg {kg[0]:g}..{kg[-1]:g} ({kg.size}{', log' if args.kg_log else ''}), "
        f"Tg {tg[0]:g}..{tg[-1]:g} ({tg.size}), kv {kv[0]:g}..{kv[-1]:g} ({kv.size}), "
        f"Padé order {args.pade_order}"
    )
    print(f"{'model':<10} {'kv last stable':>15} {'kv first empty':>15} {'min Tg (s)':>10} "
          f"{'capacity (veh/h)':>17}")
    for m, th in zip(models, ths, strict=True):
        cap = capacity(th.tg_min_overall, args.length, args.speed)
        print(f"{m.name:<10} {num(th.kv_last_stable, '.6g', 'none'):>15} "
              f"{num(th.kv_first_empty, '.6g', 'none'):>15} "
              f"{num(th.tg_min_overall, '.4g', 'none'):>10} {num(cap, '.1f', 'none'):>17}")
    if any(math.isnan(th.kv_first_empty) for th in ths):
        print(f"(kv first empty: none means stable points remain up to the grid's last kv, "
              f"{kv[-1]:g}: no kv threshold in the given range)")
    exact: dict[str, dict[str, Any]] = {}
    if args.exact:
        kg_r, tg_r, kv_r = ((float(x.min()), float(x.max())) for x in (kg, tg, kv))
        lo = kg_r if kg_r[0] > 0 else (1e-6, kg_r[1])
        print("\nexact (not grid-bound) over the same ranges (kg, Tg and kv of the grid"
              + ("; kg from 1e-06, as kg = 0 has no gap control" if kg_r[0] <= 0 else "")
              + "):")
        for m in models:
            e1 = min_stable_tg(m, lo, kv_r, args.pade_order, tg_range=tg_r,
                               threads=args.threads)
            e2 = kv_supremum(m, lo, tg_r, args.pade_order, kv_range=kv_r, threads=args.threads)
            exact[m.name] = {"min_stable_tg": e1.to_dict(), "kv_supremum": e2.to_dict()}
            print(f"{m.name:<10} {_exact_tg_text(e1, tg_r)}; {_exact_kv_text(e2, kv_r)}")
    print()
    rows = _table_rows(kv.size)
    print("kv (1/s)".rjust(10)
          + "".join(f"{m.name + ' kg_max':>18}{m.name + ' Tg_min':>18}" for m in models))
    edges = False
    for j in rows:
        cells = []
        for th in ths:
            kgc, tgc = num(th.kg_max[j], ".6g", "none"), num(th.tg_min[j], ".6g", "none")
            if th.kg_max[j] == th.kg_edge:
                kgc, edges = f">= {kgc}", True
            if th.tg_min[j] == th.tg_edge:
                tgc, edges = f"<= {tgc}", True
            cells.append(f"{kgc:>18}{tgc:>18}")
        print(f"{kv[j]:>10.4g}" + "".join(cells))
    if edges:
        print("(>= / <=: the value is the grid's edge; the threshold lies at or beyond it)")
    if len(rows) < kv.size:
        where = f"in {args.json}" if args.json else "with --json PATH"
        print(f"({len(rows)} of {kv.size} kv values shown; every value {where})")
    figs: list[tuple[str, Any]] = []
    if args.out:
        idx = _panel_indices(maps, kv.size, args.panels)
        fig = plot_regions(models, kg, tg, kv[idx], args.pade_order,
                           maps=[mp[:, :, idx] for mp in maps], labels=labels)
        figs.append((args.out, fig))
    if args.thresholds_out:
        figs.append((args.thresholds_out, plot_thresholds(models, ths, labels=labels)))
    doc: dict[str, Any] = {
        "source": {"kind": "calibration" if args.source else "paper_table_ii",
                   "path": str(args.source) if args.source else None},
        "grid": {"kg": [float(kg[0]), float(kg[-1]), kg.size, "log" if args.kg_log else "lin"],
                 "tg": [float(tg[0]), float(tg[-1]), tg.size],
                 "kv": [float(kv[0]), float(kv[-1]), kv.size],
                 "pade_order": args.pade_order},
        "capacity": {"formula": "3600 / (Tg + length / speed)", "length": args.length,
                     "speed": args.speed},
        "models": {m.name: {"params": m.to_dict(), **th.to_dict(),
                            "capacity_at_min_tg": None if math.isnan(th.tg_min_overall)
                            else float(capacity(th.tg_min_overall, args.length, args.speed))}
                   for m, th in zip(models, ths, strict=True)},
    }
    if exact:
        doc["exact"] = exact
    _commit_outputs(figs, args.json, doc)
    for path, _ in figs:
        print(f"figure written to {path}")
    return 0


def _exact_tg_text(e: Any, tg_r: tuple[float, float]) -> str:
    """The exact infimum of Tg in words: 'none' when nothing is stable in the box."""
    if not math.isfinite(e.value):
        return f"inf Tg: none (nothing stable for Tg in {tg_r[0]:g}..{tg_r[1]:g} s)"
    edge = f" (box edge: {', '.join(e.on_edge)})" if e.on_edge else ""
    return f"inf Tg {e.value:.4f} s at kg {e.kg:.4g}, kv {e.kv:.4g}{edge}"


def _exact_kv_text(e: Any, kv_r: tuple[float, float]) -> str:
    """The exact supremum of kv in words: a value at the end of the searched kv range
    is no threshold (stable up to the range's edge), and is said so."""
    if not math.isfinite(e.value):
        return f"sup kv: none (nothing stable for kv in {kv_r[0]:g}..{kv_r[1]:g} 1/s)"
    if "kv" in e.on_edge or e.attained or e.value >= kv_r[1]:
        return (f"sup kv: no threshold in the given range (stable up to kv = {kv_r[1]:g} "
                "1/s, the range's edge; widen --kv to look further)")
    edge = [c for c in e.on_edge if c != "kv"]
    at_edge = f" (box edge: {', '.join(edge)})" if edge else ""
    return f"sup kv {e.value:.4f} 1/s at kg {e.kg:.4g}, Tg {e.tg:.4g}{at_edge}"


#: At most this many kv rows of the thresholds table on stdout (the JSON has them all).
MAX_ROWS = 11


def _table_rows(n: int) -> list[int]:
    """Indices of the kv rows printed: all of them up to :data:`MAX_ROWS`, otherwise
    evenly spaced ones including the first and the last."""
    if n <= MAX_ROWS:
        return list(range(n))
    return sorted({int(round(i * (n - 1) / (MAX_ROWS - 1))) for i in range(MAX_ROWS)})


def _panel_indices(maps: Sequence[np.ndarray], n_kv: int, panels: int) -> np.ndarray:
    """kv indices of the region figure's panels: evenly spread over the kv values where
    some model still has a stable point (a panel where nothing is stable shows
    nothing), or over the whole axis when no kv has one."""
    from ..stability import STABLE

    has = np.zeros(n_kv, dtype=bool)
    for mp in maps:
        has |= (np.asarray(mp) == STABLE).any(axis=(0, 1))
    last = int(np.flatnonzero(has)[-1]) if has.any() else n_kv - 1
    k = min(panels, last + 1)
    return np.unique(np.linspace(0, last, k).round().astype(int))


def _commit_outputs(figs: Sequence[tuple[str, Any]], json_path: str | None,
                    doc: dict[str, Any]) -> None:
    """Writes the figures, then the JSON with the figures' sizes and SHA-256 (its
    manifest of the run's outputs). The ``avll`` command commits them as one unit
    (:func:`avll._atomic.output_group`): an interrupted run leaves the old files, never
    a new figure beside an old JSON."""
    import hashlib

    from .. import _atomic

    made: dict[str, Any] = {}
    for path, fig in figs:
        data = _atomic.figure_bytes(fig, Path(path).suffix.lstrip(".").lower() or "png",
                                    dpi=120)
        _atomic.write_bytes(path, data)
        made[str(path)] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    if json_path:
        doc["outputs"] = made
        _atomic.write_json(json_path, doc)


def register(sub: argparse._SubParsersAction) -> None:
    """Registers ``avll stability-map``."""
    from ..stability import CAPACITY_LENGTH, CAPACITY_SPEED

    p = sub.add_parser(
        "stability-map",
        help="stability regions and thresholds over a kg-Tg-kv grid (paper Section IV)",
        description="Local (Routh-Hurwitz) and exact string stability over a kg x Tg x kv "
        "grid, of the paper's Table II models or of the models of a calibration JSON "
        "(--from, what avll calibrate --json writes); prints the thresholds, writes the "
        "region figure and optionally the thresholds figure and JSON.",
    )
    add_models(p, ("second", "proposed"))
    p.add_argument("--from", dest="source", default=None, metavar="CAL.json",
                   help="map the calibrated models of this JSON (avll calibrate --json) "
                   "instead of Table II; --models then picks among them (default: Table "
                   "II's models)")
    grid = {k: [f"{x:g}" for x in SECTION_IV_GRID[k]] for k in ("kg", "Tg", "kv")}
    p.add_argument("--kg", nargs=3, default=grid["kg"], metavar=("MIN", "MAX", "N"),
                   help=f"kg axis in 1/s², log-spaced (default: {' '.join(grid['kg'])}, "
                   "the paper's Section IV grid)")
    p.add_argument("--kg-linear", dest="kg_log", action="store_false",
                   help="space the kg axis linearly instead of logarithmically (default: "
                   "off, log-spaced)")
    p.add_argument("--tg", nargs=3, default=grid["Tg"], metavar=("MIN", "MAX", "N"),
                   help=f"Tg axis in s (default: {' '.join(grid['Tg'])})")
    p.add_argument("--kv", nargs=3, default=grid["kv"], metavar=("MIN", "MAX", "N"),
                   help=f"kv axis in 1/s (default: {' '.join(grid['kv'])})")
    p.add_argument("--pade-order", type=int, default=SECTION_IV_GRID["pade_order"],
                   help=f"Padé order of the dead time, 1..10 (default: "
                   f"{SECTION_IV_GRID['pade_order']}, the paper's)")
    add_threads(p)
    p.add_argument("--out", default="stability-map.png", metavar="PATH",
                   help="region figure; .png, .svg or .pdf (default: stability-map.png)")
    p.add_argument("--thresholds-out", default=None, metavar="PATH",
                   help="thresholds-vs-kv figure; .png, .svg or .pdf (default: not drawn)")
    p.add_argument("--panels", type=int, default=3,
                   help="kv panels in the region figure, spread over the kv values where "
                   "a model is still stable (default: 3)")
    add_json(p, "the thresholds")
    p.add_argument("--length", type=float, default=CAPACITY_LENGTH,
                   help=f"effective vehicle length in m of the capacity formula "
                   f"(default: {CAPACITY_LENGTH:g})")
    p.add_argument("--speed", type=float, default=CAPACITY_SPEED,
                   help=f"speed in m/s of the capacity formula (default: {CAPACITY_SPEED:g})")
    add_progress(p)
    p.add_argument("--exact", action="store_true",
                   help="also compute the exact infimum of Tg and supremum of kv over the "
                   "ranges, boundaries rather than the grid (default: off)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="compute the maps on this dask.distributed scheduler, needs "
                   "avll[dask] (default: in this process)")
    declare_io(p, inputs=("source",), files=("out", "thresholds_out", "json"),
               figures=("out", "thresholds_out"))
    p.set_defaults(func=_cmd)
