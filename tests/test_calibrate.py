"""Calibration by the GA: recovery of known models, ranking, reproducibility,
cross-check against scipy's differential evolution, interrupts, CLI contract."""

from __future__ import annotations

import _thread
import json
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import avll
from avll import _core
from avll.calibration import (
    DEFAULT_BOUNDS,
    bootstrap,
    calibrate,
    calibrate_many,
    paper_workflow,
    split_runs,
)
from avll.io import write_runs
from avll.synth import PAPER_CAL_RUNS, paper_experiment

TRUE = avll.PAPER_TABLE_II


def freq_response(m: avll.LowerLevelModel, w: np.ndarray) -> np.ndarray:
    """G_fb(jw) of a model, written from Eq. 5."""
    c = m.linear()
    s = 1j * w
    g = (c["b1"] * s + c["b0"]) * np.exp(-c["Td"] * s) / (c["a2"] * s * s + c["a1"] * s + 1)
    return g / (1 - c["K"] * g)


def low_freq_delay(m: avll.LowerLevelModel) -> float:
    """-d arg G_fb / dw at w = 0: (Td + a1 - b1/b0) / (1 - K b0)."""
    c = m.linear()
    return (c["Td"] + c["a1"] - c["b1"] / c["b0"]) / (1 - c["K"] * c["b0"])


@pytest.fixture(scope="module")
def proposed_data() -> list[avll.Run]:
    return paper_experiment(TRUE["proposed"], seed=11, duration=90.0)


def true_cost(model: avll.LowerLevelModel, runs: list[avll.Run]) -> float:
    return float(avll.batch_cost(model.name, model.to_array()[None], runs).mean())


# --- recovery -------------------------------------------------------------------


def test_first_order_time_constant_is_recovered() -> None:
    runs = paper_experiment(TRUE["first"], seed=3, runs=PAPER_CAL_RUNS, duration=90.0)
    r = calibrate("first", runs, seed=1)
    assert r.params["Td"] == pytest.approx(1.0758, rel=0.01)
    assert r.cost <= true_cost(TRUE["first"], runs) * (1 + 1e-9)
    assert not r.interrupted and r.at_bound == ()


def test_second_order_identifiable_combinations_are_recovered() -> None:
    # The experiment excites ~0.05-1 rad/s, well below the paper's second-order
    # corner (4.7 rad/s): K0 and the low-frequency delay Td + m3 are identified,
    # Td, m2, m3 separately are not (seeds give Td from 0.49 to 0.90 s).
    true = TRUE["second"]
    runs = paper_experiment(true, seed=4, runs=PAPER_CAL_RUNS, duration=90.0)
    r = calibrate("second", runs, seed=2)
    m = r.model
    assert isinstance(m, avll.SecondOrder)
    assert m.K0 == pytest.approx(true.K0, rel=0.015)
    assert m.Td + m.m3 == pytest.approx(true.Td + true.m3, rel=0.03)
    assert r.cost <= true_cost(true, runs) * (1 + 1e-9)


def test_proposed_identifiable_combinations_are_recovered(proposed_data: list[avll.Run]) -> None:
    # m1..K trade off (different seeds land on e.g. K = -1.16 or 0.12, Td = 0.45 or
    # 0.94 at the same cost); the DC gain K0/(1 - K K0), the low-frequency delay and
    # the frequency response over the excited band are identified.
    true = TRUE["proposed"]
    cal, _ = split_runs(proposed_data, "paper")
    r = calibrate("proposed", cal, seed=0)
    assert r.cost <= true_cost(true, cal) * (1 + 1e-6)
    assert r.model.dc_gain == pytest.approx(true.dc_gain, rel=0.02)
    assert low_freq_delay(r.model) == pytest.approx(low_freq_delay(true), rel=0.05)
    w = np.linspace(0.1, 1.0, 10)
    h_fit, h_true = freq_response(r.model, w), freq_response(true, w)
    np.testing.assert_allclose(np.abs(h_fit), np.abs(h_true), rtol=0.03)
    np.testing.assert_allclose(np.angle(h_fit / h_true), 0.0, atol=0.05)


def test_models_rank_as_in_the_paper(proposed_data: list[avll.Run]) -> None:
    wf = paper_workflow(proposed_data, seed=0)
    avg = wf.averages()
    for col in ("cal_mse", "val_mse"):
        assert avg.loc["proposed", col] < avg.loc["second", col] < avg.loc["first", col]
    # Tables II-IV and a figure like Figs. 3-4.
    assert list(wf.params_table().index) == ["Td", "K0", "m2", "m3", "m1", "K"]
    t3, t4 = wf.mse_table("cal"), wf.mse_table("val")
    assert list(t3.columns) == [str(r) for r in PAPER_CAL_RUNS] + ["Average"]
    assert t4.shape == (3, 12)
    assert t3.loc["The proposed model", "Average"] == pytest.approx(wf.results["proposed"].cost)
    assert "Table IV" in wf.to_text()
    fig = wf.plot(17)
    assert len(fig.axes[0].lines) == 4
    # the synthetic recording is labelled so, not "measured"
    assert fig.axes[0].lines[0].get_label() == "synthetic"
    js = wf.to_json()["models"]["second"]
    assert set(js["per_run_mse"]) == {str(i) for i in range(1, 22)}


def test_fixed_parameter_by_equal_bounds(proposed_data: list[avll.Run]) -> None:
    cal = proposed_data[:3]
    r = calibrate("proposed", cal, seed=0, bounds={"m1": (0.0, 0.0)}, max_generations=20)
    assert r.params["m1"] == 0.0
    assert r.bounds["m1"] == (0.0, 0.0, "linear")


# --- reproducibility and many problems -------------------------------------------


def test_same_seed_same_result_for_any_thread_count(proposed_data: list[avll.Run]) -> None:
    cal = proposed_data[:4]
    kw = dict(seed=5, max_generations=25)
    r1 = calibrate("proposed", cal, threads=1, **kw)
    r2 = calibrate("proposed", cal, threads=2, **kw)
    assert r1.params == r2.params and r1.cost == r2.cost
    np.testing.assert_array_equal(r1.history, r2.history)
    r3 = calibrate("proposed", cal, threads=2, seed=6, max_generations=25)
    assert r3.params != r1.params


def test_starts_stopped_at_a_target_are_the_same_for_any_thread_count(
    proposed_data: list[avll.Run],
) -> None:
    """With a target, the starts stop together at the first step at which one reaches
    it: the result does not depend on the threads (or on which start ran first)."""
    cal = proposed_data[:4]
    full = calibrate("proposed", cal, seed=3, max_generations=30)
    kw = dict(seed=3, max_generations=30, target=full.cost * 1.2, starts=3)
    r1 = calibrate("proposed", cal, threads=1, **kw)
    r2 = calibrate("proposed", cal, threads=2, **kw)
    assert r1.cost <= full.cost * 1.2 and r1.stop == "target"
    assert r1.params == r2.params and r1.cost == r2.cost
    assert r1.evaluations == r2.evaluations and r1.start_costs == r2.start_costs
    np.testing.assert_array_equal(r1.history, r2.history)


def test_many_problems_equal_single_problems(proposed_data: list[avll.Run]) -> None:
    runs = proposed_data[:4]
    kw = dict(seed=9, max_generations=30, starts=1)
    many1 = calibrate_many("second", runs, "per_run", threads=1, **kw)
    many2 = calibrate_many("second", runs, "per_run", threads=2, **kw)
    assert [m.params for m in many1] == [m.params for m in many2]
    for k, (res, run) in enumerate(zip(many1, runs, strict=True)):
        single = calibrate(
            "second", [run], seed=_core.derive_seed(9, k), max_generations=30, starts=1
        )
        assert single.params == res.params
        assert list(res.per_run_mse) == [run.run_id]
    # Repeats weigh a run: [a, a, b] is the weighted mean of a and b.
    rep = calibrate_many("first", runs, [[0, 0, 1]], seed=1)[0]
    c = avll.batch_cost("first", rep.model.to_array()[None], runs[:2])[0]
    assert rep.cost == pytest.approx((2 * c[0] + c[1]) / 3, rel=1e-12)


def test_workflow_packs_the_runs_once(
    proposed_data: list[avll.Run], monkeypatch: pytest.MonkeyPatch
) -> None:
    """paper_workflow packs the calibration runs and the validation runs once each for
    all models, with the same results as packing per call."""
    from avll import _core

    calls: list[int] = []
    real = _core.RunSet

    def counting(offsets: list[int], *a: object, **kw: object) -> object:
        calls.append(len(offsets) - 1)
        return real(offsets, *a, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(_core, "RunSet", counting)
    runs = proposed_data[:6]
    models = ("first", "second", "proposed")
    wf = paper_workflow(runs, cal_runs=None, models=models, seed=2, max_generations=4,
                        polish=False, starts=1)  # fmt: skip
    assert sorted(calls) == [3, 3]  # cal (3 runs) once, val (3 runs) once
    for m in models:
        # The same numbers as a calibration and a validation packed on their own.
        r = calibrate(m, wf.cal, seed=2, max_generations=4, polish=False, starts=1)
        assert r.params == wf.results[m].params and r.cost == wf.results[m].cost
        v = avll.batch_cost(m, np.array(list(r.params.values()))[None], wf.val)[0]
        assert list(wf.val_mse[m].values()) == [float(x) for x in v]


def test_bootstrap_intervals() -> None:
    runs = paper_experiment(TRUE["first"], seed=5, runs=(1, 2, 3, 4, 5, 6), duration=60.0)
    b = bootstrap("first", runs, n=8, seed=0, max_generations=40)
    assert isinstance(b, avll.Uncertainty) and b.method == "runs"
    ci = b.ci()
    assert list(ci.index) == ["Td", "dc_gain", "low_frequency_delay"]
    assert b.samples.shape == (8, 1)
    assert (ci["low"] <= ci["median"]).all() and (ci["median"] <= ci["high"]).all()
    assert ci.loc["Td", "median"] == pytest.approx(1.0758, rel=0.02)
    assert b.samples[:, 0].std() > 0  # resamples differ


def test_closed_loop_with_free_upper_gain() -> None:
    true = TRUE["first"]
    runs = paper_experiment(true, seed=6, runs=(3, 4, 5), duration=90.0)  # kg = 0.5
    r = calibrate("first", runs, seed=0, closed_loop=True, upper_free=("kg",))
    assert r.upper["kg"] == pytest.approx(0.5, rel=0.05)
    assert r.params["Td"] == pytest.approx(1.0758, rel=0.05)


def test_closed_loop_answer_is_locally_stable() -> None:
    """A locally unstable closed loop costs inf even where its rollout stays finite over
    the record, and the calibration returns a locally stable parameter set (the best
    its GA's population held). The car: a synthetic platoon's first follower, 300 s,
    every upper gain free."""
    from avll.defaults import UPPER_NAMES
    from avll.rollout import closed_loop
    from avll.studies.openacc import WEIGHTS
    from avll.synth_platoon import synth_platoon

    run = synth_platoon(2, seed=101, duration=300.0, models=("proposed",)).runs[0]
    kw = dict(closed_loop=True, weights=WEIGHTS, init="rest")
    r = calibrate("proposed", [run], seed=5, starts=1, max_generations=30,
                  upper_free=UPPER_NAMES, bounds={"Gmin": (0.0, 10.0)}, **kw)  # fmt: skip
    names = avll.Proposed.param_names()
    k, td = len(names), names.index("Td")

    def code(row: np.ndarray) -> int:
        up = r.upper
        c, _ = _core.delay_codes_rows("proposed", np.ascontiguousarray(row[None, :k]),
                                      [up["kg"]], [up["Tg"]], [up["kv"]], threads=1)
        return int(c[0])

    def scaled(s: float) -> np.ndarray:
        row = r.x.copy()
        row[td] *= s
        return row

    assert code(r.x) != 0 and np.isfinite(r.cost)
    cost = avll.batch_cost("proposed", r.x[None, :], [run], upper_free=(0, 1, 2, 3), **kw)
    assert cost[0, 0] == pytest.approx(r.cost, rel=1e-9)
    # the same loop with the dead time raised to just across the edge (bisection)
    lo, hi = 1.0, 2.0
    while code(scaled(hi)) != 0 and hi < 64:
        lo, hi = hi, 2 * hi
    assert code(scaled(hi)) == 0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if code(scaled(mid)) != 0 else (lo, mid)
    row = scaled(hi)
    sim = closed_loop(avll.Proposed(*row[:k]), run.lead_x, run.lead_v, run.dt,
                      avll.UpperLevel(**r.upper), v0=float(run.v[0]), x0=float(run.x[0]))
    assert np.isfinite(sim.v).all()
    unstable = avll.batch_cost("proposed", row[None, :], [run], upper_free=(0, 1, 2, 3), **kw)
    assert np.isinf(unstable[0, 0])


def test_speed_command_runs() -> None:
    # A speed-tracking lower level (command and response are speeds; Eq. 6 still
    # compares accelerations, here the derivative of the simulated speed).
    true = avll.FirstOrderLag(Td=0.8)
    rng = np.random.default_rng(0)
    runs = []
    for k in range(3):
        t = np.arange(0.0, 60.0, 0.05)
        cmd = 10 + 3 * np.sin(0.3 * t + k) + np.cumsum(rng.normal(0, 0.02, t.size))
        tr = avll.simulate_full(true, cmd, 0.05, command_kind="speed", init="steady", v0=cmd[0])
        runs.append(avll.Run(run_id=str(k), t=t, a=tr.a + rng.normal(0, 0.02, t.size),
                             command_kind="speed", command=cmd, v=tr.v))  # fmt: skip
    r = calibrate("first", runs, seed=0, init="steady")
    assert r.params["Td"] == pytest.approx(0.8, rel=0.02)
    c_true = float(avll.batch_cost("first", true.to_array()[None], runs, init="steady").mean())
    assert r.cost <= c_true * (1 + 1e-9)


# --- cross-check against scipy ----------------------------------------------------


def test_ga_no_worse_than_scipy_differential_evolution() -> None:
    """Same objective (Eq. 6, open loop, from rest), same box in the same (log/linear)
    coordinates; DE with polish drives the scipy.signal.lfilter rollouts."""
    from scipy.optimize import differential_evolution

    from avll.reference.lfilter import cost_lfilter

    runs = paper_experiment(TRUE["proposed"], seed=8, runs=(3, 9), duration=60.0)
    box = DEFAULT_BOUNDS["second"]
    names = list(box)

    def to_user(z: np.ndarray) -> np.ndarray:
        out = []
        for zi, (lo, hi, sc) in zip(z, box.values(), strict=True):
            out.append(lo * (hi / lo) ** zi if sc == "log" else lo + zi * (hi - lo))
        return np.array(out)

    def f(z: np.ndarray) -> float:
        p = dict(zip(names, to_user(z), strict=True))
        return cost_lfilter(avll.SecondOrder(**p), runs)

    de = differential_evolution(f, [(0.0, 1.0)] * 4, seed=0, polish=True, tol=1e-8)
    de_cost = float(avll.batch_cost("second", to_user(de.x)[None], runs).mean())
    assert de_cost == pytest.approx(de.fun, rel=1e-9)  # the two rollouts agree
    ga = calibrate("second", runs, seed=0)
    assert ga.cost <= de_cost * 1.01


# --- stopping, interrupts and errors ----------------------------------------------


def test_progress_callable_and_interrupt(proposed_data: list[avll.Run]) -> None:
    seen: list[dict] = []

    def cb(info: dict) -> None:
        seen.append(info)
        if len(seen) >= 3:
            raise KeyboardInterrupt

    r = calibrate("proposed", proposed_data[:2], seed=0, progress=cb,
                  max_generations=10_000, stall_generations=10_000)  # fmt: skip
    assert r.interrupted and r.stop == "interrupted"
    assert r.generations < 10_000 and np.isfinite(r.cost)
    assert {"problem", "phase", "iteration", "evaluations", "best"} <= set(seen[0])


def test_ctrl_c_returns_best_so_far(proposed_data: list[avll.Run], sigint_handler: None) -> None:
    timer = threading.Timer(0.5, _thread.interrupt_main)
    timer.start()
    try:
        r = calibrate("proposed", proposed_data[:2], seed=0,
                      max_generations=100_000, stall_generations=100_000)  # fmt: skip
    finally:
        timer.cancel()
    assert r.interrupted
    assert np.isfinite(r.cost) and r.cost == pytest.approx(r.history[-1])


def test_progress_error_propagates(proposed_data: list[avll.Run]) -> None:
    def cb(info: dict) -> None:
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        calibrate("first", proposed_data[:1], progress=cb, max_generations=50,
                  stall_generations=50)  # fmt: skip


def test_stopping_rules(proposed_data: list[avll.Run]) -> None:
    r = calibrate("first", proposed_data[:2], seed=0, max_generations=3, polish=False, starts=1)
    assert r.generations == 3 and r.stop == "max_generations" and len(r.history) == 4
    assert np.all(np.diff(r.history) <= 0)
    loose = calibrate("first", proposed_data[:2], seed=0, target=10.0)
    assert loose.stop == "target" and loose.generations == 0
    # The starts run in turn: the first reached the target, so the second was skipped.
    assert len(loose.start_costs) == 1 and not loose.interrupted
    # Two starts: the result is the better of the two single-start runs.
    both = calibrate("second", proposed_data[:2], seed=4, max_generations=15)
    singles = [
        calibrate("second", proposed_data[:2], seed=_core.derive_seed(4, j), starts=1,
                  max_generations=15).cost
        for j in range(2)
    ]  # fmt: skip
    assert both.start_costs == tuple(singles) and both.cost == min(singles)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"bounds": {"zz": (0, 1)}}, "bounds: unknown parameter 'zz'"),
        ({"bounds": {"Td": (2, 1)}}, r"bounds\['Td'\]"),
        ({"seed": -1}, "seed"),
        ({"upper_free": ("kg",)}, "upper_free"),
        ({"popsize": 3}, "popsize: unknown GA option"),
        ({"weights": (0, 0, 0)}, "weights: at least one weight must be > 0"),
        ({"weights": (1, -1, 0)}, "weights: must be >= 0"),
        ({"init": "cold"}, "init"),
        ({"crossover_prob": 2.0}, "crossover_prob"),
    ],
)
def test_bad_arguments(proposed_data: list[avll.Run], kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        calibrate("first", proposed_data[:1], **kwargs)


def test_bad_model_and_runs(proposed_data: list[avll.Run]) -> None:
    with pytest.raises(ValueError, match="model"):
        calibrate("fourth", proposed_data[:1])
    with pytest.raises(ValueError, match="runs"):
        calibrate("first", [])
    with pytest.raises(ValueError, match="cal_runs"):
        split_runs(proposed_data, [99])
    cal, val = split_runs(proposed_data)
    assert [r.run_id for r in cal][:3] == ["1", "3", "5"] and val[0].run_id == "2"


# --- CLI contract ------------------------------------------------------------------


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "avll.cli", *args], capture_output=True, text=True, cwd=cwd,
        timeout=300,
    )  # fmt: skip


def test_cli_calibrate_json(tmp_path: Path) -> None:
    runs = paper_experiment(seed=2, runs=(1, 2, 3, 4), duration=40.0)
    write_runs(runs, tmp_path / "d.csv")
    res = _cli("calibrate", "d.csv", "--command-kind", "acceleration", "--models",
               "first,second", "--cal-runs", "1,3", "--seed", "3", "--json", "out.json",
               cwd=tmp_path)  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "Table III" in res.stdout
    out = json.loads((tmp_path / "out.json").read_text())
    assert set(out["models"]) == {"first", "second"}
    m = out["models"]["second"]
    assert {"params", "cal_mse", "val_mse", "per_run_mse"} <= set(m)
    assert set(m["params"]) == {"K0", "m2", "m3", "Td"}
    assert set(m["per_run_mse"]) == {"1", "2", "3", "4"}
    assert m["cal_mse"] == pytest.approx((m["per_run_mse"]["1"] + m["per_run_mse"]["3"]) / 2)
    assert m["val_mse"] == pytest.approx((m["per_run_mse"]["2"] + m["per_run_mse"]["4"]) / 2)


def test_cli_bad_input_one_line_error(tmp_path: Path) -> None:
    runs = paper_experiment(seed=2, runs=(1, 2), duration=20.0)
    write_runs(runs, tmp_path / "d.csv")
    lines = (tmp_path / "d.csv").read_text().splitlines()
    header = lines[0].split(",")
    row = lines[6].split(",")
    row[header.index("a")] = "nan"
    lines[6] = ",".join(row)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    meta = tmp_path / "d.csv.meta.json"
    if meta.exists():
        (tmp_path / "bad.csv.meta.json").write_text(meta.read_text())
    res = _cli("calibrate", "bad.csv", "--json", "o.json", cwd=tmp_path)
    assert res.returncode == 2
    err = res.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in res.stderr
    # file, column and row (the file's line 7 holds data row 6)
    assert "bad.csv" in err and "'a'" in err and "7" in err
    assert not (tmp_path / "o.json").exists()
    res = _cli("calibrate", "d.csv", "--models", "first,fourth", cwd=tmp_path)
    assert res.returncode == 2 and "fourth" in res.stderr and "Traceback" not in res.stderr
    res = _cli("calibrate", "d.csv", "--cal-runs", "1,9", cwd=tmp_path)
    assert res.returncode == 2 and "9" in res.stderr


def test_every_default_bound_has_a_physical_reason() -> None:
    from avll.defaults import BOUND_REASONS, DEFAULT_BOUNDS, UPPER_BOUNDS

    used = set()
    for model, box in DEFAULT_BOUNDS.items():
        for p in box:
            key = f"{model}.{p}" if f"{model}.{p}" in BOUND_REASONS else p
            assert BOUND_REASONS.get(key), (model, p)
            used.add(key)
    for p in UPPER_BOUNDS:
        assert BOUND_REASONS.get(p), p
        used.add(p)
    assert used == set(BOUND_REASONS)  # no reason for a bound that does not exist


def test_per_problem_warm_start_never_ends_above_its_start() -> None:
    """Each problem of ``calibrate_many`` starts from its own row (the base fit's optimum
    with an added structure at its neutral values, :func:`start_row`, which costs exactly
    the base fit's cost): with elitism the richer fit never ends above it, even on a
    budget too short to find it alone; bad shapes give errors naming the argument."""
    from avll.calibration import start_row

    true = TRUE["first"]
    runs = paper_experiment(true, seed=6, runs=(3, 4, 5), duration=60.0)
    kw = dict(closed_loop=True, upper_free=("kg",), seed=2, threads=2)
    base = calibrate_many("first", runs, "per_run", max_generations=15, **kw)
    starts = [[start_row(b, ["perception"])] for b in base]
    for b, s, run in zip(base, starts, runs, strict=True):
        c = avll.batch_cost("first", s[0][None], [run], effects=["perception"],
                            closed_loop=True, upper_free=[0])[0, 0]
        assert c == pytest.approx(b.cost, rel=1e-9)
    rich = calibrate_many("first", runs, "per_run", effects=["perception"], max_generations=2,
                          initial_per_problem=starts, **kw)
    for b, r in zip(base, rich, strict=True):
        assert r.cost <= b.cost * (1 + 1e-9)
    again = calibrate_many("first", runs, "per_run", effects=["perception"], max_generations=2,
                           initial_per_problem=starts, **{**kw, "threads": 1})
    assert [r.params for r in again] == [r.params for r in rich]
    with pytest.raises(ValueError, match="initial_per_problem"):
        calibrate_many("first", runs, "per_run", effects=["perception"], max_generations=1,
                       initial_per_problem=starts[:2], **kw)
    with pytest.raises(ValueError, match=r"initial_per_problem\[1\]\[0\]"):
        calibrate_many("first", runs, "per_run", effects=["perception"], max_generations=1,
                       initial_per_problem=[starts[0], [starts[1][0][:-1]], []], **kw)
    with pytest.raises(ValueError, match="needs subsets"):
        calibrate("first", runs, initial_per_problem=starts, **kw)
    with pytest.raises(ValueError, match="unknown effect"):
        start_row(base[0], ["nope"])
