"""Figures, drawn in one place: every command, the report and the ``.plot()`` methods
of the result objects go through these functions, so a model has one colour and one
line style and a stability class one colour everywhere (:mod:`avll.defaults`).

Conventions: functions return a matplotlib ``Figure`` (never ``pyplot`` state: safe in
threads and in a server); an axis whose grid is log-spaced is drawn on a log scale; a
threshold that sits on the edge of the searched grid is drawn as an open marker and
labelled "at the grid edge" (the true value is beyond it); data are labelled
"measured" only when they are measured (a run whose metadata say ``synthetic`` is
labelled "synthetic").
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .defaults import CLASS_COLORS, CLASS_LABELS, MEASURED_COLOR, MODEL_COLORS, MODEL_LINESTYLES
from .paper import MODEL_LABELS, PADE_ORDER

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = [
    "model_color", "model_label", "model_linestyle", "data_label", "is_log_spaced", "regions",
    "classes", "thresholds", "traces", "convergence", "measured_vs_simulated",
    "amplification_per_car", "time_gap_per_car", "residual_diagnosis", "signal_axis_label",
    "residual_unexplained", "amplitude_amplification", "boundaries",
]

#: Resolution in dots per inch of the PNG figures the ``avll`` commands write (their
#: ``--dpi``); SVG and PDF figures, chosen by the output's suffix, are vector graphics.
DEFAULT_DPI = 150

_EXTRA = ("tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:red")


def model_color(name: str, k: int = 0) -> str:
    """The colour of model ``name`` (a fixed one per known model; others cycle)."""
    return MODEL_COLORS.get(name, _EXTRA[k % len(_EXTRA)])


def model_linestyle(name: str) -> str:
    """The line style of model ``name`` in traces."""
    return MODEL_LINESTYLES.get(name, "-.")


def model_label(name: str) -> str:
    """The legend name of model ``name`` (``"first-order lag"``, ...)."""
    return MODEL_LABELS.get(name, name)


def data_label(run: Any) -> str:
    """``"synthetic"`` for a run whose metadata say it is synthetic, else
    ``"measured"``."""
    meta = getattr(run, "meta", None) or {}
    return "synthetic" if meta.get("synthetic") else "measured"


def is_log_spaced(x: Any) -> bool:
    """Whether axis values ``x`` (at least three, all > 0) are geometrically spaced,
    i.e. best drawn on a log scale."""
    a = np.asarray(x, dtype=np.float64)
    if a.size < 3 or not np.all(a > 0) or not np.all(np.diff(a) > 0):
        return False
    r = np.diff(np.log(a))
    d = np.diff(a)
    return bool(np.allclose(r, r[0], rtol=1e-6) and not np.allclose(d, d[0], rtol=1e-6))


def _new(nrow: int, ncol: int, size: tuple[float, float]) -> tuple[Figure, list[Any]]:
    """A figure of ``nrow`` x ``ncol`` panels of ``size`` each; the axes row by row."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size[0] * ncol, size[1] * nrow), layout="constrained")
    return fig, list(fig.subplots(nrow, ncol, squeeze=False).ravel())


def _names_labels(models: Sequence[Any], labels: Sequence[str] | None
                  ) -> tuple[list[str], list[str]]:
    """The models' names and their legend labels (``labels``, or :func:`model_label`)."""
    names = [getattr(m, "name", str(m)) for m in models]
    return names, list(labels) if labels is not None else [model_label(n) for n in names]


def _kv_panels(kg: np.ndarray, kvs: np.ndarray) -> tuple[Figure, list[Any]]:
    """A figure of one kg-Tg panel per kv (three a row, spare panels hidden), each
    titled and labelled, its kg axis log-scaled when the kg grid is log-spaced."""
    ncol = min(kvs.size, 3)
    fig, panels = _new((kvs.size + ncol - 1) // ncol, ncol, (4.2, 3.6))
    log = is_log_spaced(kg)
    for ax, kv in zip(panels, kvs, strict=False):
        if log:
            ax.set_xscale("log")
        ax.set_title(f"kv = {kv:g} 1/s")
        ax.set_xlabel("kg (1/s²)" + (", log scale" if log else ""))
        ax.set_ylabel("Tg (s)")
    for ax in panels[kvs.size :]:
        ax.set_visible(False)
    return fig, panels[: kvs.size]


def regions(models: Sequence[Any], kg: Any, tg: Any, kv_values: Any,
            maps: Sequence[Any], pade_order: int = PADE_ORDER, *,
            labels: Sequence[str] | None = None) -> Figure:
    """Stable regions (code 2) of several models in the kg-Tg plane, one panel per kv,
    overlaid (paper Figs. 5 and 7): each model filled in its colour with its boundary
    drawn; a log kg axis when the kg grid is log-spaced. ``maps[i]`` has the shape
    ``(kg, tg, kv_values)``; ``labels`` name the models in the legend (default: their
    names)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    kg, tg = np.asarray(kg, dtype=float), np.asarray(tg, dtype=float)
    kvs = np.atleast_1d(np.asarray(kv_values, dtype=float))
    names, labs = _names_labels(models, labels)
    fig, panels = _kv_panels(kg, kvs)
    for j, ax in enumerate(panels):
        any_stable = False
        for i, mp in enumerate(maps):
            st = (np.asarray(mp)[:, :, j] == 2).astype(float).T  # (tg, kg)
            c = model_color(names[i], i)
            if st.any():
                any_stable = True
                ax.contourf(kg, tg, st, levels=[0.5, 1.5], colors=[c], alpha=0.3)
                if 0 < st.mean() < 1:
                    ax.contour(kg, tg, st, levels=[0.5], colors=[c], linewidths=1.2)
        if not any_stable:
            ax.text(0.5, 0.5, "nothing stable", ha="center", va="center",
                    transform=ax.transAxes)
        ax.set_xlim(kg[0], kg[-1])
        ax.set_ylim(tg[0], tg[-1])
    handles: list[Any] = [
        Patch(color=model_color(nm, i), alpha=0.4, label=f"{lab}: locally and string stable")
        for i, (nm, lab) in enumerate(zip(names, labs, strict=True))
    ]
    handles.append(Line2D([], [], color="0.3", lw=1.2, label="boundary of the stable region "
                          "(a region touching the frame continues beyond the grid)"))
    fig.suptitle(f"Stable regions (local and string), Padé order {pade_order}")
    fig.legend(handles=handles, loc="outside lower center", ncol=1, frameon=False,
               fontsize="small")
    return fig


def classes(codes: Any, kg: Any, tg: Any, kv_values: Any, *,
            title: str = "") -> Figure:
    """The three stability classes of one model (locally unstable, string unstable,
    stable) in the kg-Tg plane, one panel per kv; ``codes`` has the shape
    ``(kg, tg, kv_values)``."""
    from matplotlib.colors import BoundaryNorm, ListedColormap
    from matplotlib.patches import Patch

    kg, tg = np.asarray(kg, dtype=float), np.asarray(tg, dtype=float)
    kvs = np.atleast_1d(np.asarray(kv_values, dtype=float))
    c = np.asarray(codes)
    fig, panels = _kv_panels(kg, kvs)
    cmap = ListedColormap([CLASS_COLORS[k] for k in (0, 1, 2)])
    norm = BoundaryNorm([-0.5, 0.5, 1.5, 2.5], 3)
    for j, ax in enumerate(panels):
        ax.pcolormesh(kg, tg, c[:, :, j].T, cmap=cmap, norm=norm, shading="nearest")
    fig.legend(handles=[Patch(color=CLASS_COLORS[k], label=f"{k}: {CLASS_LABELS[k]}")
                        for k in (0, 1, 2)],
               loc="outside lower center", ncol=3, frameon=False, fontsize="small")
    if title:
        fig.suptitle(title)
    return fig


def thresholds(models: Sequence[Any], ths: Sequence[Any], *,
               labels: Sequence[str] | None = None) -> Figure:
    """Largest stable kg and smallest stable Tg against kv for several models (paper
    Figs. 6 and 8). A value on the edge of the searched grid (``Thresholds.kg_edge``,
    ``Thresholds.tg_edge``) is drawn as an open marker: the true threshold lies at or
    beyond it. A kg axis is logarithmic when the thresholds span more than a decade."""
    from matplotlib.lines import Line2D

    fig, (a1, a2) = _new(1, 2, (4.6, 3.8))
    names, labs = _names_labels(models, labels)
    any_edge = False
    for i, (nm, lab, th) in enumerate(zip(names, labs, ths, strict=True)):
        c = model_color(nm, i)
        kv = np.asarray(th.kv, dtype=float)
        for ax, y, edge in ((a1, np.asarray(th.kg_max, float), getattr(th, "kg_edge", np.nan)),
                            (a2, np.asarray(th.tg_min, float), getattr(th, "tg_edge", np.nan))):
            on_edge = np.isfinite(y) & np.isfinite(edge) & np.isclose(y, edge, rtol=1e-12)
            inner = np.where(on_edge, np.nan, y)
            ax.plot(kv, inner, color=c, ls=model_linestyle(nm), label=lab)
            if on_edge.any():
                any_edge = True
                ax.plot(kv[on_edge], y[on_edge], ls="none", marker="o", mfc="none", ms=4,
                        color=c)
    a1.set(xlabel="kv (1/s)", ylabel="largest stable kg (1/s²)",
           title="(a) largest stable kg")
    a2.set(xlabel="kv (1/s)", ylabel="smallest stable Tg (s)", title="(b) smallest stable Tg")
    k = np.concatenate([np.asarray(t.kg_max, float) for t in ths]) if ths else np.array([])
    k = k[np.isfinite(k) & (k > 0)]
    if k.size and k.max() / k.min() > 10:
        a1.set_yscale("log")
    handles, _ = a1.get_legend_handles_labels()
    if any_edge:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="none", color="0.3",
                              label="at the grid edge (true value at or beyond)"))
    for a in (a1, a2):
        a.grid(alpha=0.3)
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 4),
               frameon=False, fontsize="small")
    return fig


def traces(t: Any, measured: Any, simulated: Mapping[str, Any], *, data: str = "measured",
           title: str = "", ylabel: str = "acceleration (m/s²)",
           command: Any = None) -> Figure:
    """A recorded (``data``: ``"measured"`` or ``"synthetic"``) trace against the
    models' simulations (paper Figs. 3-4); ``command`` adds the command input."""
    fig, (ax,) = _new(1, 1, (8.0, 3.5))
    if measured is not None:
        ax.plot(t, measured, color=MEASURED_COLOR, lw=1.0, label=data)
    if command is not None:
        ax.plot(t, command, color="0.5", lw=0.8, ls="--", label="command")
    for i, (m, y) in enumerate(simulated.items()):
        ax.plot(t, y, color=model_color(m, i), ls=model_linestyle(m), lw=1.0,
                label=f"{model_label(m)} (simulated)")
    ax.set(xlabel="time (s)", ylabel=ylabel, title=title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return fig


def convergence(history: Any, *, model: str = "", title: str = "") -> Figure:
    """Best cost against GA generation (log scale when positive)."""
    fig, (ax,) = _new(1, 1, (5.0, 3.5))
    h = np.asarray(history, dtype=float)
    ax.plot(np.arange(1, h.size + 1), h, color=model_color(model), label=model_label(model)
            if model else "best cost")
    if h.size and np.all(h[np.isfinite(h)] > 0):
        ax.set_yscale("log")
    ax.set(xlabel="generation", ylabel="best cost (Eq. 6)", title=title or "GA convergence")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    return fig


def measured_vs_simulated(rows: Sequence[Mapping[str, Any]], *, title: str,
                          xlabel: str = "time (s)", data: str = "measured") -> Figure:
    """One row of two panels per run: recorded (``data``) against simulated signals
    (the field-data studies' figures). Each row is a mapping with ``name`` (row label),
    ``title`` (the run), ``t`` and ``left``/``right`` panels, each a mapping with
    ``ylabel``, ``measured`` (array), optional ``reference`` (``(label, array)``, e.g.
    the command or the predecessor's speed) and ``simulated`` (model name -> array)."""
    n = max(len(rows), 1)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 1.9 * n + 0.6), layout="constrained")
    axes = fig.subplots(n, 2, squeeze=False)
    for i, row in enumerate(rows):
        for j, side in enumerate(("left", "right")):
            ax, panel = axes[i, j], row[side]
            ax.plot(row["t"], panel["measured"], color=MEASURED_COLOR, lw=1.0, label=data)
            ref = panel.get("reference")
            if ref is not None:
                ax.plot(row["t"], ref[1], color="0.6", lw=0.8, label=ref[0])
            for k, (m, y) in enumerate(panel.get("simulated", {}).items()):
                ax.plot(row["t"], y, color=model_color(m, k), ls=model_linestyle(m), lw=1.0,
                        label=f"{model_label(m)} (simulated)")
            ax.set_ylabel(f"{row['name']}\n{panel['ylabel']}" if j == 0 else panel["ylabel"])
        axes[i, 0].set_title(row["title"], fontsize="small", loc="left")
    axes[-1, 0].set_xlabel(xlabel)
    axes[-1, 1].set_xlabel(xlabel)
    axes[0, 0].legend(fontsize="x-small", ncol=3, loc="best")
    fig.suptitle(title)
    return fig


def amplification_per_car(cars: Sequence[Mapping[str, Any]], models: Sequence[str]) -> Figure:
    """Measured (with its 95 % interval) against predicted amplification of the
    predecessor's speed oscillations, per car, from ``|H(jω)|`` and by replay (the OpenACC
    study's ``cars`` entries); cars under human control are crosses."""
    fig, axes = _new(1, 2, (5.5, 5.0))
    axes[1].sharex(axes[0])
    axes[1].sharey(axes[0])
    meas = [c for c in cars if c["amplification_measured"] is not None]
    if meas:
        xs = np.array([c["amplification_measured"] for c in meas], dtype=float)
        ci = [c.get("amplification_measured_ci") or [None, None] for c in meas]
        lo = np.array([np.nan if a is None else a for a, _ in ci], dtype=float)
        hi = np.array([np.nan if b is None else b for _, b in ci], dtype=float)
        # a percentile interval need not contain the estimate: bars never negative
        xerr = np.array([np.clip(xs - lo, 0.0, None), np.clip(hi - xs, 0.0, None)])
        xerr[:, ~(np.isfinite(lo) & np.isfinite(hi))] = 0.0
        ys_all = [c["models"][m][k] for c in meas for m in models
                  for k in ("amplification_H", "amplification_replay")
                  if c["models"][m][k] is not None]
        top = max(2.5, 1.15 * max([float(np.max(xs)), *ys_all]))
        low = [float(v) for v in (*lo, *xs) if np.isfinite(v) and v > 0]
        bottom = 0.8 * min([0.5, *low, *[y for y in ys_all if y > 0]])
        hum = np.array([c.get("group", "acc" if c["acc"] else "human") == "human"
                        for c in meas], dtype=bool)
        for ax, key, title in ((axes[0], "amplification_H", "predicted from |H(jω)|"),
                               (axes[1], "amplification_replay", "predicted by replay")):
            grid = np.array([bottom, top])
            ax.fill_between(grid, 0.9 * grid, 1.1 * grid, color="0.9", label="±10 %")
            ax.plot(grid, grid, "k-", lw=0.8)
            ax.axhline(1.0, color="0.6", lw=0.5, ls=":")
            ax.axvline(1.0, color="0.6", lw=0.5, ls=":")
            for k, m in enumerate(models):
                ys = np.array([c["models"][m][key] if c["models"][m][key] is not None
                               else np.nan for c in meas])
                ax.errorbar(xs[~hum], ys[~hum], xerr=xerr[:, ~hum],
                            fmt="o", ms=4, lw=0.6, color=model_color(m, k),
                            label=model_label(m), alpha=0.8)
                if hum.any():
                    ax.plot(xs[hum], ys[hum], "x", color=model_color(m, k), ms=6,
                            label=f"{model_label(m)} (human control)")
            ax.set(xlim=(bottom, top), ylim=(bottom, top), xscale="log", yscale="log",
                   title=title, xlabel="measured amplification (95 % CI)")
        axes[0].set_ylabel("predicted amplification")
        axes[0].legend(fontsize="x-small", loc="upper left")
    fig.suptitle("Amplification of the predecessor's speed oscillations, per car")
    return fig


#: Marker, colour and offset of the OpenACC ACC settings (long, medium, short; None:
#: no ACC, a human driver) in :func:`time_gap_per_car`.
_SETTINGS = {"L": ("tab:red", "o", -0.2, "long"), "M": ("tab:green", "s", 0.0, "medium"),
             "S": ("tab:blue", "^", 0.2, "short"), None: ("0.4", "x", 0.0, "no ACC (human)")}


def time_gap_per_car(cars: Sequence[Mapping[str, Any]], model: str) -> Figure:
    """The calibrated time gap ``Tg`` of ``model`` per car and ACC setting (the
    OpenACC study's ``cars`` entries); cars without a finite ``Tg`` are left out. With
    several campaigns a car model has one column per campaign; settings other than
    L/M/S (e.g. ``min``, ``shortest``) get a colour each, placed by their order
    (``setting_rank``) within the column."""
    fig, (ax,) = _new(1, 1, (11.0, 4.5))
    multi = len({c.get("campaign", "") for c in cars}) > 1

    def col_name(c: Mapping[str, Any]) -> str:
        return f"{c['car']} ({c.get('campaign', '')})" if multi else str(c["car"])

    names = sorted({col_name(c) for c in cars})
    pos = {n: i for i, n in enumerate(names)}
    others = sorted({str(c["setting"]) for c in cars if c["setting"] not in _SETTINGS})
    palette = ("tab:purple", "tab:orange", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")
    seen = set()
    for c in cars:
        acc = c.get("group", "acc" if c["acc"] else "human") == "acc"
        st = c["setting"] if acc else None
        if acc and st is None:
            col, mk, off, lab = "0.4", "+", 0.0, "ACC, setting not given"
        elif st in _SETTINGS:
            col, mk, off, lab = _SETTINGS[st]
        else:
            rank = c.get("setting_rank")
            col = palette[others.index(str(st)) % len(palette)]
            off = 0.2 - 0.15 * rank if isinstance(rank, int) else 0.0
            mk, lab = "v", f"{st}" + (f" (order {rank})" if isinstance(rank, int) else "")
        if str(c.get("folder", "")).lower() == "mixed" and acc:
            mk, lab = "D", f"{lab} (folder 'mixed')"
        if c["Tg"] is None:
            continue
        ax.plot(pos[col_name(c)] + off, c["Tg"], mk, color=col, ms=6, mfc="none",
                label=None if lab in seen else lab)
        seen.add(lab)
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize="small")
    ax.set_ylabel(f"calibrated Tg (s), {model_label(model)} model")
    if seen:
        ax.legend(fontsize="small")
    ax.set_title("Calibrated time gap per car model and ACC setting")
    return fig


def residual_diagnosis(d: Any) -> list[tuple[str, Figure]]:
    """The figures of a residual diagnosis (:class:`avll.diagnose.Diagnosis`):
    ``residual_vs_signals`` (the residual binned against each candidate signal, 95 %
    bands) and ``residual_spectrum`` (spectrum, autocorrelation, cross-correlation
    with the command rate)."""
    n = len(d.signals)
    cols = 3
    fig, axes = _new((n + cols - 1) // cols or 1, cols, (4.0, 3.0))
    for ax, s in zip(axes, d.signals, strict=False):
        ok = s.counts > 0
        ax.errorbar(s.centers[ok], s.means[ok], yerr=s.half_width[ok], fmt="o-", capsize=3,
                    color=MEASURED_COLOR)
        ax.axhline(0, color="0.5", lw=0.6)
        ax.set_title(f"{s.signal}\nexpl. {100 * s.explained:.1f} %, p={s.p_value:.2g}",
                     fontsize=9)  # fmt: skip
        ax.set_xlabel(signal_axis_label(s.signal), fontsize=8)
        ax.set_ylabel("residual (m/s²)", fontsize=8)
    for ax in axes[n:]:
        ax.set_visible(False)
    fig2, (ax0, ax1, ax2) = _new(1, 3, (4.3, 3.2))
    ax0.semilogy(d.freq[1:], d.psd[1:], color=MEASURED_COLOR)
    ax0.set(xlabel="frequency (Hz)", ylabel="(m/s²)²/Hz", title="residual PSD")
    dt = d.xcorr_lags[1] - d.xcorr_lags[0] if d.xcorr_lags.size > 1 else 1.0
    ax1.plot(np.arange(d.autocorr.size) * dt, d.autocorr, color=MEASURED_COLOR)
    ax1.set(xlabel="lag (s)", ylabel="autocorrelation (1)",
            title=f"autocorrelation (lag-1 {d.lag1:.2f})")
    ax2.plot(d.xcorr_lags, d.xcorr, color=MEASURED_COLOR)
    ax2.set(xlabel="lag (s)", ylabel="correlation (1)",
            title=f"xcorr with command rate (peak {d.best_lag:+.2f} s)")
    return [("residual_vs_signals", fig), ("residual_spectrum", fig2)]


#: Units of the signals a residual is binned against ("cmd": the command's own unit,
#: m/s² for an acceleration command and m/s for a speed command).
_SIGNAL_UNITS = {"speed": "m/s", "time in run": "s", "command": "cmd", "|command|": "cmd",
                 "command rate": "cmd/s", "command jerk": "cmd/s²",
                 "simulated acceleration": "m/s²", "speed error": "m/s",
                 "sign of speed error": "±1", "sign of command": "±1",
                 "sign of acceleration": "±1"}


def signal_axis_label(signal: str) -> str:
    """An axis label for a diagnosis signal with its unit (``cmd``: the unit of the
    command, m/s² or m/s); exogenous signals (``exo_*``) keep their name."""
    unit = _SIGNAL_UNITS.get(signal, "")
    if unit.startswith("cmd"):
        unit = "command unit" + unit[3:]
    return signal + (f" ({unit})" if unit else "")


def residual_unexplained(unexplained: Mapping[str, Any]) -> Figure:
    """The final residual of the loop binned against speed, time and command (95 %
    bands with the effective sample size), one panel each, titled with the share of
    residual variance and the p-value; panels that keep structure are drawn in the
    "keeps structure" colour and say so."""
    sigs = list(unexplained.get("signals", []))
    fig, axes = _new(1, max(len(sigs), 1), (4.0, 3.2))
    for ax, s in zip(axes, sigs, strict=False):
        c, m, h = (np.asarray(s[k], dtype=float) for k in ("centers", "means", "half_width"))
        ok = np.isfinite(c) & np.isfinite(m)
        ax.errorbar(c[ok], m[ok], yerr=h[ok], fmt="o-", capsize=3,
                    color="tab:red" if s["keeps_structure"] else MEASURED_COLOR)
        ax.axhline(0, color="0.5", lw=0.6)
        ax.set_xlabel(signal_axis_label(s["signal"]))
        ax.set_ylabel("residual (m/s²)")
        mark = " — keeps structure" if s["keeps_structure"] else ""
        ax.set_title(f"{100 * s['explained']:.1f} % of variance, p={s['p_value']:.2g}{mark}",
                     fontsize=9)  # fmt: skip
    return fig


def amplitude_amplification(res: Any) -> Figure:
    """An amplitude study (:class:`avll.effect_stability.AmplitudeStudy`): the
    amplification per car against the disturbance amplitude (with the linearised
    ``|H(jω)|``), and the speed amplitude along the platoon relative to the
    leader's."""
    fig, (ax1, ax2) = _new(1, 2, (5.0, 4.0))
    n_cars = res.amplification.shape[1]
    for i in range(n_cars):
        ax1.plot(res.amplitudes, res.amplification[:, i], "o-", ms=3, label=f"car {i + 1}")
    for e in res.linear:
        if e.gain_at_omega is not None and e.label in ("base", "with effects"):
            ax1.axhline(e.gain_at_omega, ls="--" if e.label == "base" else ":",
                        color="k", lw=1, label=f"|H(jω)| {e.label}")  # fmt: skip
    ax1.axhline(1.0, color="grey", lw=0.5)
    ax1.set_xscale("log")
    ax1.set_xlabel("leader speed amplitude A (m/s)")
    ax1.set_ylabel("amplification (car i / car i−1)")
    ax1.set_title(f"{res.model}, T = {res.period:.3g} s, v0 = {res.v0:g} m/s")
    ax1.legend(fontsize=7)
    cars = np.arange(n_cars + 1)
    for a, sp, hr in zip(res.amplitudes, res.speed_amplitude, res.half_range, strict=True):
        (ln,) = ax2.plot(cars, sp / a, "o-", ms=3, label=f"A = {a:g} m/s")
        ax2.plot(cars, hr / a, "--", color=ln.get_color(), lw=1)
    ax2.set_yscale("log")
    ax2.set_xlabel("car (0 = leader)")
    ax2.set_ylabel("speed fundamental (—) and half range (--) / A")
    ax2.legend(fontsize=7)
    return fig


def boundaries(bounds: Sequence[Any], labels: Sequence[str] | None = None) -> Figure:
    """Boundaries from :func:`avll.stability.boundary` drawn as curves: one panel per
    boundary, the boundary value against the first fixed parameter (log axis for a
    log-spaced one, as kg), one curve per value of the second (e.g. ``tg_min``
    against kg for each kv)."""
    bs = list(bounds)
    if not bs or not all(hasattr(b, "dims") and len(b.dims) == 2 for b in bs):
        raise ValueError("boundaries: expected 2-D DataArrays from avll.boundary")
    fig, axes = _new(1, len(bs), (4.6, 3.6))
    for i, (ax, b) in enumerate(zip(axes, bs, strict=True)):
        x, c = b.dims
        for j, cv in enumerate(b[c].values):
            ax.plot(b[x].values, b.values[:, j], label=f"{c} = {cv:g}")
        if x == "kg" or is_log_spaced(b[x].values):
            ax.set_xscale("log")
        ax.set_xlabel(x)
        ax.set_ylabel(str(b.name))
        ax.set_title(labels[i] if labels is not None else f"{b.attrs.get('model', '')} {b.name}")
        ax.grid(alpha=0.3)
        if b[c].size <= 8:
            ax.legend(fontsize=8)
    return fig
