"""The small-sample correction of the block bootstrap (avll.uncertainty): its formula,
the widening of resampled deviations in the GA's unit coordinates, and the statistics
it rests on, checked on a case with a known answer (least squares with few
observations per parameter)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import avll
from avll.uncertainty import Intervals, small_sample_scale, widen, widen_values

# Student's t quantiles from the tables (not from the code under test)
T975 = {10: 2.228139, 30: 2.042272, 4: 2.776445}
Z975 = 1.959964


def test_scale_is_the_dof_correction_times_the_student_quantile() -> None:
    for g, p in ((20.0, 10), (40.0, 10), (14.0, 10)):
        nu = int(g - p)
        want = math.sqrt(g / nu) * T975[nu] / Z975
        assert small_sample_scale(g, p) == pytest.approx(want, rel=1e-5)
    # many blocks, few parameters: no correction; fewer blocks than parameters: nothing
    assert small_sample_scale(1e7, 3) == pytest.approx(1.0, abs=1e-5)
    assert math.isinf(small_sample_scale(10.5, 10))
    assert math.isinf(small_sample_scale(6.0, 10))
    # a lower level widens less (its quantiles are closer to the normal's)
    assert small_sample_scale(20.0, 10, 0.68) < small_sample_scale(20.0, 10, 0.95)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="blocks"):
            small_sample_scale(bad, 3)
    with pytest.raises(ValueError, match="level"):
        small_sample_scale(20.0, 3, 1.0)


def test_widen_scales_deviations_in_unit_coordinates_and_clips_to_the_box() -> None:
    bounds = [(0.0, 10.0, "lin"), (0.01, 100.0, "log"), (2.0, 2.0, "lin")]
    est = np.array([5.0, 1.0, 2.0])
    x = np.array([[6.0, 10.0, 2.0], [4.5, 0.1, 2.0], [9.0, 1.0, 2.0]])
    w = widen(x, est, bounds, 2.0)
    # linear: 5 + 2 (6 - 5) = 7, 5 + 2 (4.5 - 5) = 4, 5 + 2 (9 - 5) = 13 -> the bound 10
    assert w[:, 0] == pytest.approx([7.0, 4.0, 10.0])
    # log: a decade above becomes two decades; a decade below, two below
    assert w[:, 1] == pytest.approx([100.0, 0.01, 1.0])
    assert np.all(w[:, 2] == 2.0)  # a fixed column is left alone
    assert np.allclose(widen(x, est, bounds, 1.0), x, rtol=1e-12)
    nothing = widen(x, est, bounds, math.inf)
    assert np.isnan(nothing[:, :2]).all() and np.all(nothing[:, 2] == 2.0)
    with pytest.raises(ValueError, match="factor"):
        widen(x, est, bounds, 0.5)


def test_widen_values_scales_a_quantitys_own_deviations() -> None:
    v = np.array([1.9, 2.1, 2.4, np.nan])
    w = widen_values(2.0, v, 1.5)
    assert w[:3] == pytest.approx([1.85, 2.15, 2.6]) and np.isnan(w[3])
    assert np.array_equal(widen_values(2.0, v[:3], 1.0), v[:3])
    assert np.isnan(widen_values(2.0, v, math.inf)).all()
    assert np.isnan(widen_values(math.nan, v, 1.5)).all()
    with pytest.raises(ValueError, match="factor"):
        widen_values(2.0, v, 0.9)


def test_a_combinations_interval_does_not_feel_the_box_of_its_terms() -> None:
    """Two parameters that trade off along a valley the data do not determine: the
    refits spread along it (``Tg + Gmin / v`` constant) by amounts that depend on the
    optimiser, not on the data. Widening the parameters and clipping them to the box
    before combining them turned that spread into a wide, one-sided interval of the
    combination; widened as a quantity of its own, it is the refits' spread of the
    combination times the factor, whatever they did along the valley."""
    from dataclasses import replace

    from avll.uncertainty import Uncertainty

    rng = np.random.default_rng(5)
    v, fac = 20.0, 1.5
    est = np.array([1.5, 1.0])  # Tg (s), Gmin (m): Gmin near its lower bound 0
    along = rng.normal(0.0, 0.05, 200)  # the valley: Tg + Gmin / v unchanged
    noise = rng.normal(0.0, 0.002, 200)  # what the data determine
    refits = np.column_stack([est[0] + along + noise, est[1] - v * along])
    bounds = {"Tg": (0.5, 4.0, "lin"), "Gmin": (0.0, 10.0, "lin")}
    base = Uncertainty(model="proposed", effects=(), names=("Tg", "Gmin"), estimate=est,
                       samples=widen(refits, est, list(bounds.values()), fac),
                       costs=np.zeros(200), level=0.95, method="blocks", block_s=10.0,
                       atom_s=1.0, bounds=bounds,
                       upper={"Tg": refits[:, 0], "Gmin": refits[:, 1]},
                       upper_estimate={"Tg": 1.5, "Gmin": 1.0}, mean_speed=v,
                       refits=refits, widening=fac)
    base = replace(base, upper={"Tg": base.samples[:, 0], "Gmin": base.samples[:, 1]})
    e, smp = base.time_gap_effective(v)
    assert e == pytest.approx(1.55)
    np.testing.assert_allclose(smp, e + fac * noise, rtol=0, atol=1e-12)
    # the clipped widened parameters, combined, give a much wider interval
    clipped = base.samples[:, 0] + base.samples[:, 1] / v
    assert np.ptp(clipped) > 5 * np.ptp(smp)


def _ls_coverage(x: np.ndarray, reps: int, rng: np.random.Generator) -> tuple[float, float]:
    """Coverage of the normal 95 % interval of the second coefficient of least squares
    on design ``x`` (G x p) with i.i.d. normal errors, its variance the sandwich from
    the fitted residuals (HC0, what a resampling of the observations sees), raw and
    widened by :func:`small_sample_scale`."""
    g, p = x.shape
    xtx_inv = np.linalg.inv(x.T @ x)
    beta = rng.standard_normal(p)
    k = small_sample_scale(float(g), p)
    raw = cor = 0
    for _ in range(reps):
        y = x @ beta + rng.standard_normal(g)
        b = xtx_inv @ x.T @ y
        r = y - x @ b
        se = math.sqrt((xtx_inv @ ((x * r[:, None] ** 2).T @ x) @ xtx_inv)[1, 1])
        raw += abs(b[1] - beta[1]) <= Z975 * se
        cor += abs(b[1] - beta[1]) <= Z975 * k * se
    return raw / reps, cor / reps


def test_correction_restores_the_coverage_of_least_squares_with_few_observations() -> None:
    """The premise on a known answer: least squares with ``G`` independent observations
    (the blocks) and ``p`` parameters. The residual-based variance is too small by
    ``(G - p) / G`` on average and its normal intervals undercover. With equal
    leverage (a balanced design: ``p / G`` each) the correction is exact in the mean
    and the intervals hold their level; with a random design (unequal leverage) it
    recovers most, not all, of the shortfall."""
    from scipy.linalg import hadamard

    rng = np.random.default_rng(20261128)
    raw, cor = _ls_coverage(hadamard(16)[:, :8].astype(float), 4000, rng)
    assert raw < 0.83, raw  # far too narrow uncorrected
    assert 0.935 <= cor <= 0.97, cor  # the 95 % held (Monte Carlo error ~0.35 %)
    x = np.column_stack([np.ones(20), rng.standard_normal((20, 7))])
    raw, cor = _ls_coverage(x, 4000, rng)
    assert raw < 0.85 and cor > raw + 0.08 and cor >= 0.90, (raw, cor)


def test_calibration_reports_its_widening_and_keeps_the_refits() -> None:
    from avll.synth_platoon import synth_platoon

    sp = synth_platoon(1, seed=11, duration=300.0, models=("proposed",))
    kw = dict(closed_loop=True, upper_free=("kg", "kv", "Tg", "Gmin"),
              weights=(1.0, 1.0, 0.01), bounds={"Gmin": (0.0, 10.0)}, seed=2, starts=1,
              max_generations=20)
    a = avll.calibrate("proposed", sp.runs, intervals=Intervals(n=16, block=10.0), **kw)
    b = avll.calibrate("proposed", sp.runs, intervals=Intervals(n=16, block=10.0,
                                                                correction="none"), **kw)
    ua, ub = a.uncertainty, b.uncertainty
    assert ua.blocks == pytest.approx(30.0, rel=1e-3) and ua.fitted == 10
    assert ua.widening == pytest.approx(small_sample_scale(ua.blocks, 10), rel=1e-12)
    assert ub.widening == 1.0 and np.array_equal(ub.samples, ub.refits)
    # the same refits (same multiplicities); the samples are the widened refits
    assert np.array_equal(ua.refits, ub.refits)
    bnd = [ua.bounds[n] for n in ua.names]
    assert np.array_equal(ua.samples, widen(ua.refits, ua.estimate, bnd, ua.widening),
                          equal_nan=True)
    tg = ua.names.index("Tg")
    wa = np.subtract(*ua.intervals["Tg"][::-1])
    wb = np.subtract(*ub.intervals["Tg"][::-1])
    assert wa > wb and "widened" in ua.report()
    del tg
    with pytest.raises(ValueError, match="correction"):
        Intervals(correction="basic")
