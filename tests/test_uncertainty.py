"""The uncertainty stage of a calibration (avll.uncertainty): block bootstrap over time
refit from the full-data optimum, intervals, identifiability, combinations; validated
on synthetic platoons with a known truth."""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pytest

import avll
from avll import _core
from avll.calibration import _problem
from avll.defaults import UPPER_NAMES
from avll.studies.openacc import WEIGHTS, predicted_amplification
from avll.synth_platoon import synth_platoon, validate_intervals
from avll.uncertainty import (
    Intervals,
    Uncertainty,
    block_length,
    to_dataset,
)

CL = dict(closed_loop=True, upper_free=UPPER_NAMES, weights=WEIGHTS,
          bounds={"Gmin": (0.0, 10.0)})


def test_block_length_follows_the_correlation_and_has_a_floor() -> None:
    rng = np.random.default_rng(3)
    white = rng.standard_normal(6000)
    ar = np.zeros(6000)
    for k in range(1, 6000):
        ar[k] = 0.98 * ar[k - 1] + white[k]
    assert block_length([white], 0.1) == 5.0  # the floor
    b = block_length([ar], 0.1)
    assert b > 10.0  # a correlation time of 5 s asks for blocks of tens of seconds
    assert block_length([ar], 0.1, cap=12.0) == 12.0
    assert block_length([white, ar], 0.1) == b  # the largest


def test_interval_options_are_checked() -> None:
    with pytest.raises(ValueError, match="level"):
        Intervals(level=1.5)
    with pytest.raises(ValueError, match="method"):
        Intervals(method="iid")
    with pytest.raises(ValueError, match="block"):
        Intervals(block=-1.0)
    with pytest.raises(ValueError, match="n"):
        Intervals(n=1)
    with pytest.raises(ValueError, match="refit"):
        Intervals(refit="newton")
    with pytest.raises(ValueError, match="ftol"):
        Intervals(ftol=-1e-9)
    with pytest.raises(TypeError, match="polish"):
        Intervals(polish=1)  # type: ignore[arg-type]
    for bad in (0.0, -1.0, math.inf, math.nan, True):
        with pytest.raises(ValueError, match="block_factor"):
            Intervals(block_factor=bad)
    with pytest.raises(TypeError, match="intervals"):
        Intervals.of("yes")
    assert Intervals.of(True) == Intervals()
    assert Intervals.of({"n": 20}).n == 20
    assert Intervals.of(None) is None


@pytest.fixture(scope="module")
def platoon() -> object:
    return synth_platoon(2, seed=101, duration=300.0, models=("proposed",))


@pytest.fixture(scope="module")
def fitted(platoon) -> list:  # type: ignore[no-untyped-def]
    return avll.calibrate_many("proposed", platoon.runs, "per_run", seed=5, starts=1,
                               max_generations=120, intervals=Intervals(n=40), **CL)


def test_refits_are_exact_at_unit_weights_and_do_not_depend_on_threads(platoon, fitted
                                                                       ) -> None:  # type: ignore[no-untyped-def]
    prob = _problem("proposed", platoon.runs, bounds={"Gmin": (0.0, 10.0)},
                    closed_loop=True, upper_free=UPPER_NAMES, weights=WEIGHTS, init="rest")
    x0 = np.ascontiguousarray(fitted[0].x[None, :])
    n_atoms = -(-len(platoon.runs[0]) // 25)
    w = np.ones((3, n_atoms))
    w[1, ::2] = 2.0
    w[2, :10] = 0.0

    def go(threads: int) -> dict:
        return _core.refit_resamples(
            prob.cls.name, lower_bounds=prob.lower, upper_bounds=prob.upper,
            scale=prob.scale, problems=[[0]], x0=x0, atoms=[[25]], resample_weights=[w],
            budget=150, threads=threads, **prob.kw)[0]

    a, b = go(1), go(2)
    np.testing.assert_array_equal(a["x"], b["x"])
    np.testing.assert_array_equal(a["f"], b["f"])
    # all-ones weights: the Eq. 6 cost of the GA at its optimum (up to summation order)
    assert a["f_full"] == pytest.approx(fitted[0].cost, rel=1e-9)
    assert a["f_x0"][0] == pytest.approx(fitted[0].cost, rel=1e-9)
    assert np.all(a["f"] <= a["f_x0"])  # a refit never ends above its start
    assert a["done"].all() and not a["interrupted"]


def test_levenberg_marquardt_refits_against_the_simplex(platoon, fitted
                                                       ) -> None:  # type: ignore[no-untyped-def]
    """The two refits of the same resamples (closed loop, every upper gain free, three
    weighted channels): Levenberg-Marquardt never ends above its start, in fewer
    rollouts. Where a resample's minimum lies across the edge of local stability (a
    locally unstable loop costs inf), a step across it is refused: LM, a least-squares
    method, stops where its steps are, the simplex slides along the edge. Measured on
    this car (its estimate is on the edge): LM 0.3-4.2 % above the simplex on the five
    resampled weights, equal at unit weights (the estimate is polished). On the intervals
    guide's cars (seed 7601, 50 resamples each) the median difference is -0.002 %."""
    prob = _problem("proposed", platoon.runs, bounds={"Gmin": (0.0, 10.0)},
                    closed_loop=True, upper_free=UPPER_NAMES, weights=WEIGHTS, init="rest")
    x0 = np.ascontiguousarray(fitted[0].x[None, :])
    n_atoms = -(-len(platoon.runs[0]) // 25)
    rng = np.random.default_rng(11)
    w = rng.poisson(1.0, (6, n_atoms)).astype(np.float64)
    w[0] = 1.0

    def go(method: str) -> dict:
        return _core.refit_resamples(
            prob.cls.name, lower_bounds=prob.lower, upper_bounds=prob.upper,
            scale=prob.scale, problems=[[0]], x0=x0, atoms=[[25]], resample_weights=[w],
            method=method, threads=1, **prob.kw)[0]

    nm, lm = go("simplex"), go("lm")
    assert lm["f_full"] == nm["f_full"]
    np.testing.assert_array_equal(lm["f_x0"], nm["f_x0"])
    assert np.all(lm["f"] <= lm["f_x0"]) and lm["done"].all()
    assert np.isfinite(lm["f"]).all() and np.isfinite(nm["f"]).all()
    ratio = lm["f"] / nm["f"]
    assert ratio[0] == pytest.approx(1.0, rel=1e-6) and ratio.max() <= 1.05, ratio
    assert lm["evaluations"].sum() < nm["evaluations"].sum() / 2, (lm["evaluations"],
                                                                   nm["evaluations"])
    with pytest.raises(ValueError, match="method"):
        _core.refit_resamples(
            prob.cls.name, lower_bounds=prob.lower, upper_bounds=prob.upper,
            scale=prob.scale, problems=[[0]], x0=x0, atoms=[[25]], resample_weights=[w],
            method="newton", **prob.kw)


@pytest.mark.parametrize("effects", [["speed_gains"], ["closing"], ["feedforward"]])
def test_resampled_cost_carries_the_upper_level_structures(platoon, fitted, effects
                                                          ) -> None:  # type: ignore[no-untyped-def]
    """The refits' cost at unit weights is the calibration's cost with upper-level
    structures too (they act through the law: before the fix, the atom sums ran the
    plain law, and a speed_gains optimum of cost 0.018 was refit from a start costing
    0.074)."""
    from avll.calibration import start_row

    run = platoon.runs[0]
    r = avll.calibrate("proposed", [run], effects=effects, seed=3, starts=1,
                       max_generations=5, initial=[start_row(fitted[0], effects)], **CL)
    prob = _problem("proposed", [run], effects=effects, bounds={"Gmin": (0.0, 10.0)},
                    closed_loop=True, upper_free=UPPER_NAMES, weights=WEIGHTS, init="rest")
    x0 = np.ascontiguousarray(np.asarray(r.x)[None, :])
    w = np.ones((1, -(-len(run) // 25)))
    for method in ("simplex", "lm"):
        o = _core.refit_resamples(
            prob.cls.name, lower_bounds=prob.lower, upper_bounds=prob.upper,
            scale=prob.scale, problems=[[0]], x0=x0, atoms=[[25]], resample_weights=[w],
            budget=30, method=method, **prob.kw)[0]
        assert o["f_full"] == pytest.approx(r.cost, rel=1e-9), (method, o["f_full"], r.cost)
        assert o["f"][0] <= r.cost * (1 + 1e-12)


def test_the_block_is_the_factor_times_the_politis_white_length(platoon, fitted
                                                                 ) -> None:  # type: ignore[no-untyped-def]
    """The same fit (same seed and start), its score series' Politis-White length times
    ``block_factor`` (above the floor, below the cap), and the default factor is
    :data:`avll.uncertainty.BLOCK_FACTOR`."""
    from avll.uncertainty import BLOCK_FACTOR, MIN_BLOCK

    run = platoon.runs[1]
    bs = [avll.calibrate("proposed", [run], seed=5, starts=1, max_generations=2,
                         initial=[fitted[1].x], intervals=Intervals(n=4, polish=False, **kw),
                         **CL).uncertainty.block_s
          for kw in ({"block_factor": 1.0}, {"block_factor": 2.0}, {})]
    assert MIN_BLOCK < bs[0] < bs[1] < 100.0
    assert bs[1] == pytest.approx(2.0 * bs[0], rel=1e-12)
    assert bs[2] == pytest.approx(BLOCK_FACTOR * bs[0], rel=1e-12)
    assert Intervals().block_factor == BLOCK_FACTOR


def test_uncertainty_result(platoon, fitted) -> None:  # type: ignore[no-untyped-def]
    r = fitted[0]
    u = r.uncertainty
    assert isinstance(u, Uncertainty)
    assert u.samples.shape == (40, 10) and u.names == tuple(r.bounds)
    assert set(r.intervals) >= set(u.names) | {"time_gap_effective", "dc_gain",
                                                "low_frequency_delay"}
    assert u.block_s >= 5.0
    # this car's fit is a corner local minimum (K0 ~ 1e-9: a lower level without DC
    # gain): its gap loop never settles, so Tg + Gmin/v̄ has no interval; the other car's
    # has one
    assert u.combination_estimates["dc_gain"] < 1e-6 and u.gap_loop_too_slow()
    assert u.gap_loop_period() > u.record_s == pytest.approx(300.0)
    for n, (lo, hi) in r.intervals.items():
        if n == "time_gap_effective":
            assert math.isnan(lo) and math.isnan(hi)
        else:
            assert lo <= hi, n
    # every interval holds its estimate (symmetric intervals)
    for n, (lo, hi) in r.intervals.items():
        if n in u.names:
            e = float(u.estimate[u.names.index(n)])
            assert lo <= e <= hi or not math.isfinite(lo), n
    ver = u.verdicts()
    assert set(ver) == set(u.names) | set(u.combinations)
    assert set(ver.values()) <= {"identified", "at bound", "reaches bound", "wide", "fixed",
                                 "undetermined"}
    # a parameter at its bound is never a finding
    for n in r.at_bound:
        assert ver[n] != "identified"
    assert u.verdicts()["time_gap_effective"] == "undetermined"
    u1 = fitted[1].uncertainty
    assert not u1.gap_loop_too_slow() and u1.gap_loop_period() < 60.0
    assert "time_gap_effective" in u1.identified()
    text = u.report()
    for part in ("[[Parameters]]", "[[Combinations]]", "[[Correlations]]", "P(string stable)"):
        assert part in text
    c = u.correlations
    assert c.shape == (10, 10)
    p = u.string_stable_probability
    assert p is not None and 0.0 <= p <= 1.0
    # the band amplification of the estimate is the study's prediction
    run = platoon.runs[0]
    amp, amps = u.band_amplification(run.lead_v, run.dt)
    mod, up = r.model, avll.UpperLevel(**{k: r.upper[k] for k in UPPER_NAMES})
    # (without the exact test's mask: this car's estimate lies on the edge of local
    # stability, and a locally unstable estimate's band gain is NaN)
    raw, _ = replace(u, string_codes=None, string_code_estimate=None).band_amplification(
        run.lead_v, run.dt)
    assert raw == pytest.approx(predicted_amplification(mod, up, run.lead_v, run.dt), rel=1e-12)
    assert math.isnan(amp) == (u.string_code_estimate == 0)
    assert amps.shape == (40,)
    ds = to_dataset([f.uncertainty for f in fitted], car=["a", "b"], file=["f1", "f2"])
    assert dict(ds.sizes) == {"car": 2, "parameter": 10, "parameter2": 10}
    assert ds["time_gap_effective_low"].shape == (2,)
    assert list(ds["file"].values) == ["f1", "f2"]
    assert ds["identified"].dtype == bool
    # maps: the resampled models of a calibration directly
    prob = avll.stability_probability(r, np.array([0.1]), np.array([2.0]), np.array([0.4]),
                                      pade_order=2)
    assert prob.shape == (1, 1, 1) and prob.attrs["samples"] == len(u.models())


def test_the_estimate_is_polished_before_resampling(platoon) -> None:  # type: ignore[no-untyped-def]
    """The resamples start from a local minimum of the full-data cost: the GA's optimum
    refit by the same local search first, and the calibration reports that point."""
    from avll.calibration import _with_uncertainty

    run = platoon.runs[0]
    kw = dict(seed=3, starts=1, max_generations=2, **CL)  # the polish gains 0.6 % here
    plain = avll.calibrate("proposed", [run], **kw)
    r = avll.calibrate("proposed", [run], intervals=Intervals(n=8), **kw)
    u = r.uncertainty
    assert u.cost_given == pytest.approx(plain.cost, rel=1e-9)
    assert u.cost_estimate < u.cost_given and u.polish_evaluations > 0
    assert r.cost == u.cost_estimate and r.cost_ga == plain.cost_ga
    np.testing.assert_array_equal(r.x, u.estimate)
    assert r.per_run_mse[run.run_id] == pytest.approx(r.cost, rel=1e-9)  # at the new row
    assert r.params == dict(zip(u.names, r.x, strict=True))
    assert "polished from" in u.report() and u.to_dict()["cost_given"] == u.cost_given
    # a local minimum: polishing it again gains (almost) nothing
    prob = _problem("proposed", [run], bounds={"Gmin": (0.0, 10.0)}, closed_loop=True,
                    upper_free=UPPER_NAMES, weights=WEIGHTS, init="rest")
    again = _with_uncertainty(prob, [[0]], [r], Intervals(n=4), 1, 0, False)[0]
    assert again.cost >= r.cost * (1 - 1e-6)
    # without the polish the resamples start from the GA's optimum
    q = avll.calibrate("proposed", [run], intervals=Intervals(n=8, polish=False), **kw)
    np.testing.assert_array_equal(q.x, plain.x)
    assert q.cost == plain.cost and q.uncertainty.cost_estimate == pytest.approx(plain.cost,
                                                                                 rel=1e-9)
    # the polish cannot carry a locally stable optimum across the edge of local
    # stability: a locally unstable closed loop costs inf, so the refit's steps across
    # it are refused and the polished estimate stays locally stable
    kw8 = dict(kw, max_generations=8)
    ga8 = avll.calibrate("proposed", [run], **kw8)
    s8 = avll.calibrate("proposed", [run], intervals=Intervals(n=8), **kw8)
    u8 = s8.uncertainty
    assert u8.polish_evaluations > 0 and u8.string_code_estimate != 0
    assert s8.cost == u8.cost_estimate <= u8.cost_given == pytest.approx(ga8.cost, rel=1e-9)


def test_ctrl_c_during_the_polish_returns_the_calibration_without_resamples(
        platoon, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A Ctrl-C in the polish (the first refit call) stops the stage: the GA's fit is
    returned, its uncertainty interrupted, with no resample and no further refit."""
    import avll.uncertainty as U

    calls = []
    real = U._core.refit_resamples

    def stopped(*a, **k):  # type: ignore[no-untyped-def]
        calls.append(k["resample_weights"][0].shape)
        out = real(*a, **k)
        for r in out:  # as a stop before the refit ran returns it
            r["interrupted"] = True
            r["done"][:] = False
            r["x"][:] = np.nan
            r["f"][:] = np.nan
        return out

    monkeypatch.setattr(U._core, "refit_resamples", stopped)
    kw = dict(seed=3, starts=1, max_generations=2, **CL)
    r = avll.calibrate("proposed", platoon.runs[:1], intervals=Intervals(n=8), **kw)
    monkeypatch.undo()
    plain = avll.calibrate("proposed", platoon.runs[:1], **kw)
    u = r.uncertainty
    assert calls == [(1, 1)]  # the polish only, no resample refit
    assert u.interrupted and u.samples.shape == (0, len(u.names))
    np.testing.assert_array_equal(r.x, plain.x)
    assert r.cost == plain.cost and u.cost_given == u.cost_estimate
    assert all(math.isnan(lo) and math.isnan(hi) for lo, hi in r.intervals.values())


def test_intervals_are_seeded(platoon) -> None:  # type: ignore[no-untyped-def]
    kw = dict(seed=7, starts=1, max_generations=60, **CL)
    a = avll.calibrate("proposed", platoon.runs[:1], intervals=Intervals(n=12), threads=1, **kw)
    b = avll.calibrate("proposed", platoon.runs[:1], intervals=Intervals(n=12), threads=2, **kw)
    np.testing.assert_array_equal(a.uncertainty.samples, b.uncertainty.samples)
    c = avll.calibrate("proposed", platoon.runs[:1], intervals=Intervals(n=12, seed=99), **kw)
    assert not np.array_equal(a.uncertainty.samples, c.uncertainty.samples)


def test_ctrl_c_returns_the_resamples_so_far(platoon) -> None:  # type: ignore[no-untyped-def]
    calls = []

    def progress(info: dict) -> None:
        if info.get("phase") == "resample":
            calls.append(info)
            if len(calls) >= 2:
                raise KeyboardInterrupt

    from avll.calibration import _with_uncertainty

    base = avll.calibrate("proposed", platoon.runs[:1], seed=1, starts=1, max_generations=40,
                          **CL)
    prob = _problem("proposed", platoon.runs[:1], bounds={"Gmin": (0.0, 10.0)},
                    closed_loop=True, upper_free=UPPER_NAMES, weights=WEIGHTS, init="rest")
    r = _with_uncertainty(prob, [[0]], [base], Intervals(n=200, budget=400), 1, 1,
                          progress)[0]
    assert r.uncertainty.interrupted
    assert 0 < len(r.uncertainty.samples) < 200


def test_run_resampling_is_an_option_of_the_same_entry() -> None:
    sp = synth_platoon(3, seed=5, duration=150.0, models=("proposed",))
    r = avll.calibrate("proposed", sp.runs, seed=1, starts=1, max_generations=40,
                       intervals=Intervals(n=12, method="runs"), **CL)
    assert r.uncertainty.method == "runs" and r.uncertainty.samples.shape[0] == 12
    with pytest.raises(ValueError, match="method='runs'"):
        avll.calibrate("proposed", sp.runs[:1], seed=1, starts=1, max_generations=5,
                       intervals=Intervals(n=12, method="runs"), **CL)


def test_validation_on_synthetic_platoons_quick() -> None:
    # fresh seeds, a few cars: the plumbing of the validation and the estimates' accuracy;
    # the intervals' coverage needs many cars (the slow tests below)
    v = validate_intervals([20261128], cars=3, n=40)
    s = v["summary"]
    assert s["cars"] == 3 and len(v["rows"]) == 3
    assert s["amplification"]["within_10pct"] >= 2 / 3, s
    assert s["time_gap_effective"]["within_10pct"] >= 2 / 3, s
    for r in v["rows"]:
        assert r["widening"] > 1.0, r
        for key in ("amplification", "time_gap_effective"):
            d = r[key]
            # a record of fewer effective blocks than parameters gets no interval
            assert d["determined"] == math.isfinite(r["widening"]), r
            if d["determined"]:
                assert d["low"] < d["high"] and d["rel_width"] > 0, r
                assert d["inside"] == (d["low"] <= d["truth"] <= d["high"])
            else:
                assert d["inside"] is None and math.isnan(d["low"]), r


@pytest.fixture(scope="module")
def validation() -> dict:
    # 8 platoons of 6 cars: 48 cars, enough for a coverage of 85 % to mean something; seeds
    # not used while the method was chosen (that was 7301-7308; 7501-7508, 7601-7608 and
    # 7701-7708 were the final checks of earlier rules), the same as the docs' fragment
    # (docs/gen/intervals.py)
    from docs.gen.intervals import SEEDS
    return validate_intervals(list(SEEDS), cars=6, n=200)["summary"]


@pytest.mark.slow
@pytest.mark.long
def test_predictions_are_within_10_percent_on_synthetic_platoons(validation) -> None:  # type: ignore[no-untyped-def]
    s = validation
    print(s)
    assert s["cars"] >= 40
    assert s["amplification"]["within_10pct"] >= 0.90, s


@pytest.mark.slow
@pytest.mark.long
def test_time_gaps_are_within_10_percent_on_synthetic_platoons(validation) -> None:  # type: ignore[no-untyped-def]
    s = validation
    assert s["time_gap_effective"]["within_10pct"] >= 0.90, s


@pytest.fixture(scope="module")
def validation_long() -> dict:
    # the same method on records four times as long, fresh seeds (docs/gen/intervals.py)
    from docs.gen.intervals import LONG_DURATION, LONG_SEEDS
    return validate_intervals(list(LONG_SEEDS), cars=6, n=200,
                              duration=LONG_DURATION)["summary"]


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.parametrize("records", ["validation", "validation_long"])
def test_amplification_intervals_cover_the_truth_on_synthetic_platoons(
        records: str, request: pytest.FixtureRequest) -> None:
    """The 95 % intervals of the band amplification hold the truth for at least 85 % of
    the cars (the issue's criterion; the docs' fragment on these seeds says by how
    much, from the same function), on 5 min records and on 20 min ones."""
    s = request.getfixturevalue(records)
    assert s["amplification"]["coverage"] >= 0.85, s


@pytest.mark.slow
@pytest.mark.long
@pytest.mark.parametrize("records", ["validation", "validation_long"])
def test_time_gap_intervals_cover_the_truth_on_synthetic_platoons(
        records: str, request: pytest.FixtureRequest) -> None:
    """The issue's criterion for ``Tg + Gmin / v̄``: at least 85 % of the cars with an
    interval, on 5 min and on 20 min records (the docs' fragment on these seeds says by
    how much, from the same function)."""
    s = request.getfixturevalue(records)
    assert s["time_gap_effective"]["coverage"] >= 0.85, s
    # not by leaving cars out: at most one in five without an interval
    assert s["time_gap_effective"]["undetermined"] <= 0.2, s


def test_combinations_match_their_definitions() -> None:
    """The DC gain and the low-frequency delay of the proposed lower level, vectorised
    over rows, against G_fb(jω) = G / (1 - K G) evaluated near ω = 0."""
    from avll.uncertainty import _linear_columns, dc_gain, low_frequency_delay

    x = np.array([[0.3, 0.05, 0.6, 0.9, 0.2, -0.3], [0.0, 0.2, 1.1, 1.2, 0.0, 0.4]])
    lin = _linear_columns(avll.Proposed, x)
    w = 1e-5
    for i, row in enumerate(x):
        m = avll.Proposed.from_array(row)
        c = m.linear()
        s = 1j * w
        g = (c["b1"] * s + c["b0"]) * np.exp(-s * c["Td"]) / (c["a2"] * s * s + c["a1"] * s + 1)
        gfb = g / (1 - c["K"] * g)
        assert dc_gain(lin)[i] == pytest.approx(m.dc_gain, rel=1e-12)
        assert dc_gain(lin)[i] == pytest.approx(abs(gfb), rel=1e-6)
        assert low_frequency_delay(lin)[i] == pytest.approx(-np.angle(gfb) / w, rel=1e-4)


def test_band_amplification_and_string_verdicts_carry_the_structures(platoon, fitted
                                                                    ) -> None:  # type: ignore[no-untyped-def]
    """With structures (both levels) the band amplification of every resample is the
    whole follower's |H| (one Rust call over the rows), the full-data value is the
    study's prediction of the fitted WithEffects, and the string verdicts come from the
    certified test of every delay (said in :attr:`Uncertainty.string_test`)."""
    from avll.calibration import start_row
    from avll.effect_stability import band_amplification_rows
    from avll.uncertainty import STRING_TEST_CERTIFIED, STRING_TEST_EXACT

    run = platoon.runs[0]
    effs = ["perception", "feedforward"]
    r = avll.calibrate("proposed", [run], effects=effs, seed=3, starts=1, max_generations=20,
                       initial=[start_row(fitted[0], effs)], intervals=Intervals(n=30), **CL)
    assert r.cost <= fitted[0].cost * (1 + 1e-9)
    u = r.uncertainty
    assert u is not None and u.string_test == STRING_TEST_CERTIFIED
    assert u.string_certified is not None and u.string_certified.shape == (30,)
    up = avll.UpperLevel(**{k: r.upper[k] for k in UPPER_NAMES})
    amp, amps = u.band_amplification(run.lead_v, run.dt)
    assert r.with_effects is not None
    want = predicted_amplification(r.with_effects, up, run.lead_v, run.dt)
    raw, _ = replace(u, string_codes=None, string_code_estimate=None).band_amplification(
        run.lead_v, run.dt)  # without the mask of a locally unstable estimate
    assert raw == pytest.approx(want, rel=1e-12)
    assert math.isnan(amp) == (u.string_code_estimate == 0)
    base_only = predicted_amplification(r.model, up, run.lead_v, run.dt)
    assert np.isfinite(want) and abs(want / base_only - 1) > 1e-6, "the structures enter |H|"
    rows = u.uncorrected().rows()  # the refits' closed loops
    assert rows.shape == (31, len(u.names) + 4 - sum(n in UPPER_NAMES for n in u.names))
    again = band_amplification_rows("proposed", rows, run.lead_v, run.dt,
                                    effects=list(u.effects))
    # the refits' |H| with their deviations from the estimate's widened in |H| itself
    assert u.widening > 1.0
    assert np.isfinite(amps).all()
    np.testing.assert_allclose(amps, again[0] + u.widening * (again[1:] - again[0]),
                               rtol=1e-12)
    p = u.string_stable_probability
    assert p is not None and 0.0 <= p <= 1.0
    assert "certified test" in u.report()
    assert u.to_dict()["string_test"] == STRING_TEST_CERTIFIED
    base = avll.calibrate("proposed", [run], seed=3, starts=1, max_generations=20,
                          intervals=Intervals(n=20), **CL)
    assert base.uncertainty is not None and base.uncertainty.string_test == STRING_TEST_EXACT


def test_time_gap_effective_with_speed_gains_is_the_equilibrium_one(platoon, fitted
                                                                   ) -> None:  # type: ignore[no-untyped-def]
    """With speed-dependent gains the effective time gap of the estimate and of every
    resample is ``Tg_eq + Gmin / v̄`` (``Tg_eq = Tg + ch v̄``), the OpenACC study's point
    estimate, not ``Tg + Gmin / v̄``."""
    from avll.calibration import start_row
    from avll.studies.openacc import time_gap_effective

    # the second car: the first car's fit is a corner without a gap loop (no interval of
    # the effective time gap, test_uncertainty_result)
    run = platoon.runs[1]
    effs = ["speed_gains"]
    r = avll.calibrate("proposed", [run], effects=effs, seed=3, starts=1, max_generations=20,
                       initial=[start_row(fitted[1], effs)], intervals=Intervals(n=20), **CL)
    u = r.uncertainty
    assert u is not None and r.with_effects is not None
    v = float(np.mean(run.v))
    up = avll.UpperLevel(**{k: r.upper[k] for k in UPPER_NAMES})
    est, smp = u.time_gap_effective(v)
    assert est == pytest.approx(time_gap_effective(r.with_effects, up, v), rel=1e-12)
    j = u.names.index("speed_gains.ch")
    raw = u.uncorrected()  # the refits themselves
    ch = raw.samples[:, j]
    assert np.count_nonzero(ch) > 0, "the resamples move ch"
    plain = raw.upper["Tg"] + raw.upper["Gmin"] / v
    est_raw, smp_raw = raw.time_gap_effective(v)
    assert est_raw == est
    fin = np.isfinite(smp_raw)
    assert fin.sum() >= 15
    np.testing.assert_allclose(smp_raw[fin] - plain[fin], ch[fin] * v, rtol=1e-9, atol=1e-12)
    # the resamples' values, widened as a quantity of their own
    np.testing.assert_allclose(smp, est + u.widening * (smp_raw - est), rtol=1e-12)
    assert est - (u.upper_estimate["Tg"] + u.upper_estimate["Gmin"] / v) == pytest.approx(
        u.estimate[j] * v, rel=1e-9, abs=1e-12)
    assert r.intervals["time_gap_effective"][0] <= est <= r.intervals["time_gap_effective"][1]


def test_the_guide_states_the_refits_cap_and_the_code_applies_it() -> None:
    """docs/guide/intervals.md says the Levenberg-Marquardt refits stop after
    ``LM_BUDGET_PER_PARAM d`` rollouts (and the polish and simplex refits keep Rust's cap);
    the budget the refits are given is that."""
    from pathlib import Path

    from avll.uncertainty import LM_BUDGET_PER_PARAM, refit_budget

    text = (Path(__file__).resolve().parents[1] / "docs" / "guide" / "intervals.md"
            ).read_text(encoding="utf-8")
    caps = set(re.findall(r"after `(\d+) d` rollouts", text))
    assert caps == {str(LM_BUDGET_PER_PARAM)}, caps
    assert refit_budget(Intervals(), 10) == 10 * LM_BUDGET_PER_PARAM
    assert refit_budget(Intervals(refit="simplex"), 10) == 0  # Rust's 200 d
    assert refit_budget(Intervals(budget=77), 10) == 77
