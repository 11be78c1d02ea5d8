"""avll.synth_platoon: synthetic platoons with a known truth, and the validation of
both measured-amplification estimators on them. Each test uses its
own seeds, none of them the seeds the estimators were developed on."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from avll.effects import Grade, Saturation
from avll.models import SecondOrder, UpperLevel
from avll.spectral import h1_band_gain
from avll.studies.openacc import amplification
from avll.synth_platoon import (
    EQUIPMENT,
    CarTruth,
    Equipment,
    random_car,
    synth_platoon,
    validate_amplification,
)

STUDY_META = ("file", "car", "setting", "position", "acc", "track", "folder", "lead_car")


def test_runs_have_the_loader_form_and_the_truth() -> None:
    pl = synth_platoon(4, seed=7101, equipment="jrc", duration=300.0)
    assert len(pl.runs) == len(pl.truth) == 4
    assert pl.v.shape == pl.x.shape == (5, 3000)
    for i, (r, tr) in enumerate(zip(pl.runs, pl.truth, strict=True), start=1):
        assert r.dt == pytest.approx(0.1)
        assert r.command is None and r.lead_x is not None and r.lead_v is not None
        assert all(k in r.meta for k in STUDY_META)
        assert r.meta["position"] == i - 1 and r.meta["truth"] is tr
        assert r.x is not None and abs(r.x[0]) < 3.0  # arc length from 0, plus noise
        # the spacing is the true one plus the equipment's spacing noise
        gap = r.lead_x - r.x
        err = gap - (pl.x[i - 1] - pl.x[i])
        assert np.std(err) < 1.5
        # a car's measured speed is the same realisation in its run and its follower's
        if i > 1:
            np.testing.assert_array_equal(r.lead_v, pl.runs[i - 2].v)
        assert set(tr) >= {"model", "params", "upper", "band_gain", "freqs", "H_abs",
                           "time_gap_effective", "v_mean", "rms_ratio_true"}
        up = tr["upper"]
        assert tr["time_gap_effective"] == pytest.approx(up["Tg"] + up["Gmin"] / tr["v_mean"])
        assert len(tr["freqs"]) == len(tr["H_abs"]) > 10
        json.dumps(tr, allow_nan=False)
    assert {t["model"] for t in pl.truth} == {"first", "second", "proposed"}


def test_seeded() -> None:
    a = synth_platoon(2, seed=7102, duration=200.0)
    b = synth_platoon(2, seed=7102, duration=200.0)
    c = synth_platoon(2, seed=7103, duration=200.0)
    np.testing.assert_array_equal(a.runs[1].v, b.runs[1].v)
    assert not np.allclose(a.runs[1].v, c.runs[1].v)


@pytest.mark.parametrize("name", ["zalazone", "jrc"])
def test_equipment_noise_levels(name: str) -> None:
    eq = EQUIPMENT[name]
    pl = synth_platoon(2, seed=7104, equipment=name, duration=600.0)
    r = pl.runs[1]
    assert r.v is not None
    err = r.v - pl.v[2]
    want = float(np.hypot(eq.speed_white, eq.speed_coloured))
    assert np.std(err) == pytest.approx(want, rel=0.25)
    # the unfiltered receiver is rough sample to sample, the smoothed one is not
    white = float(np.std(np.diff(err, 2))) / np.sqrt(6)
    assert white == pytest.approx(eq.speed_white, rel=0.3, abs=0.003)


def test_plant_matches_the_linear_truth() -> None:
    """Without disturbance and noise both estimators find the true band gain: the
    100 Hz plant sampled at 10 Hz is the |H| of the truth. Not exactly per car: over
    a finite record two leader tones closer than 1/T beat, so the band RMS of a
    resonant car's speed is not its power-weighted |H| (on seeds 7500-7505, 36 cars:
    median |error| 0.9 % for the ratio, 1.1 % for H1, the worst 6 % and 12 %)."""
    er, eh = [], []
    for seed in (7601, 7602):
        pl = synth_platoon(6, seed=seed, equipment="none", disturbance_std=0.0)
        for r, tr in zip(pl.runs, pl.truth, strict=True):
            assert r.v is not None and r.lead_v is not None
            ratio = amplification(r.v, r.lead_v, r.dt)[0]
            assert tr["rms_ratio_true"] == pytest.approx(ratio)
            er.append(ratio / tr["band_gain"] - 1)
            g = h1_band_gain(r.lead_v, r.v, r.dt)
            assert g.gain is not None
            eh.append(g.gain / tr["band_gain"] - 1)
    for e in (np.array(er), np.array(eh)):
        assert abs(np.median(e)) < 0.01
        assert np.median(np.abs(e)) < 0.02
        assert np.max(np.abs(e)) < 0.15


def test_start_in_equilibrium() -> None:
    car = CarTruth(SecondOrder(K0=1.0, m2=0.05, m3=0.4, Td=0.3),
                   UpperLevel(kg=0.15, kv=0.4, Tg=1.5, Gmin=3.0), disturbance_std=0.0)
    pl = synth_platoon([car], seed=7106, equipment="none", warmup=0.0, band_rms=0.0,
                       drift_rms=0.0, duration=60.0)
    assert np.ptp(pl.v[1]) < 1e-6
    assert pl.x[0, 0] - pl.x[1, 0] == pytest.approx(3.0 + 1.5 * 20.0)


def test_cars_with_effects() -> None:
    rng = np.random.default_rng(7107)
    car = random_car(rng, "proposed", effects=(Saturation(a_max=3.0, d_max=5.0),))
    pl = synth_platoon([car], seed=7107, equipment="zalazone", duration=300.0)
    assert pl.truth[0]["effects"][0]["name"] == "saturation"
    assert np.isfinite(pl.truth[0]["band_gain"])


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"equipment": "vbox"}, "equipment: unknown"),
        ({"equipment": 3}, "equipment"),
        ({"fine_dt": 0.03}, "fine_dt"),
        ({"band": (0.3, 0.1)}, "band"),
        ({"cars": 0}, "cars"),
        ({"cars": []}, "cars"),
        ({"cars": ["x"]}, "cars"),
        ({"duration": 1.0}, "duration"),
        ({"v_mean": 1.0}, "v_mean"),
    ],
)
def test_bad_input_is_a_clear_error(kw: dict, match: str) -> None:
    args = {"cars": 1, "seed": 1, "duration": 100.0}
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        synth_platoon(args.pop("cars"), **args)


def test_bad_truth_is_a_clear_error() -> None:
    m = SecondOrder(K0=1.0, m2=0.05, m3=0.4, Td=0.3)
    up = UpperLevel(kg=0.1)
    with pytest.raises(ValueError, match="grade"):
        CarTruth(m, up, effects=(Grade(g_eff=9.81),))
    with pytest.raises(ValueError, match="disturbance_std"):
        CarTruth(m, up, disturbance_std=-1.0)
    with pytest.raises(ValueError, match="speed_white"):
        Equipment("x", speed_white=-0.1)


# ---------------------------------------------------------------------------
# Validation of the estimators against the truth
# ---------------------------------------------------------------------------


def test_both_estimators_recover_the_band_gain() -> None:
    """JRC-like noise, a mild follower disturbance (0.05 m/s², 3 s): both estimators
    within 10 % for at least 90 % of cars, median error within 2 %, and their 95 %
    intervals cover the truth for at least 85 % of cars (the issue's target)."""
    v = validate_amplification(range(7200, 7205), equipment="jrc")
    r, h = v["rms_ratio"], v["h1"]
    assert r["n"] == h["n"] == 25 and r["missing"] == h["missing"] == 0
    assert r["within_10pct"] >= 0.9 and h["within_10pct"] >= 0.9
    assert abs(r["median_error"]) < 0.02 and abs(h["median_error"]) < 0.02
    assert r["coverage"] >= 0.85 and h["coverage"] >= 0.85
    assert h["median_coherence"] > 0.9


def test_follower_disturbance_inflates_the_rms_ratio_not_h1() -> None:
    """A strong follower-side disturbance (0.3 m/s²): the RMS ratio counts it as
    gain (median error > +5 %), H1 stays unbiased (median error within 3 %) with a
    lower coherence."""
    v = validate_amplification(range(7300, 7304), equipment="jrc", disturbance_std=0.3)
    r, h = v["rms_ratio"], v["h1"]
    assert r["median_error"] > 0.05
    assert abs(h["median_error"]) < 0.03
    assert h["within_10pct"] >= 0.8 and h["coverage"] >= 0.8
    assert h["median_coherence"] < 0.9


def test_input_noise_biases_h1_low() -> None:
    """Slow speed noise of 0.1 m/s on every car against a weak excitation (band RMS
    0.3 m/s): H1 is biased low by the noise on its input (median error below -3 %),
    the RMS ratio high by the noise on its numerator."""
    noisy = Equipment("noisy", speed_white=0.05, speed_coloured=0.1, speed_tau=3.0)
    v = validate_amplification(range(7400, 7404), equipment=noisy, band_rms=0.3)
    assert v["h1"]["median_error"] < -0.03
    assert v["rms_ratio"]["median_error"] > 0.0


def _white_level(x: np.ndarray) -> float:
    """Robust white-noise level of a series from its second differences."""
    x = x[np.isfinite(x)]
    d = np.diff(x, 2)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(6))


def _columns(path: Path, prefix: str) -> dict[str, np.ndarray]:
    import pandas as pd

    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("Time"))
    d = pd.read_csv(io.StringIO("\n".join(lines[k:])))
    return {c: d[c].to_numpy(dtype=float) for c in d.columns if c.startswith(prefix)}


def test_presets_against_the_shared_files(shared_data: Path) -> None:
    """The measured noise levels the module doc quotes to justify the presets, and
    each preset's white speed noise inside the measured range."""
    zala = shared_data / "openacc-zalazone" / "short_setting" / "dynamic_part12.csv"
    jrc = [shared_data / "openacc-jrc" / "JRC low speed" / f"part{i}.csv" for i in (1, 11)]
    for p in (zala, *jrc):
        if not p.is_file():
            pytest.skip(f"{p} is absent (a different version of the shared data?)")
    zs = [_white_level(v) for c, v in _columns(zala, "Speed").items() if c != "Speed1"]
    assert 0.0005 <= round(min(zs), 4) and round(max(zs), 4) <= 0.0013, zs
    assert min(zs) <= EQUIPMENT["zalazone"].speed_white <= max(zs)
    js = [_white_level(v) for p in jrc for v in _columns(p, "Speed").values()]
    assert 0.012 <= round(min(js), 3) and round(max(js), 3) <= 0.064, js
    assert min(js) <= EQUIPMENT["jrc"].speed_white <= max(js)
    ivs = [_white_level(v) for p in jrc for v in _columns(p, "IVS").values()]
    assert 0.005 <= round(min(ivs), 3) and round(max(ivs), 3) <= 0.008, ivs


def test_one_disturbance_and_plant_period_default() -> None:
    """The follower disturbance (0.05 m/s², 3 s) and the plant's period (0.01 s) are
    one decision each: every signature and the CarTruth fields default to the named
    constants, and synth_campaign's cars get them when not told otherwise."""
    import dataclasses
    import inspect

    from avll import synth_platoon as sp

    assert (sp.DISTURBANCE_STD, sp.DISTURBANCE_TAU, sp.FINE_DT) == (0.05, 3.0, 0.01)
    fields = {f.name: f.default for f in dataclasses.fields(CarTruth)}
    assert (fields["disturbance_std"], fields["disturbance_tau"]) == (
        sp.DISTURBANCE_STD, sp.DISTURBANCE_TAU)
    for f in (random_car, synth_platoon):
        ps = inspect.signature(f).parameters
        assert ps["disturbance_std"].default is sp.DISTURBANCE_STD
        assert ps["disturbance_tau"].default is sp.DISTURBANCE_TAU
        assert ps["fine_dt"].default is sp.FINE_DT
    runs = sp.synth_campaign(1, 1, seed=7131, duration=30.0, warmup=0.0)
    tr = runs[0].meta["truth"]
    assert (tr["disturbance_std"], tr["disturbance_tau"]) == (sp.DISTURBANCE_STD,
                                                              sp.DISTURBANCE_TAU)


def test_truth_time_gap_is_the_study_definition() -> None:
    """The truth's ``Tg + Gmin / v̄`` is the OpenACC study's own (time_gap_effective),
    with and without an upper-level structure, to the bit."""
    from avll.effects import SpeedGains, WithEffects
    from avll.models import Proposed
    from avll.paper import TABLE_II_PARAMS
    from avll.studies.openacc import time_gap_effective

    m = Proposed(**TABLE_II_PARAMS["proposed"])
    up = UpperLevel(kg=0.15, kv=0.4, Tg=1.5, Gmin=3.0)
    cars = [CarTruth(m, up), CarTruth(m, up, (SpeedGains(ch=0.01, cs=0.0),))]
    pl = synth_platoon(cars, seed=7141, duration=60.0, warmup=10.0)
    for car, tr in zip(cars, pl.truth, strict=True):
        want = time_gap_effective(WithEffects(car.model, car.effects), car.upper,
                                  tr["v_mean"])
        assert tr["time_gap_effective"] == want
    assert pl.truth[1]["time_gap_effective"] != pytest.approx(pl.truth[0]["time_gap_effective"])


def test_truth_band_gain_is_the_study_prediction_of_the_true_car() -> None:
    """The truth's band gain is the study's predicted amplification of the true car
    (one weighting, avll.spectral.band_rms_gain), to the bit, at the plant's period."""
    from avll.effects import WithEffects
    from avll.models import model_class
    from avll.studies.openacc import predicted_amplification
    from avll.synth_platoon import FINE_DT

    pl = synth_platoon(3, seed=7151, duration=200.0, equipment="none")
    for i, (r, tr) in enumerate(zip(pl.runs, pl.truth, strict=True), start=1):
        model = model_class(tr["model"])(**tr["params"])
        want = predicted_amplification(WithEffects(model, ()), UpperLevel(**tr["upper"]),
                                       pl.v[i - 1], r.dt, tr["band"], v=tr["v_mean"],
                                       hold=FINE_DT)
        assert tr["band_gain"] == want
