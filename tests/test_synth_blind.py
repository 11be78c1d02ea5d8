"""The physical blind generator (avll.synth_blind): determinism, the physics of
each effect, and the diagnosis loop on two of its scenarios."""

from __future__ import annotations

import inspect
import json
import math

import numpy as np
import pytest

from avll.diagnose import effect_loop, run_mse
from avll.models import UpperLevel
from avll.synth_blind import (
    ACCEPTABLE,
    DEFAULTS,
    SCENARIOS,
    _params,
    blind_experiment,
    simulate_vehicle,
)

DT = 0.05
UP = UpperLevel(kg=0.5, kv=0.0, Tg=2.0, Gmin=9.5)


def _open_loop(command: np.ndarray, v0: float, **overrides: object) -> dict:
    p = _params("clean", overrides)
    z = np.zeros(command.size)
    return simulate_vehicle(p, z, z, DT, UP, rng_latency=np.random.default_rng(0),
                            command=command, v0=v0, x0=0.0)  # fmt: skip


def test_deterministic_and_seeded() -> None:
    a = blind_experiment("delay_jitter", seed=3, runs=(1, 8), duration=30.0)
    b = blind_experiment("delay_jitter", seed=3, runs=(1, 8), duration=30.0)
    c = blind_experiment("delay_jitter", seed=4, runs=(1, 8), duration=30.0)
    for x, y, z in zip(a, b, c, strict=True):
        np.testing.assert_array_equal(x.a, y.a)
        np.testing.assert_array_equal(x.command, y.command)
        np.testing.assert_array_equal(x.exo["grade"], y.exo["grade"])
        assert not np.array_equal(x.a, z.a)
    # A run does not change when others are added; the leader is the same in every
    # scenario.
    one = blind_experiment("delay_jitter", seed=3, runs=(8,), duration=30.0)[0]
    np.testing.assert_array_equal(one.a, a[1].a)
    other = blind_experiment("sensor", seed=3, runs=(8,), duration=30.0)[0]
    np.testing.assert_array_equal(other.lead_v, one.lead_v)


def test_runs_follow_the_conventions() -> None:
    runs = blind_experiment("grade", seed=0, runs=(1, 3), duration=40.0)
    for r in runs:
        assert r.command_kind == "acceleration" and r.upper is not None
        assert float(r.t[1] - r.t[0]) == pytest.approx(DT)
        assert set(r.exo) == {"grade"}
        truth = r.meta["truth"]
        assert truth["scenario"] == "grade" and truth["acceptable"] == ["grade"]
        assert truth["params"]["grade_rms"] == SCENARIOS["grade"]["grade_rms"]
        json.dumps(r.meta, allow_nan=False)  # strict-JSON metadata
    assert set(ACCEPTABLE) == set(SCENARIOS)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="scenario"):
        blind_experiment("wind")
    with pytest.raises(ValueError, match="overrides"):
        blind_experiment("clean", overrides={"mass_kg": 1.0})
    with pytest.raises(ValueError, match="ar1_phi"):
        blind_experiment("clean", overrides={"ar1_phi": 1.0})
    with pytest.raises(ValueError, match="runs"):
        blind_experiment("clean", runs=(99,))


def test_power_limit_caps_acceleration_at_speed() -> None:
    power = 14.0e3
    u = np.full(400, 2.0)
    free = _open_loop(u, 12.0)
    lim = _open_loop(u, 12.0, power=power)
    m = DEFAULTS["mass"]
    settled = slice(100, None)  # after the lags
    assert free["a"][settled].min() > 1.9  # the unlimited car delivers the command
    cap = power / (m * lim["v"][settled])
    assert np.all(lim["a"][settled] <= cap + 1e-9)
    # ...and the cap binds (the car accelerates at nearly P/(m v) minus its road load)
    rl = (DEFAULTS["c0"] + DEFAULTS["c1"] * lim["v"] + DEFAULTS["c2"] * lim["v"] ** 2) / m
    np.testing.assert_allclose(lim["a"][settled], (cap - rl[settled]), atol=0.05)
    assert lim["limited_share"] > 0.5


def test_brake_lag_slows_only_the_braking_response() -> None:
    n = 300
    t0 = 5.0  # the actuators settle on the road-load feed-forward first
    step_down = np.where(np.arange(n) * DT >= t0, -1.0, 0.0)
    step_up = -step_down
    flat = {"c0": 0.0, "c1": 0.0, "c2": 0.0}  # no road load: the whole demand brakes
    fast_b = _open_loop(step_down, 15.0, **flat)
    slow_b = _open_loop(step_down, 15.0, brake_lag=0.9, **flat)

    def t63(a: np.ndarray) -> float:
        k0 = int(t0 / DT)
        d = a[k0:] - a[k0]
        return float(np.argmax(np.abs(d) >= 0.63 * abs(d[-1])) * DT)

    # 0.9 s instead of 0.35 s of brake lag: the 63 % time grows by about the difference
    assert t63(slow_b["a"]) - t63(fast_b["a"]) == pytest.approx(0.55, abs=0.15)
    np.testing.assert_allclose(_open_loop(step_up, 15.0)["a"],
                               _open_loop(step_up, 15.0, brake_lag=0.9)["a"])  # fmt: skip


def test_road_load_uncompensated_decelerates_a_coasting_car() -> None:
    u = np.zeros(40)
    comp = _open_loop(u, 20.0)
    unc = _open_loop(u, 20.0, road_load_comp=0.0)
    m, v = DEFAULTS["mass"], 20.0
    want = (DEFAULTS["c0"] * math.tanh(v / 0.3) + DEFAULTS["c1"] * v + DEFAULTS["c2"] * v * v) / m
    assert unc["a"][0] == pytest.approx(-want, rel=1e-6)
    # compensated: the feed-forward catches up after the lags
    assert abs(comp["a"][-1]) < 0.02 * want


def test_gear_shifts_cut_the_drive_force() -> None:
    u = np.full(300, 1.0)
    plain = _open_loop(u, 0.0)
    shift = _open_loop(u, 0.0, gear_up=(4.0, 8.0))
    # Upshift at 4 m/s: the acceleration dips well below the command, then recovers.
    k = int(np.argmax(shift["v"] >= 4.0))
    window = shift["a"][k : k + int(1.0 / DT)]
    assert window.min() < 0.5
    assert plain["a"][k : k + int(1.0 / DT)].min() > 0.95
    assert shift["shift_cut_share"] > 0


def test_sensor_bias_and_lag() -> None:
    # Without noise: both runs draw the same noise, which would favour no shift.
    ov = {"quantization_a": 0.0, "noise_a": 0.0}
    clean = blind_experiment("clean", seed=1, runs=(3,), overrides=ov)[0]
    sens = blind_experiment("sensor", seed=1, runs=(3,), overrides=ov)[0]
    np.testing.assert_array_equal(sens.command, clean.command)  # the vehicle is the same
    bias = SCENARIOS["sensor"]["sensor_bias"]
    assert float(np.mean(sens.a - clean.a)) == pytest.approx(bias, abs=0.005)
    # The lag: the sensor's signal best matches the clean one delayed by about the
    # lag (a first-order lag delays slow signals by its time constant).
    d = sens.a - bias
    errs = [float(np.mean((d[k:] - clean.a[: d.size - k]) ** 2)) for k in range(0, 20)]
    k_best = int(np.argmin(errs))
    assert abs(k_best * DT - SCENARIOS["sensor"]["sensor_lag"]) <= 0.1


def test_ar1_noise_has_the_declared_autocorrelation_and_size() -> None:
    ov = {"quantization_a": 0.0}
    runs = (1, 3, 8, 15)
    clean = blind_experiment("clean", seed=2, runs=runs, overrides=ov)
    noisy = blind_experiment("noise_ar1", seed=2, runs=runs, overrides=ov)
    e = [n.a - c.a for n, c in zip(noisy, clean, strict=True)]
    phi, sigma = SCENARIOS["noise_ar1"]["ar1_phi"], SCENARIOS["noise_ar1"]["ar1_sigma"]
    lag1 = np.mean([np.corrcoef(x[1:], x[:-1])[0, 1] for x in e])
    assert lag1 == pytest.approx(phi, abs=0.02)
    assert float(np.std(np.concatenate(e))) == pytest.approx(sigma, rel=0.15)


def test_grade_estimate_tracks_the_terrain() -> None:
    flat = blind_experiment("clean", seed=0, runs=(1,), duration=60.0)[0]
    hills = blind_experiment("grade", seed=0, runs=(1,), duration=120.0)[0]
    assert float(np.std(flat.exo["grade"])) < 0.004  # sensor noise only
    assert float(np.std(hills.exo["grade"])) > 0.5 * SCENARIOS["grade"]["grade_rms"]
    # Uphill costs acceleration: the gravity term shows in a - command.
    r = hills.a - hills.command
    assert np.corrcoef(r, hills.exo["grade"])[0, 1] < -0.5


def test_delay_jitter_only_adds_latency() -> None:
    # A 1 m/s² step; without road load the speed gained by the end is the step's
    # integral after the latency, so the jittered car (extra latency in [0, 0.2] s
    # per sample) ends slower by its mean extra latency times 1 m/s².
    n = 200
    u = np.where(np.arange(n) * DT >= 1.0, 1.0, 0.0)
    flat = {"c0": 0.0, "c1": 0.0, "c2": 0.0}
    base = _open_loop(u, 10.0, **flat)
    z = np.zeros(n)
    lag = []
    for seed in (5, 6):
        p = _params("clean", {"jitter_max": 0.2, **flat})
        jit = simulate_vehicle(p, z, z, DT, UP, rng_latency=np.random.default_rng(seed),
                               command=u, v0=10.0, x0=0.0)  # fmt: skip
        lag.append(float(base["v"][-1] - jit["v"][-1]))
    assert all(0.0 < x < 0.2 for x in lag), lag
    assert lag[0] != lag[1]


# --- the loop on the generator --------------------------------------------


def _loop_kwargs() -> dict:
    """Seed 1, and a small GA budget where the loop exposes one (``max_generations``,
    ``starts``), so that the cross-validated loop stays within the time of a test."""
    params = inspect.signature(effect_loop).parameters
    kw: dict = {"seed": 1}
    kw.update({k: v for k, v in (("max_generations", 150), ("starts", 1)) if k in params})
    return kw


def _split(scenario: str) -> tuple[list, list, list]:
    runs = blind_experiment(scenario, seed=0)
    return runs[:4], runs[4:6], runs[6:]


def test_loop_accepts_nothing_on_coloured_noise_only() -> None:
    """The false-positive control: AR(1) measurement noise (phi 0.95, sigma 0.08)
    on an effect-free vehicle gets no effect."""
    cal, val, _ = _split("noise_ar1")
    res = effect_loop("second", cal, val, **_loop_kwargs())
    assert res.steps == []


@pytest.mark.slow
def test_loop_finds_asymmetric_for_a_slow_brake() -> None:
    """Brake lag 0.9 s vs drive lag 0.35 s: the loop accepts `asymmetric` (the right
    class; the library's form is a time scale of the whole model while braking),
    and the gain holds on test runs it never saw."""
    cal, val, test = _split("brake_lag")
    res = effect_loop("second", cal, val, **_loop_kwargs())
    assert [s.effect for s in res.steps] == ["asymmetric"]
    assert res.steps[0].params["rb"] > 1.2  # slower while braking
    before = float(np.mean(run_mse(res.baseline, test)))
    after = float(np.mean(run_mse(res.final, test)))
    assert after < 0.95 * before


def test_one_substeps_default_and_one_duration_rule() -> None:
    """The integration's steps per sample are one decision (SUBSTEPS), the default of
    every generator function; the minimum run length is synth's one rule."""
    from avll import synth, synth_blind

    for f in (synth_blind.simulate_vehicle, synth_blind.simulate_platoon,
              synth_blind.blind_experiment):
        assert inspect.signature(f).parameters["substeps"].default is synth_blind.SUBSTEPS
    short = synth.MIN_SAMPLES * DT
    for make in (lambda: blind_experiment("clean", runs=(1,), duration=short, dt=DT),
                 lambda: synth.paper_experiment(runs=(1,), duration=short, dt=DT)):
        with pytest.raises(ValueError, match=f"> {synth.MIN_SAMPLES} dt"):
            make()
