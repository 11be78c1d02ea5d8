"""avll.plotting: one colour per model and per stability class, log axes for log
grids, grid edges marked, synthetic data labelled so."""

from __future__ import annotations

import numpy as np
import pytest

import avll
from avll import plotting
from avll.defaults import CLASS_COLORS, MODEL_COLORS


def test_log_spacing_detection() -> None:
    assert plotting.is_log_spaced(np.geomspace(1e-3, 2, 40))
    assert not plotting.is_log_spaced(np.linspace(0.1, 2, 40))
    assert not plotting.is_log_spaced(np.linspace(0, 2, 40))


def test_regions_log_axis_and_model_colours() -> None:
    from matplotlib.colors import to_rgba

    P = avll.PAPER_TABLE_II
    kg, tg, kv = np.geomspace(1e-3, 2, 25), np.linspace(0, 15, 16), [0.0, 0.3]
    ms = [P["proposed"], P["second"]]
    fig = avll.stability.plot_regions(ms, kg, tg, kv)
    ax = fig.axes[0]
    assert ax.get_xscale() == "log" and "log scale" in ax.get_xlabel()
    leg = fig.legends[0]
    texts = [t.get_text() for t in leg.get_texts()]
    assert texts[0].startswith("proposed") and texts[1].startswith("second-order")
    assert any("boundary" in t for t in texts)
    got = [tuple(np.round(h.get_facecolor()[:3], 3)) for h in leg.legend_handles[:2]]
    want = [tuple(np.round(to_rgba(MODEL_COLORS[m])[:3], 3)) for m in ("proposed", "second")]
    assert got == want
    lin = avll.stability.plot_regions(ms, np.linspace(0.01, 2, 25), tg, kv)
    assert lin.axes[0].get_xscale() == "linear"


def test_thresholds_mark_grid_edges() -> None:
    P = avll.PAPER_TABLE_II
    kg, tg, kv = np.geomspace(1e-3, 2, 30), np.linspace(0, 15, 31), np.linspace(0, 1, 11)
    ths = [avll.thresholds(avll.stability_map(P[m], kg, tg, kv), kg, tg, kv)
           for m in ("proposed", "first")]
    first = ths[1]
    assert first.kg_edge == pytest.approx(2.0) and first.tg_edge == 0.0
    # the first-order lag is stable up to the grid's largest kg at small kv
    assert np.nanmax(first.kg_max) == pytest.approx(2.0)
    fig = avll.stability.plot_thresholds([P["proposed"], P["first"]], ths)
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("grid edge" in t for t in texts)
    line = [ln for ln in fig.axes[0].lines if ln.get_marker() == "o"]
    assert line and np.allclose(line[0].get_ydata(), 2.0)
    # Thresholds.plot delegates to the same function
    assert len(first.plot("first").axes) == 2


def test_class_colours() -> None:
    kg, tg, kv = np.geomspace(1e-3, 2, 10), np.linspace(0, 15, 8), [0.2]
    codes = avll.stability_map(avll.PAPER_TABLE_II["second"], kg, tg, kv)
    fig = plotting.classes(codes, kg, tg, kv, title="second")
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == [f"{k}: {v}" for k, v in avll.defaults.CLASS_LABELS.items()]
    assert len(CLASS_COLORS) == 3


def test_traces_label_synthetic_truthfully() -> None:
    runs = avll.synth.paper_experiment(avll.PAPER_TABLE_II["first"], runs=(3,), duration=10.0)
    assert plotting.data_label(runs[0]) == "synthetic"
    assert plotting.data_label(object()) == "measured"
    fig = plotting.traces(runs[0].t, runs[0].a, {"first": runs[0].a}, data="synthetic")
    labels = [ln.get_label() for ln in fig.axes[0].lines]
    assert labels == ["synthetic", "first-order lag (simulated)"]


def test_calibration_result_plot() -> None:
    runs = avll.synth.paper_experiment(avll.PAPER_TABLE_II["first"], runs=(3,), duration=20.0)
    res = avll.calibrate("first", runs, max_generations=5, starts=1)
    fig = res.plot()
    assert fig.axes[0].lines[0].get_xdata().size == res.history.size
