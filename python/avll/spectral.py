"""A cross-spectral transfer-gain estimate of a follower's amplification.

The band RMS ratio (:func:`avll.studies.openacc.amplification`) divides the band power
of the follower's speed by that of its predecessor. Everything in the follower's speed
that its predecessor did not cause -- the follower's own disturbances (road, wind, the
ACC's own hunting) and its speed-measurement noise -- adds to the numerator, so the
ratio over-states the gain of the car's transfer from predecessor speed to follower
speed. This module estimates that gain directly:

* **H1.** ``H1(f) = S_xy(f) / S_xx(f)`` with ``x`` the predecessor's measured speed and
  ``y`` the follower's, Welch averages (Hann window, 50 % overlap, each segment detrended
  by a straight line) over segments of ``2 / low`` seconds (100 s for the default band)
  when the record holds at least :data:`MIN_SEGMENTS` of them, else ``1 / low`` (the
  shortest segment with a bin at the band's low edge: OpenACC records are often only
  100-300 s). Before averaging, the follower's speed is shifted back by its delay
  behind the predecessor (the phase slope of a first H1 over the band): a delay
  ``tau`` lowers ``|H1|`` by about ``tau / T_segment`` and a pure delay has gain 1.
  Output-side disturbances and noise that are uncorrelated with ``x`` average out of
  ``S_xy``: H1 is consistent for them (they only widen its interval and lower the
  coherence).
* **Band gain.** ``G = sqrt(sum_j |H1(f_j)|^2 P(f_j) / sum_j P(f_j))`` over the bins
  ``f_j`` in the band of ``P``, the periodogram of the whole record of the
  predecessor's speed band-passed as the study does, ``|H1|^2`` interpolated linearly
  between the Welch bins: exactly the weighting
  :func:`avll.studies.openacc.predicted_amplification` gives a model's ``|H|``, so the
  two compare like with like. (Weighting by the coarse Welch ``S_xx`` instead ignores
  the band-pass's roll-off at the band edges and the record's fine spectral lines,
  which costs several per cent on a car with a steep ``|H|`` behind a leader with
  sharp spectral lines.)
* **Coherence.** ``gamma^2(f) = |S_xy|^2 / (S_xx S_yy)``; the reported ``coherence`` is
  its mean over the band with the band gain's weights (1: the follower's band speed is
  all explained linearly by the predecessor's).
* **Interval (95 %).** Analytic, from the coherence (Bendat & Piersol, *Random Data*,
  Sec. 9.2): ``var|H1(f)| / |H1(f)|^2 = (1 - gamma^2) / (2 n_d gamma^2)`` per bin, with
  ``n_d`` the *effective* number of averages of overlapped Hann segments (Welch 1967:
  ``K / (1 + 2 sum_j (1 - j/K) rho(j)^2)``, ``rho(1) = 0.167`` at 50 % overlap; a
  record just short of three half-overlapping segments gets up to 60 % overlap),
  propagated to ``G^2`` with the correlation between neighbouring bins that the Hann
  window introduces (``4/9`` for adjacent bins, ``1/36`` two bins apart), and made a
  log-normal interval ``G exp(+-1.96 sd(log G))`` (the weights are taken as fixed). Why
  this and not a block bootstrap: both respect the serial correlation (here through the
  overlap and the window), but a bootstrap over Welch segments degenerates with the 3-8
  segments a 100-300 s record gives, and a bootstrap over blocks of the raw series
  splices the input without splicing the response to it, which biases the transfer
  estimate at every join. The analytic interval is a large-sample approximation: with
  few averages the measured coherence is biased upwards (so the interval is too narrow),
  which the validation (``tests/test_spectral.py``, ``tests/test_synth_platoon.py``)
  measures.

Known biases (measured on synthetic platoons with a known truth, see the docs page
*Measured amplification*): H1 is biased **low** by noise on its input (the
predecessor's measured speed): ``E H1 = H S_uu / (S_uu + S_nn)``; in the 0.02-0.2 Hz
band GNSS speed noise is small against the oscillations of a platoon, but a predecessor
that barely moves makes this bias large (the estimate then returns ``None`` with a reason
below :data:`MIN_EXCITATION`). Without the delay alignment (``align=False``) H1 is
biased low by about ``tau / T_segment``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from ._limits import check_number
from .defaults import LEVEL

__all__ = [
    "DEFAULT_BAND",
    "TRIM",
    "bandpass",
    "check_band",
    "MIN_SEGMENTS",
    "MIN_EXCITATION",
    "MAX_LAG",
    "BandGain",
    "band_weights",
    "band_rms_gain",
    "h1_band_gain",
    "welch_effective_averages",
]

#: Band (Hz) of the amplification (the OpenACC study's band, :mod:`avll.studies.openacc`).
DEFAULT_BAND: tuple[float, float] = (0.02, 0.2)
#: Seconds cut at each end of the band-passed signals.
TRIM = 5.0
#: Fewest Welch segments for an estimate (with one segment the coherence is 1 by
#: construction and H1 is a ratio of two periodograms).
MIN_SEGMENTS = 3
#: Smallest band RMS (m/s) of the predecessor's speed that counts as an excitation
#: (the order of GNSS speed noise; the study's threshold).
MIN_EXCITATION = 0.05
#: Largest delay (s) of the follower behind its predecessor that the alignment removes.
MAX_LAG = 10.0

# Correlation of Hann-windowed periodograms of white noise at bin distance 1 and 2
# (|sum w^2 e^{-2 pi i j n / N}| / sum w^2 squared: (2/3)^2 and (1/6)^2).
_HANN_BIN_CORR = (1.0, 4.0 / 9.0, 1.0 / 36.0)
# Correlation of Hann windows shifted by half their length (Welch's rho(1) at 50 %).
_HANN_RHO_HALF = 0.1667


@dataclass(frozen=True)
class BandGain:
    """Result of :func:`h1_band_gain`.

    ``gain`` the band gain of H1 (``None`` with ``reason`` when the record cannot give
    one); ``ci`` its 95 % interval (``None`` with ``ci_reason``); ``coherence`` the
    band-weighted mean magnitude-squared coherence; ``n_segments``
    the Welch segments of ``segment_s`` seconds and ``n_effective`` their effective
    number of averages; ``excitation`` the predecessor's band RMS speed (m/s);
    ``freqs``, ``h`` (complex H1), ``coh`` and ``sxx`` per bin in the band."""

    gain: float | None
    ci: tuple[float, float] | None
    coherence: float | None
    n_segments: int
    n_effective: float
    segment_s: float
    excitation: float | None
    reason: str | None = None
    ci_reason: str | None = None
    lag_s: float = 0.0
    method: str = "H1 Welch, delay-aligned, coherence-based analytic interval"
    freqs: np.ndarray = field(default_factory=lambda: np.zeros(0))
    h: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=complex))
    coh: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sxx: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def to_dict(self) -> dict[str, Any]:
        """The scalar fields (JSON-ready; ``None`` where not estimated)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)
               if f.name not in ("freqs", "h", "coh", "sxx")}
        return {**out, "ci": None if self.ci is None else list(self.ci)}


def check_band(band: Any, dt: float) -> tuple[float, float]:
    """``band`` as ``(low, high)`` floats in Hz; a ``ValueError`` unless it is two
    numbers with ``0 < low < high <`` the Nyquist frequency of ``dt``."""
    try:
        lo, hi = (float(b) for b in band)
    except (TypeError, ValueError):
        raise ValueError(f"band: expected (low, high) in Hz, got {band!r}") from None
    if not (0 < lo < hi < 0.5 / dt):
        raise ValueError(f"band: need 0 < low < high < {0.5 / dt:g} Hz, got ({lo:g}, {hi:g})")
    return lo, hi


def bandpass(x: np.ndarray, dt: float, band: Sequence[float] = DEFAULT_BAND,
             trim: float = TRIM) -> np.ndarray:
    """``x`` detrended (straight line), band-passed by a zero-phase 2nd-order
    Butterworth filter (forwards and backwards) and with ``trim`` seconds cut at
    each end."""
    from scipy import signal

    lo, hi = check_band(band, dt)
    x = np.asarray(x, dtype=np.float64)
    k = int(round(trim / dt))
    if x.shape[0] <= 2 * k + 20:
        raise ValueError(f"record of {x.shape[0] * dt:g} s is too short for trim {trim:g} s")
    sos = signal.butter(2, [lo * 2 * dt, hi * 2 * dt], btype="bandpass", output="sos")
    y = signal.sosfiltfilt(sos, signal.detrend(x))
    return y[k:x.shape[0] - k] if k else y


def band_weights(lead_v: np.ndarray, dt: float, band: Sequence[float] = DEFAULT_BAND,
                 trim: float = TRIM) -> tuple[np.ndarray, np.ndarray]:
    """The periodogram bins ``f`` (Hz) in ``band`` of the predecessor's speed band-passed
    as the study does (:func:`bandpass`, Hann window) and their power as weights
    summing to 1: a model's band amplification is ``sqrt(sum w |H(f)|^2)``
    (:func:`band_rms_gain`). Empty arrays when the band
    holds no bin or no power."""
    from scipy import signal

    lo, hi = check_band(band, dt)
    f, p = signal.periodogram(bandpass(lead_v, dt, band, trim), fs=1.0 / dt, window="hann",
                              detrend=False)  # fmt: skip
    m = (f >= lo) & (f <= hi)
    if not m.any() or p[m].sum() <= 0:
        return np.zeros(0), np.zeros(0)
    return f[m], p[m] / p[m].sum()


def band_rms_gain(gain: Callable[[np.ndarray], Any], lead_v: np.ndarray, dt: float,
                  band: Sequence[float] = DEFAULT_BAND, trim: float = TRIM) -> float:
    """A transfer's ``|H|`` as an RMS gain on the predecessor's band-passed speed
    spectrum: ``sqrt(sum w |H(f)|^2)`` over the bins and weights of
    :func:`band_weights`, ``gain`` giving ``|H|`` at an array of frequencies (Hz); NaN
    when the band holds no bin or no power. The one computation of a model's band
    amplification (:func:`avll.studies.openacc.predicted_amplification`) and of the
    synthetic truth's band gain (:mod:`avll.synth_platoon`)."""
    f, w = band_weights(lead_v, dt, band, trim)
    if not f.size:
        return math.nan
    h = np.asarray(gain(f), dtype=np.float64)
    return float(np.sqrt(np.sum(h * h * w)))


def welch_effective_averages(k: int, n: int = 0, step: int = 0) -> float:
    """Welch's (1967) equivalent number of independent averages of ``k`` Hann segments of
    ``n`` samples started every ``step`` samples:
    ``k / (1 + 2 sum_j (1 - j/k) rho(j)^2)``, ``rho(j)`` the correlation of two Hann
    windows ``j step`` apart (``n = 0``: half overlap, ``rho(1) = 0.167``)."""
    if k <= 0:
        return 0.0
    if k == 1:
        return 1.0
    if n <= 0 or step <= 0:
        rho = [_HANN_RHO_HALF]
    else:
        from scipy import signal

        w = signal.get_window("hann", n)
        e = float(np.sum(w * w))
        rho = [float(np.sum(w[j * step:] * w[:n - j * step])) / e
               for j in range(1, k) if j * step < n]
    return k / (1.0 + 2.0 * sum((1.0 - j / k) * r * r for j, r in enumerate(rho, start=1)))


def _series(name: str, x: Any) -> np.ndarray:
    if isinstance(x, (str, bytes)) or x is None:
        raise ValueError(f"{name}: expected an array of numbers, got {x!r:.40}")
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: expected an array of numbers ({e})") from None
    if a.ndim != 1:
        raise ValueError(f"{name}: must be 1-D, got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ValueError(f"{name}: not finite at sample {int(bad[0])} ({a[bad[0]]})")
    return a


def _segments(x: np.ndarray, n: int, step: int) -> np.ndarray:
    from scipy import signal

    k = 1 + (x.shape[0] - n) // step
    idx = np.arange(n)[None, :] + step * np.arange(k)[:, None]
    seg = signal.detrend(x[idx], axis=1, type="linear")
    return np.asarray(np.fft.rfft(seg * signal.get_window("hann", n)[None, :], axis=1))


def _lag(res: BandGain, dt: float, max_lag: float) -> int:
    """Samples by which the output lags the input: the slope of H1's unwrapped phase
    over the band (weighted by ``S_xx`` times the coherence), rounded; 0 when the
    slope is not a lag of at most ``max_lag`` s."""
    if res.freqs.size < 2:
        return 0
    ph = np.unwrap(np.angle(res.h))
    w = 2 * np.pi * res.freqs
    wt = np.sqrt(np.maximum(res.sxx * res.coh, 0.0))
    if not np.any(wt > 0):
        return 0
    a = np.vstack([w, np.ones_like(w)]).T * wt[:, None]
    tau = -float(np.linalg.lstsq(a, ph * wt, rcond=None)[0][0])
    if not (math.isfinite(tau) and 0 < tau <= max_lag):
        return 0
    return int(round(tau / dt))


def h1_band_gain(
    lead_v: Any,
    v: Any,
    dt: float,
    band: Sequence[float] = DEFAULT_BAND,
    *,
    segment: float | None = None,
    align: bool = True,
    max_lag: float = MAX_LAG,
    level: float = LEVEL,
    min_excitation: float = MIN_EXCITATION,
) -> BandGain:
    """The H1 transfer-gain estimate of predecessor speed ``lead_v`` -> follower speed
    ``v`` (m/s, sampled every ``dt`` s) over ``band`` (Hz), with its coherence and
    interval (see the module doc). ``segment`` is the Welch segment length in seconds
    (default ``2 / band[0]`` when the record holds :data:`MIN_SEGMENTS` of them, else
    ``1 / band[0]``). With ``align`` (the default) the follower's speed is
    first shifted back by its delay behind the predecessor (the phase slope of a
    first H1 over the band, at most ``max_lag`` s), which removes most of the delay
    bias of a short segment and leaves ``|H|`` unchanged (a pure delay has gain 1);
    ``lag_s`` reports the shift. A record too short for the band (fewer than
    :data:`MIN_SEGMENTS` segments) or a predecessor whose band RMS speed is below
    ``min_excitation`` gives ``gain=None`` with a ``reason``; bad input (non-numbers,
    NaN, different lengths, a band outside ``(0, Nyquist)``) is a ``ValueError``."""
    x = _series("lead_v", lead_v)
    y = _series("v", v)
    if x.shape != y.shape:
        raise ValueError(f"lead_v, v: different lengths ({x.shape[0]} and {y.shape[0]})")
    dt = check_number(dt, "dt", positive=True)
    lo, hi = check_band(band, dt)
    try:
        lvl = float(level)
    except (TypeError, ValueError):
        raise ValueError(f"level: must be a number in (0.5, 1), got {level!r}") from None
    if not (0.5 < lvl < 1):
        raise ValueError(f"level: must be in (0.5, 1), got {level!r}")
    max_lag = check_number(max_lag, "max_lag", nonneg=True)
    if segment is None:  # 2/low when the record holds MIN_SEGMENTS of them, else 1/low
        long_n = int(round(2.0 / lo / dt))
        seg_s = 2.0 / lo if x.shape[0] >= (MIN_SEGMENTS + 1) * (long_n // 2) else 1.0 / lo
    else:
        seg_s = check_number(segment, "segment", positive=True)
    n = int(round(seg_s / dt))
    if n * dt * lo < 1.0 - 1e-6:
        raise ValueError(f"segment: {seg_s:g} s has no bin at the band's low edge "
                         f"{lo:g} Hz (need >= {1 / lo:g} s)")
    res = _h1(x, y, dt, n, lo, hi, lvl, min_excitation)
    if align and res.gain is not None:
        k = _lag(res, dt, max_lag)
        if k > 0:
            shifted = _h1(x[:-k], y[k:], dt, n, lo, hi, lvl, min_excitation)
            if shifted.gain is not None:
                return replace(shifted, lag_s=k * dt)
    return res


def _fine_weights(x: np.ndarray, dt: float, f: np.ndarray, lo: float, hi: float
                  ) -> np.ndarray:
    """Weights of the Welch bins ``f`` such that ``sum_k W_k |H1(f_k)|^2`` is
    ``sum_j |H1(f_j)|^2 P(f_j) / sum_j P(f_j)`` over the band's bins ``f_j`` of ``P``, the
    periodogram (Hann) of the whole record of the predecessor's speed band-passed as
    the study does (:func:`bandpass`), ``|H1|^2`` interpolated
    linearly between the Welch bins: exactly the weighting
    :func:`avll.studies.openacc.predicted_amplification` gives a model's ``|H|``."""
    from scipy import signal

    try:
        xb = bandpass(x, dt, (lo, hi))
    except ValueError:  # too short for the study's trim: the band-pass without it
        xb = bandpass(x, dt, (lo, hi), trim=0.0)
    fj, pj = signal.periodogram(xb, fs=1.0 / dt, window="hann", detrend=False)
    m = (fj >= lo) & (fj <= hi)
    fj, pj = fj[m], pj[m]
    if not fj.size or pj.sum() <= 0 or f.size < 2:
        return np.full(f.size, 1.0 / max(f.size, 1))
    w = np.array([np.sum(pj * np.interp(fj, f, np.eye(f.size)[k])) for k in range(f.size)])
    return w / np.sum(w)


def _h1(x: np.ndarray, y: np.ndarray, dt: float, n: int, lo: float, hi: float,
        level: float, min_excitation: float) -> BandGain:
    step = n // 2
    m = x.shape[0]
    k = 1 + (m - n) // step if m >= n else 0
    if k < MIN_SEGMENTS and m >= n + (MIN_SEGMENTS - 1) * int(math.ceil(0.4 * n)):
        # a record just short of MIN_SEGMENTS half-overlapping segments (e.g. 99.9 s for
        # 50 s segments): overlap them a little more (at most 60 %)
        step = (m - n) // (MIN_SEGMENTS - 1)
        k = 1 + (m - n) // step
    empty: dict[str, Any] = dict(n_segments=k, n_effective=welch_effective_averages(k, n, step),
                                 segment_s=n * dt)
    if k < MIN_SEGMENTS:
        need = (n + (MIN_SEGMENTS - 1) * int(math.ceil(0.4 * n))) * dt
        return BandGain(None, None, None, excitation=None, reason=(
            f"record of {m * dt:g} s gives {k} Welch segment(s) of {n * dt:g} s "
            f"(needs >= {MIN_SEGMENTS}, i.e. >= {need:g} s, to resolve the band's low edge "
            f"{lo:g} Hz with averaging)"), ci_reason="no estimate", **empty)
    fx, fy = _segments(x, n, step), _segments(y, n, step)
    f = np.fft.rfftfreq(n, dt)
    sel = (f >= lo - 1e-9) & (f <= hi + 1e-9)
    fx, fy, f = fx[:, sel], fy[:, sel], f[sel]
    sxx = np.mean(np.abs(fx) ** 2, axis=0)
    syy = np.mean(np.abs(fy) ** 2, axis=0)
    sxy = np.mean(np.conj(fx) * fy, axis=0)
    # The predecessor's band RMS speed (Parseval on the Welch estimate; Hann power).
    from scipy import signal

    w = signal.get_window("hann", n)
    excitation = float(np.sqrt(np.sum(sxx) * 2.0 / (n * np.sum(w * w)))) if sxx.size else 0.0
    ok = sxx > 0
    if not ok.any() or excitation < min_excitation:
        return BandGain(None, None, None, excitation=excitation, reason=(
            f"the predecessor does not excite: its band RMS speed is {excitation:.3f} m/s < "
            f"{min_excitation:g} m/s"), ci_reason="no estimate", **empty)
    h = np.where(ok, sxy / np.where(ok, sxx, 1.0), 0.0)
    coh = np.where(ok & (syy > 0), np.abs(sxy) ** 2 / np.where(ok & (syy > 0), sxx * syy, 1.0),
                   0.0)
    wts = _fine_weights(x, dt, f, lo, hi)
    h2 = np.abs(h) ** 2
    g2 = float(np.sum(wts * h2))
    gain = math.sqrt(g2)
    nd = welch_effective_averages(k, n, step)
    ci: tuple[float, float] | None = None
    ci_reason = "the band gain is 0" if g2 <= 0 else None
    if g2 > 0:
        c = np.clip(coh, 1e-6, 1.0)
        # var |H|^2 = 4 |H|^2 var|H| = 2 |H|^4 (1 - g) / (nd g)
        sd = np.sqrt(2.0 * h2 * h2 * (1.0 - c) / (nd * c)) * wts
        var = float(np.sum(sd * sd))
        for j in (1, 2):
            if sd.size > j:
                var += 2.0 * _HANN_BIN_CORR[j] * float(np.sum(sd[:-j] * sd[j:]))
        s_log = math.sqrt(max(var, 0.0)) / (2.0 * g2)
        from scipy.stats import norm

        z = float(norm.ppf(0.5 + 0.5 * float(level)))
        ci = (gain * math.exp(-z * s_log), gain * math.exp(z * s_log))
    return BandGain(gain, ci, float(np.sum(wts * coh)), excitation=excitation, ci_reason=ci_reason,
                    freqs=f, h=h, coh=coh, sxx=sxx, **empty)
