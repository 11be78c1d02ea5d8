"""Statistics of autocorrelated residuals: the effective sample size, binned
dependence on a signal (one-way ANOVA with effective sample sizes), the one-sided
test of a per-sample loss difference, and a moving-block bootstrap.

Residuals of a lower-level model sampled at 10-20 Hz are far from independent:
with the raw sample count every small structure would be "significant". Every test
here uses the effective sample size ``n_eff = n / (1 + 2 sum rho_k)`` (Geyer's
initial positive sequence on the pooled autocorrelation) or resamples whole blocks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy import stats

from ..defaults import LEVEL
from .defaults import N_BOOT

__all__ = [
    "SignalDependence",
    "LossTest",
    "BootstrapGain",
    "effective_sample_size",
    "binned_dependence",
    "loss_difference_test",
    "block_bootstrap_gain",
]


@dataclass(frozen=True)
class LossTest:
    """The one-sided test of :func:`loss_difference_test`: the pooled ``gain = 1 -
    mse_after / mse_before``, the t statistic with the effective sample size ``n_eff``
    of the loss difference (``n`` samples) and its p-value."""

    gain: float
    mse_before: float
    mse_after: float
    t: float
    n: float
    n_eff: float
    p_value: float


@dataclass(frozen=True)
class BootstrapGain:
    """The moving-block bootstrap of :func:`block_bootstrap_gain`: the pooled gain, its
    interval ``ci`` (low, high), the one-sided p-value of "no reduction", the block
    length and the number of replicates."""

    gain: float
    ci: tuple[float, float]
    p_value: float
    block_length: int
    n_boot: int


@dataclass(frozen=True)
class SignalDependence:
    """Residual binned against one candidate signal (means with 95 % bands that use
    the effective sample size of each bin)."""

    signal: str
    centers: np.ndarray
    means: np.ndarray
    half_width: np.ndarray
    counts: np.ndarray
    explained: float
    p_value: float

    def to_dict(self, *, bins: bool = False) -> dict[str, Any]:
        """``{"signal", "explained", "p_value"}`` and, with ``bins``, the bin
        centres, means, 95 % half-widths and counts."""
        out: dict[str, Any] = {"signal": self.signal, "explained": self.explained,
                               "p_value": self.p_value}  # fmt: skip
        if bins:
            out.update(centers=self.centers.tolist(), means=self.means.tolist(),
                       half_width=self.half_width.tolist(), counts=self.counts.tolist())
        return out


def _lag1(res: list[np.ndarray]) -> float:
    num = sum(float(np.dot(r[1:], r[:-1])) for r in res)
    den = sum(float(np.dot(r, r)) for r in res)
    return float(np.clip(num / den, -0.99, 0.999)) if den > 0 else 0.0


def _ess(res: Sequence[np.ndarray]) -> float:
    """Effective sample size of autocorrelated residuals, ``n / (1 + 2 sum rho_k)``,
    with the pooled autocorrelation summed by Geyer's initial positive sequence
    (pairs ``rho_2m + rho_2m+1`` while positive) — the standard estimator for
    correlated samples; residuals at 10-20 Hz are far from independent."""
    n = sum(len(r) for r in res)
    maxlag = int(min(min(len(r) for r in res) // 2, 4000))
    if maxlag < 2:
        return float(n)
    acov = np.zeros(maxlag + 1)
    for r in res:
        x = r - r.mean()
        m = 1 << int(np.ceil(np.log2(2 * x.size)))
        f = np.fft.rfft(x, m)
        acov += np.fft.irfft(f * np.conj(f), m)[: maxlag + 1]
    if acov[0] <= 0:
        return float(n)
    rho = acov / acov[0]
    total = 0.0  # 1 + 2 sum_{k>=1} rho_k = -1 + 2 sum_m Gamma_m
    for m in range(maxlag // 2):
        g = rho[2 * m] + rho[2 * m + 1]
        if g <= 0:
            break
        total += g
    tau = max(2 * total - 1.0, 1.0)
    return max(float(n) / tau, 10.0)


def effective_sample_size(res: Sequence[np.ndarray]) -> float:
    """The effective sample size of the pooled series ``res`` (one array per run):
    see :func:`_ess`."""
    return _ess([np.asarray(r, dtype=np.float64) for r in res])


def _binned(x: np.ndarray, e: np.ndarray, cuts: np.ndarray, nbins: int = 10) -> SignalDependence:
    uniq = np.unique(x)
    if uniq.size <= 3:
        edges = np.concatenate([[uniq[0] - 0.5], (uniq[1:] + uniq[:-1]) / 2, [uniq[-1] + 0.5]])
    else:
        edges = np.unique(np.quantile(x, np.linspace(0, 1, nbins + 1)))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    k = edges.size - 1
    centers, means, hw, counts = (np.zeros(k) for _ in range(4))
    for b in range(k):
        m = idx == b
        if m.any():
            means[b] = float(np.mean(e[m]))
    # Effective sample size of the residual under the alternative (bin means removed).
    ratio = _ess(np.split(e - means[idx], cuts)) / e.size
    for b in range(k):
        m = idx == b
        counts[b] = m.sum()
        if counts[b] == 0:
            centers[b] = means[b] = np.nan
            continue
        centers[b] = float(np.mean(x[m]))
        ne = max(counts[b] * ratio, 2.0)
        hw[b] = 1.96 * float(np.std(e[m])) / math.sqrt(ne)
    # One-way ANOVA of the bins with effective sample sizes.
    ok = counts > 0
    ss_between = float(np.sum(counts[ok] * (means[ok] - e.mean()) ** 2))
    ss_tot = float(np.sum((e - e.mean()) ** 2))
    explained = ss_between / ss_tot if ss_tot > 0 else 0.0
    n_eff = max(e.size * ratio, 10.0)
    kk = int(ok.sum())
    if kk > 1 and ss_tot > ss_between:
        F = (explained / (kk - 1)) / ((1 - explained) / max(n_eff - kk, 1))
        p = float(stats.f.sf(F, kk - 1, max(n_eff - kk, 1)))
    else:
        p = 1.0
    return SignalDependence("", centers, means, hw, counts, explained, p)


def binned_dependence(
    signal: str, x: np.ndarray, e: np.ndarray, lengths: Sequence[int], nbins: int = 10
) -> SignalDependence:
    """The residual ``e`` binned against ``x`` (both concatenated over runs of
    ``lengths`` samples): bin means with 95 % bands, the share of the residual's
    variance the bin means explain and the one-way ANOVA p-value, both with the
    effective sample size of the residual with the bin means removed."""
    cuts = np.cumsum(list(lengths))[:-1]
    d = _binned(np.asarray(x, dtype=np.float64), np.asarray(e, dtype=np.float64), cuts, nbins)
    return replace(d, signal=signal)


def loss_difference_test(
    before: Sequence[np.ndarray], after: Sequence[np.ndarray]
) -> LossTest:
    """One-sided test that the squared error falls from ``before`` to ``after``
    (residual series, one array per held-out run or block): the per-sample loss
    difference ``d = e_before² - e_after²`` has mean ``> 0``. The t statistic uses
    the effective sample size of ``d`` (its own autocorrelation), not ``n``.

    ``gain = 1 - mse_after/mse_before`` is pooled over samples."""
    b = [np.asarray(x, dtype=np.float64) for x in before]
    a = [np.asarray(x, dtype=np.float64) for x in after]
    d = [x * x - y * y for x, y in zip(b, a, strict=True)]
    dd = np.concatenate(d)
    n = dd.size
    m0 = float(np.mean(np.concatenate(b) ** 2))
    m1 = float(np.mean(np.concatenate(a) ** 2))
    gain = 1.0 - m1 / m0 if m0 > 0 else 0.0
    if not (np.all(np.isfinite(dd)) and n > 2):
        return LossTest(gain if math.isfinite(gain) else -math.inf, m0, m1, -math.inf,
                        float(n), float(n), 1.0)  # fmt: skip
    n_eff = _ess(d)
    sd = float(np.std(dd, ddof=1))
    mean = float(np.mean(dd))
    if sd == 0:
        t = math.inf if mean > 0 else (-math.inf if mean < 0 else 0.0)
    else:
        t = mean / (sd / math.sqrt(n_eff))
    p = float(stats.t.sf(t, df=max(n_eff - 1.0, 1.0)))
    return LossTest(gain, m0, m1, t, float(n), n_eff, p)


def block_bootstrap_gain(
    before: Sequence[np.ndarray],
    after: Sequence[np.ndarray],
    *,
    n_boot: int = N_BOOT,
    seed: int = 0,
    level: float = LEVEL,
) -> BootstrapGain:
    """A moving-block bootstrap of the pooled relative MSE reduction
    ``gain = 1 - sum e_after² / sum e_before²`` (residual series, one array per
    held-out run or block). Each series is rebuilt from blocks of ``L`` consecutive
    samples drawn with replacement within that series (the same blocks for both
    errors), ``L = 2 n / n_eff`` — twice the integrated autocorrelation time of the
    loss difference, at least 1, at most a quarter of the shortest series.

    ``ci`` is the interval at ``level``; ``p_value = (1 + #{replicates with gain <= 0})
    / (n_boot + 1)`` the one-sided bootstrap p-value of "no reduction". Deterministic
    from ``seed``."""
    b = [np.asarray(x, dtype=np.float64) ** 2 for x in before]
    a = [np.asarray(x, dtype=np.float64) ** 2 for x in after]
    d = [x - y for x, y in zip(b, a, strict=True)]
    shortest = min(x.size for x in d)
    s0 = float(sum(x.sum() for x in b))
    gain = float(sum(x.sum() for x in d)) / s0 if s0 > 0 else 0.0
    bad = BootstrapGain(gain if math.isfinite(gain) else -math.inf, (-math.inf, math.inf), 1.0,
                        1, int(n_boot))  # fmt: skip
    if not all(np.all(np.isfinite(x)) for x in d) or shortest < 4 or s0 <= 0:
        return bad
    n = sum(x.size for x in d)
    n_eff = _ess(d)
    L = int(np.clip(math.ceil(2.0 * n / n_eff), 1, max(shortest // 4, 1)))
    rng = np.random.default_rng(seed)
    num = np.zeros(n_boot)
    den = np.zeros(n_boot)
    for x0, x1 in zip(b, a, strict=True):
        m = x0.size
        nb = -(-m // L)
        # Block sums over every start position (prefix sums), then draw the starts.
        c0 = np.concatenate([[0.0], np.cumsum(x0)])
        c1 = np.concatenate([[0.0], np.cumsum(x1)])
        bs0 = c0[L:] - c0[:-L]
        bs1 = c1[L:] - c1[:-L]
        starts = rng.integers(0, m - L + 1, size=(n_boot, nb))
        num += (bs0[starts] - bs1[starts]).sum(axis=1)
        den += bs0[starts].sum(axis=1)
    g = num / np.where(den > 0, den, np.nan)
    g = np.where(np.isfinite(g), g, -np.inf)
    q = (1.0 - level) / 2.0
    p = (1.0 + float(np.sum(g <= 0))) / (n_boot + 1.0)
    return BootstrapGain(gain, (float(np.quantile(g, q)), float(np.quantile(g, 1.0 - q))), p,
                         L, int(n_boot))  # fmt: skip


def _lstsq(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    if X.shape[1] == 0:
        return np.zeros(0), float(y @ y)
    sc = np.linalg.norm(X, axis=0)
    sc[sc == 0] = 1.0
    beta, *_ = np.linalg.lstsq(X / sc, y, rcond=None)
    beta = beta / sc
    r = y - X @ beta
    return beta, float(r @ r)
