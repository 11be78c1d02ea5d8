"""Which effect closes a car's amplification gap
(:mod:`avll.studies.openacc_effects`): the gap selection and, on a follower driven
with a known actuator saturation, the calibrate-and-replay of the base model plus
each effect."""

from __future__ import annotations

import json

import numpy as np
import pytest

from avll import Run, SecondOrder, UpperLevel, calibrate, calibrate_many
from avll.effects import Saturation, WithEffects
from avll.rollout import closed_loop
from avll.studies import openacc as st
from avll.studies.openacc_effects import _gap_cars, effect_gaps


def _car(run_id, meas, errs):
    return {"run_id": run_id, "car": "X", "setting": "L", "amplification_measured": meas,
            "models": {m: {"amplification_replay_error": e} for m, e in errs.items()}}


def test_gap_cars_selects_cars_no_model_replays():
    s = st.OpenACCStudy({"cars": [
        _car("a", 1.2, {"first": 0.05, "second": -0.3}),   # first within 10 %
        _car("b", 1.2, {"first": 0.2, "second": -0.15}),   # none within: best second
        _car("c", None, {"first": 0.5}),                   # not excited
        _car("d", 1.1, {"first": None}),                   # no replay
    ]}, {}, {}, "")
    assert _gap_cars(s, 0.1) == [(1, "second")]
    assert _gap_cars(s, 0.16) == []


@pytest.fixture(scope="module")
def saturated_car():
    dt = 0.1
    t = np.arange(0, 300, dt)
    w = 2 * np.pi * 0.05
    lv = 8 + 1.5 * np.sin(w * t)
    lx = np.cumsum(lv) * dt + 300
    up = UpperLevel(kg=0.2, kv=0.6, Tg=1.5, Gmin=4.0)
    truth = WithEffects(SecondOrder(1.0, 0.2, 0.6, 0.3), (Saturation(0.35, 0.35),))
    tr = closed_loop(truth, lx, lv, dt, up, v0=float(lv[0]),
                             x0=float(lx[0] - up.Gmin - up.Tg * lv[0]))
    v = tr.v + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    run = Run(run_id="f/car", t=t, a=np.gradient(v, dt), v=v, x=tr.x, lead_x=lx, lead_v=lv,
              upper=up)
    res = calibrate_many("second", [run], "per_run", closed_loop=True,
                         upper_free=("kg", "kv", "Tg", "Gmin"), weights=st.WEIGHTS,
                         init="rest", starts=1, max_generations=40, bounds={"Gmin": (0, 10)})
    p = dict(res[0].params)
    a_r, _ = st.replay_amplification(st._model_of("second", p), st._upper_of(p), run)
    meas = st.amplification(v, lv, dt)[0]
    return run, p, float(res[0].cost), meas, a_r


def _gap_study(saturated_car):
    """A one-car study of the saturated car's linear fit, its replay declared outside
    the tolerance so that the car is examined (the replay is in fact close here)."""
    run, p, cost, meas, a_r = saturated_car
    car = {"run_id": run.run_id, "car": "X", "setting": "L", "amplification_measured": meas,
           "models": {"second": {"params": p, "cal_mse": cost, "amplification_replay": a_r,
                                 "amplification_replay_error": 0.5}}}
    return st.OpenACCStudy({"cars": [car], "band_hz": list(st.DEFAULT_BAND),
                            "bounds": {"Gmin": [0.0, 10.0]}}, {}, {}, "", runs=[run])


def test_effect_gaps_fits_and_replays_each_effect(saturated_car):
    run, _, cost, meas, _ = saturated_car
    s = _gap_study(saturated_car)
    out = effect_gaps(s, effects=("saturation", "delay", "grade"), max_generations=40, seed=1)
    json.dumps(out, allow_nan=False)
    assert out["n_gap"] == 1 and len(out["cars"]) == 1
    e = out["cars"][0]["effects"]
    assert "exo_grade" in e["grade"]["skipped"]
    sat = e["saturation"]
    # the fit starts from the linear fit, so it never ends above its cost, and the
    # gain is credited by the rule ...
    assert sat["cal_mse"] <= cost * (1 + 1e-9)
    assert sat["lowers_cost"] == (sat["cost_gain"] >= 0.02)
    # ... and its replay is scored against the measured amplification
    assert sat["amplification_replay_error"] == pytest.approx(
        sat["amplification_replay"] / meas - 1.0)
    assert sat["closes_gap"] == (abs(sat["amplification_replay_error"]) <= 0.1)
    # a delay the data do not have: the fit switches it off, the cost moves by less
    # than min_gain and the delay is not credited even though its replay is close
    assert e["delay"]["cost_gain"] < 0.02 and not e["delay"]["lowers_cost"]
    assert not e["delay"]["closes_gap"]
    assert out["closed_by"]["delay"] == 0
    assert out["closed_by"]["saturation"] == int(sat["closes_gap"])
    assert (out["not_closed"] == []) == sat["closes_gap"]


def test_effect_gaps_rejects_bad_arguments(saturated_car):
    s = st.OpenACCStudy({"cars": []}, {}, {}, "")
    with pytest.raises(ValueError, match="tol"):
        effect_gaps(s, tol=1.5)
    with pytest.raises(ValueError, match="min_gain"):
        effect_gaps(s, min_gain=-1)
    with pytest.raises(ValueError, match="unknown effect 'nope'"):
        effect_gaps(s, effects=("nope",))


def test_the_upper_bounds_name_a_known_gain(saturated_car):
    run = saturated_car[0]
    with pytest.raises(ValueError, match="bounds: unknown parameter 'G0'"):
        calibrate("second", [run], closed_loop=True, upper_free=("kg", "kv", "Tg", "Gmin"),
                  max_generations=2, bounds={"G0": (0.0, 1.0)})


def test_effect_gaps_can_recover_the_true_saturation(saturated_car):
    """The true effect lowers the calibration cost of the linear fit by far and is found
    near its value (a_max = d_max = 0.35 m/s²) by at least one of four seeds, four starts
    each, 40 generations. Not by every seed: the linear fit compensates for the
    saturation with degenerate parameters (Gmin at its bound, m2 and m3 near theirs),
    and its basin holds the search that starts there. Measured on seeds 1-8 with four
    starts: 4 of 8 below half the linear fit's cost 0.0706 (0.0054 to 0.0108, the truth's
    cost 0.0054); with
    one start 0 of 6, and 2 of 6 from the linear fit of the build before the closed
    loop's local-stability rule (its fit differs in the fourth digit of the cost; from
    that same start this build gives the same six results)."""
    cost = saturated_car[2]
    s = _gap_study(saturated_car)
    found = []
    for seed in (1, 2, 3, 4):
        out = effect_gaps(s, effects=("saturation",), max_generations=40, seed=seed,
                          starts=4)
        sat = out["cars"][0]["effects"]["saturation"]
        assert sat["cal_mse"] <= cost * (1 + 1e-9)
        if sat["cal_mse"] < 0.5 * cost:
            found.append(sat)
    assert found, "no seed found the saturation"
    for sat in found:
        assert sat["lowers_cost"]
        assert sat["params"]["a_max"] == pytest.approx(0.35, rel=0.1)
        assert sat["params"]["d_max"] == pytest.approx(0.35, rel=0.1)
