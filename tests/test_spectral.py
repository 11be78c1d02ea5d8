"""avll.spectral: the H1 band-gain estimate on systems with a known transfer."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import signal

from avll.spectral import MIN_SEGMENTS, h1_band_gain, welch_effective_averages

DT = 0.1
BAND = (0.02, 0.2)


def _input(rng: np.random.Generator, n: int, rms: float = 0.8) -> np.ndarray:
    """Band-limited Gaussian noise (0.01-0.3 Hz) of band RMS about ``rms`` plus a cruise."""
    sos = signal.butter(2, [0.01 * 2 * DT, 0.3 * 2 * DT], btype="bandpass", output="sos")
    x = signal.sosfilt(sos, rng.normal(size=n + 2000))[2000:]
    return 20.0 + rms * x / np.std(x)


def _system(x: np.ndarray, gain: float, tau: float, delay: int) -> np.ndarray:
    """``y = gain e^{-s delay dt} / (tau s + 1) x`` (exact ZOH discretisation)."""
    a = math.exp(-DT / tau)
    y = signal.lfilter([gain * (1 - a)], [1.0, -a], x - x[0]) + gain * x[0]
    return np.concatenate([np.full(delay, y[0]), y[:-delay]]) if delay else y


def _true_band_gain(x: np.ndarray, gain: float, tau: float) -> float:
    """|H| as an RMS gain on the band-passed input's periodogram (the weighting of
    avll.studies.openacc.predicted_amplification)."""
    from avll.studies.openacc import bandpass

    f, p = signal.periodogram(bandpass(x, DT, BAND), fs=1 / DT, window="hann", detrend=False)
    m = (f >= BAND[0]) & (f <= BAND[1])
    h2 = gain**2 / (1 + (2 * np.pi * f[m] * tau) ** 2)
    return float(np.sqrt(np.sum(h2 * p[m]) / np.sum(p[m])))


def test_known_system_without_noise_is_recovered() -> None:
    rng = np.random.default_rng(5101)
    x = _input(rng, 6000)
    for gain, tau, delay in ((1.2, 0.5, 15), (0.9, 2.0, 25), (1.05, 1.0, 0)):
        y = _system(x, gain, tau, delay)
        res = h1_band_gain(x, y, DT, BAND)
        truth = _true_band_gain(x, gain, tau)
        assert res.gain == pytest.approx(truth, rel=0.02), (gain, tau, delay)
        assert res.coherence is not None and res.coherence > 0.97
        # the group delay of the lag is below tau in the band: the shift lies between
        assert delay * DT - 0.2 <= res.lag_s <= delay * DT + tau + 0.2
        assert res.ci is not None and res.ci[0] <= res.gain <= res.ci[1]


def test_output_noise_lowers_coherence_not_the_gain() -> None:
    """A disturbance on the output only (uncorrelated with the input) leaves H1
    consistent: over 20 records the median error is small and the 95 % intervals
    cover the truth most of the time; the band RMS ratio is inflated."""
    from avll.studies.openacc import amplification

    rng = np.random.default_rng(5102)
    errs, inside, ratio_errs, cohs = [], [], [], []
    for _ in range(20):
        x = _input(rng, 6000)
        y = _system(x, 1.1, 1.0, 15)
        sos = signal.butter(2, [0.02 * 2 * DT, 0.2 * 2 * DT], btype="bandpass", output="sos")
        d = signal.sosfilt(sos, rng.normal(size=y.size))
        y = y + 0.4 * d / np.std(d)
        truth = _true_band_gain(x, 1.1, 1.0)
        res = h1_band_gain(x, y, DT, BAND)
        assert res.gain is not None and res.ci is not None and res.coherence is not None
        errs.append(res.gain / truth - 1)
        inside.append(res.ci[0] <= truth <= res.ci[1])
        cohs.append(res.coherence)
        ratio_errs.append(amplification(y, x, DT, BAND)[0] / truth - 1)
    assert abs(np.median(errs)) < 0.03
    assert np.median(cohs) < 0.95
    assert np.mean(inside) >= 0.8, f"coverage {np.mean(inside):.2f}"
    assert np.median(ratio_errs) > 0.03  # the ratio counts the disturbance as gain


def test_input_noise_biases_h1_low() -> None:
    """Noise on the input (the predecessor's measured speed) biases H1 low by about
    ``S_uu / (S_uu + S_nn)``."""
    rng = np.random.default_rng(5103)
    errs = []
    for _ in range(10):
        x = _input(rng, 6000, rms=0.5)
        y = _system(x, 1.0, 1.0, 10)
        n = 0.25 * rng.normal(size=x.size)
        sos = signal.butter(2, [0.02 * 2 * DT, 0.2 * 2 * DT], btype="bandpass", output="sos")
        n = signal.sosfilt(sos, n)
        n *= 0.25 / np.std(n)  # band noise RMS 0.25 against a band signal RMS ~0.5
        res = h1_band_gain(x + n, y, DT, BAND)
        assert res.gain is not None
        errs.append(res.gain / _true_band_gain(x, 1.0, 1.0) - 1)
    assert -0.35 < np.median(errs) < -0.1


def test_welch_spectra_match_scipy() -> None:
    rng = np.random.default_rng(5104)
    x = _input(rng, 3000)
    y = _system(x, 1.3, 0.7, 0)
    res = h1_band_gain(x, y, DT, BAND, align=False, segment=1 / BAND[0])
    n = int(round(1 / BAND[0] / DT))
    f, pxy = signal.csd(x, y, fs=1 / DT, window="hann", nperseg=n, noverlap=n // 2,
                        detrend="linear")
    _, pxx = signal.welch(x, fs=1 / DT, window="hann", nperseg=n, noverlap=n // 2,
                          detrend="linear")
    _, coh = signal.coherence(x, y, fs=1 / DT, window="hann", nperseg=n, noverlap=n // 2,
                              detrend="linear")
    m = (f >= BAND[0] - 1e-9) & (f <= BAND[1] + 1e-9)
    np.testing.assert_allclose(res.freqs, f[m])
    np.testing.assert_allclose(res.h, pxy[m] / pxx[m], rtol=1e-9)
    np.testing.assert_allclose(res.coh, coh[m], rtol=1e-9)
    # the excitation is the band RMS of the predecessor's speed (Parseval)
    df = f[1] - f[0]
    assert res.excitation == pytest.approx(math.sqrt(np.sum(pxx[m]) * df), rel=1e-9)


@pytest.mark.parametrize("seconds", [2.0, 40.0, 70.0, 89.0])
def test_short_record_gives_none_with_a_reason(seconds: float) -> None:
    rng = np.random.default_rng(5105)
    x = _input(rng, int(seconds / DT))
    res = h1_band_gain(x, x, DT, BAND)
    assert res.gain is None and res.ci is None
    assert res.n_segments < MIN_SEGMENTS
    assert "Welch segment" in (res.reason or "") and "s" in (res.reason or "")
    json.dumps(res.to_dict(), allow_nan=False)


def test_no_excitation_gives_none_with_a_reason() -> None:
    rng = np.random.default_rng(5106)
    x = 15.0 + 0.001 * rng.normal(size=3000)
    res = h1_band_gain(x, x + 0.01 * rng.normal(size=3000), DT, BAND)
    assert res.gain is None and "does not excite" in (res.reason or "")


def test_result_is_strict_json() -> None:
    rng = np.random.default_rng(5107)
    x = _input(rng, 3000)
    d = h1_band_gain(x, _system(x, 1.0, 1.0, 5), DT, BAND).to_dict()
    assert set(d) >= {"gain", "ci", "coherence", "n_segments", "n_effective", "reason",
                      "ci_reason", "lag_s", "method"}
    json.dumps(d, allow_nan=False)


def test_effective_averages() -> None:
    assert welch_effective_averages(0) == 0.0
    assert welch_effective_averages(1) == 1.0
    assert 0.9 * 20 < welch_effective_averages(20) < 20
    # the numerical window correlation at half overlap is Welch's 0.167
    assert welch_effective_averages(20, 500, 250) == pytest.approx(
        welch_effective_averages(20), rel=1e-3)
    # more overlap, fewer independent averages per segment
    assert welch_effective_averages(3, 500, 200) < welch_effective_averages(3, 500, 250)


def test_record_just_short_of_three_segments_is_estimated() -> None:
    """A 99.9 s record (many ZalaZone files) still gives three 50 s segments."""
    rng = np.random.default_rng(5108)
    x = _input(rng, 999)
    res = h1_band_gain(x, _system(x, 1.0, 1.0, 5), DT, BAND)
    assert res.gain is not None and res.n_segments == MIN_SEGMENTS
    assert res.segment_s == pytest.approx(50.0)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"lead_v": "abc"}, "lead_v"),
        ({"v": [1.0, float("nan")] * 600}, "v: not finite at sample 1"),
        ({"v": np.ones(10)}, "different lengths"),
        ({"v": np.ones((2, 600))}, "v: must be 1-D"),
        ({"band": (0.2, 0.02)}, "band"),
        ({"band": (0.02, 6.0)}, "band"),
        ({"band": "x"}, "band"),
        ({"dt": 0.0}, "dt"),
        ({"segment": 10.0}, "segment"),
        ({"level": 1.5}, "level"),
    ],
)
def test_bad_input_is_a_clear_error(kw: dict, match: str) -> None:
    args = {"lead_v": np.ones(1200), "v": np.ones(1200), "dt": DT, "band": BAND}
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        h1_band_gain(args.pop("lead_v"), args.pop("v"), args.pop("dt"), args.pop("band"),
                     **args)


def test_band_rms_gain_is_the_models_band_amplification() -> None:
    """band_rms_gain weighs |H| by band_weights: a flat gain comes back, no power is NaN,
    and predicted_amplification is this computation (the one path)."""
    from avll.models import Proposed, UpperLevel
    from avll.paper import TABLE_II_PARAMS
    from avll.spectral import band_rms_gain, band_weights
    from avll.studies.openacc import predicted_amplification, transfer_gain

    dt = 0.1
    t = np.arange(3000) * dt
    lead_v = 20.0 + np.sin(2 * np.pi * 0.05 * t) + 0.5 * np.sin(2 * np.pi * 0.13 * t)
    assert band_rms_gain(lambda f: np.full(f.shape, 1.7), lead_v, dt) == pytest.approx(1.7)
    assert math.isnan(band_rms_gain(lambda f: np.ones(f.shape), np.zeros(3000), dt))
    m, up = Proposed(**TABLE_II_PARAMS["proposed"]), UpperLevel(kg=0.15, kv=0.4, Tg=1.5)
    f, w = band_weights(lead_v, dt)
    h = transfer_gain(m, up, f, v=float(np.mean(lead_v)), hold=dt)
    got = predicted_amplification(m, up, lead_v, dt)
    assert got == band_rms_gain(lambda ff: transfer_gain(m, up, ff, v=float(np.mean(lead_v)),
                                                         hold=dt), lead_v, dt)
    assert got == pytest.approx(math.sqrt(float(np.sum(h * h * w))), rel=1e-15)
