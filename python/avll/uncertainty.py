"""How sure a calibration is: intervals, correlations and identifiability from a
block bootstrap over time, refit from the full-data optimum.

:func:`avll.calibrate` with ``intervals=True`` (or an :class:`Intervals`) runs this
second stage after the GA and fills :attr:`avll.CalibrationResult.uncertainty` (an
:class:`Uncertainty`) and :attr:`avll.CalibrationResult.intervals`.

**Resampling (serial correlation).** Residuals at 10 Hz are strongly correlated, so
i.i.d. covariances (or resampling samples) give intervals far too narrow. Each run is
cut into *atoms* of a quarter block; a resample is a moving-block bootstrap within
each run (``ceil(atoms / 4)`` blocks of four consecutive atoms, starting at uniformly
drawn atoms, circularly), i.e. a vector of atom multiplicities. One rollout of a
candidate parameter set gives the squared-error sum of every atom, so a resample's
Eq. 6 cost is a weighted sum of those (no data copied; see
``rust/optimize/resample.rs``). ``method="runs"`` resamples whole runs instead (each
atom gets its run's multiplicity): the former run bootstrap, useful when the
problem has many runs and the runs, not the seconds, are the independent units.

**Block length from the data.** The Politis-White (2004) automatic block length for
the circular bootstrap of the mean (flat-top lag window, with the Patton, Politis and
White 2009 correction), computed on the full-data fit's *score series* (per run and
fitted parameter, the weighted residuals of the channels times their sensitivities
to the parameter: the terms whose sum is the cost's gradient, whose resampled sums
move the refits; the bandwidth of a sandwich variance is chosen on the estimating
equations, not on the residuals); the largest, times :data:`BLOCK_FACTOR`, is used,
not below :data:`MIN_BLOCK` seconds (a floor: below a few seconds the lower level's own
response correlates the errors) and not above a third of the shortest run (at least
three blocks per run). Politis-White's length minimises the mean squared error of the
*variance* estimate; an interval's coverage error is dominated by that estimate's
downward bias (of order ``1 / b``, Lahiri 2003, ch. 7), so intervals want longer
blocks. :data:`BLOCK_FACTOR` was chosen on the development seeds of the synthetic
platoons (7301-7308) among 1, 1.25, 1.5 and 2, as the smallest whose standardised errors
of ``Tg + Gmin / v̄`` have a standard deviation of one (the table is generated into
``docs/_generated/intervals.md``; ``Intervals(block_factor=...)``); the final check is on
fresh seeds (the same page).

**Polish.** The GA's optimum is first refit on the full data by the same local search
(``Intervals(polish=True)``, the default): the resamples should start from a local
minimum of the full-data cost, or their refits travel from one side of it to their
own minima. The calibration's estimate and cost become the polished ones (the GA's
are kept in :attr:`Uncertainty.cost_given`), and the score series and the resamples
start there. In closed loop a locally unstable loop costs ``inf`` (the exact test with
the true delay; with effects the certified test at the run's mean predecessor speed),
so neither the polish nor the refits can carry a locally stable optimum across the
edge of local stability: the car followed its predecessor through the record, and a
cost that prefers a slowly diverging loop fits the record's length, not the car.

**Refits.** Each resample is refit in the GA's unit coordinates (log scale for the
positive coefficients), warm-started from the full-data optimum, by a bounded
Levenberg-Marquardt iteration on its weighted residuals (``Intervals(refit="lm")``, the
default) or by the GA's bounded Nelder-Mead (``refit="simplex"``). A
Levenberg-Marquardt refit takes at most :data:`LM_BUDGET_PER_PARAM` ``d`` rollouts
(``d`` parameters; :attr:`Intervals.budget` sets another cap): a *k-step bootstrap*
(Andrews 2002, Econometrica 70: a fixed number of Newton-type steps from the full-data
optimum gives the full bootstrap's accuracy, with blocks of dependent data too).
Chosen on the development seeds of the synthetic platoons: the intervals hold the
truth as often as with refits run to convergence, at a fraction of their rollouts;
all resamples in parallel in Rust, one after the other problem, seeded (the
multiplicities are drawn from ``numpy.random.default_rng([seed, problem])``: the same
result for any thread count), with progress and Ctrl-C.

**Small-sample correction.** The refits are fitted to resamples of the *fitted*
residuals, which a fit of ``p`` parameters to a record of only ``G`` effective blocks
(record length over block length; runs when whole runs are resampled) has made
smaller than the errors, and the spread itself is estimated from few pieces: the
plain percentile intervals are far too narrow. With ``correction="dof"`` (the
default) each quantity's resampled deviations from its estimate are widened by
:func:`small_sample_scale` ``= sqrt(G / (G - p)) t_{G-p} / z`` (the average-leverage
degrees-of-freedom correction of a cluster-robust variance and Student's quantile):
the parameters' in the GA's unit coordinates, clipped to the box
(:attr:`Uncertainty.samples`, from which the correlations and the probability of string
stability come; :attr:`Uncertainty.refits` are the refits themselves), and every
combination's and the band amplification's in its own units, from the refits' values
(:func:`widen_values`). Widening the parameters first and combining the widened ones
made a combination's interval depend on how far the refits had travelled along the
directions the data do not determine (the box clips one of two parameters that trade
off, the maps are not linear): on the same resamples, two refit rules that reach the
same values of ``Tg + Gmin / v̄`` gave intervals of markedly different widths. A
record with ``G - p < 1`` determines nothing: its samples are NaN and every interval
``undetermined``.

**What the data determine.** Symmetric intervals at ``level`` of the (widened)
samples about the estimate (:func:`symmetric_interval`, Hall 1988; the parameters'
in unit coordinates, clipped to the box): on the development seeds the equal-tailed
percentile interval left the estimate out where the refits drift to one side of it,
and with it the truth beside the estimate. ``Tg + Gmin / v̄`` has no interval when the
fit's gap loop is slower than the record (:meth:`Uncertainty.gap_loop_too_slow`: ``kg``
or the lower level's DC gain at zero, where the equilibrium gap is not determined).
Correlations of the resampled parameters in the unit coordinates; a verdict per
parameter (:meth:`Uncertainty.identified`): *identified* when the interval covers at most
:data:`MAX_BOX_SHARE` of the search box in unit coordinates and neither the estimate
nor the interval reaches a bound (within :data:`BOUND_TOL` of the box in unit
coordinates). A parameter whose interval reaches a bound is determined on one side
only (the box, not the data, closes it); one spanning a large share of the box trades
off with others. Neither is printed as a finding. The identified combinations,
computed from every resample (of the base model's linear part when the model carries
effects): the effective time gap ``Tg + Gmin / v̄`` (closed loop),
the lower level's DC gain ``K0 / (1 - K K0)``, its low-frequency delay (the group delay
of ``G / (1 - K G)`` at ``ω -> 0``: ``(a1 - b1 / b0 + Td) / (1 - K b0)``), and, given a
predecessor's speed, the band amplification (``|H|`` of the calibrated closed loop with
the true delay on the predecessor's band-passed spectrum) and the probability of string
stability (the share of resamples whose closed loop is string stable by the exact
test with the true delay; a locally unstable resample counts as not string stable and
is counted apart). A combination is identified by the same width rule relative to
its estimate (:data:`MAX_REL_WIDTH`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from . import _core, _sigint
from ._limits import check_int, check_seed, check_threads
from .defaults import AT_BOUND_TOL, LEVEL
from .report import finite_or_none

__all__ = [
    "Intervals",
    "Uncertainty",
    "block_length",
    "MIN_BLOCK",
    "MAX_BOX_SHARE",
    "MAX_REL_WIDTH",
    "BOUND_TOL",
    "ATOMS_PER_BLOCK",
    "CORRECTIONS",
    "REFITS",
    "small_sample_scale",
    "widen",
    "widen_values",
    "symmetric_interval",
    "LM_BUDGET_PER_PARAM",
    "BLOCK_FACTOR",
    "to_dataset",
]

#: Floor of the block length (s).
MIN_BLOCK = 5.0
#: The block length is the Politis-White length times this (see the module doc).
BLOCK_FACTOR = 1.25
#: Atoms per block (a block starts on an atom boundary).
ATOMS_PER_BLOCK = 4
#: A parameter whose interval spans more than this share of its search box (unit
#: coordinates) is not identified.
MAX_BOX_SHARE = 0.25
#: A combination whose interval is wider than this share of its estimate is not
#: identified.
MAX_REL_WIDTH = 0.5
#: Distance (unit coordinates) within which a value counts as at its bound.
BOUND_TOL = AT_BOUND_TOL
#: Correlations at least this large (absolute) are listed in the report.
MIN_CORREL = 0.5
#: Rollouts per fitted parameter of a Levenberg-Marquardt refit when
#: :attr:`Intervals.budget` is 0 (the polish and simplex refits keep Rust's ``200 d``):
#: a k-step bootstrap (Andrews 2002), see the module doc.
LM_BUDGET_PER_PARAM = 10
_METHODS = ("blocks", "runs")
#: The corrections of the resampled deviations (:class:`Intervals`): ``"dof"`` the
#: small-sample correction (:func:`small_sample_scale`), ``"none"`` the plain
#: percentile bootstrap.
CORRECTIONS = ("dof", "none")
#: How each resample is refit (:class:`Intervals`).
REFITS = ("simplex", "lm")


@dataclass(frozen=True)
class Intervals:
    """Options of the uncertainty stage of :func:`avll.calibrate`.

    ``n`` resamples; ``level`` of the symmetric intervals; ``block`` the block length
    in seconds (``None``: ``block_factor`` times the Politis-White length of the
    fit's score series, :func:`block_length`; see the module doc); ``method``
    ``"blocks"`` (moving blocks over time within each run) or ``"runs"`` (whole runs);
    ``budget`` rollouts per refit at most (0: :data:`LM_BUDGET_PER_PARAM` ``d`` for
    ``"lm"`` refits, ``200 d`` for ``"simplex"`` ones and for the polish; a refit stops
    earlier when its cost stalls); ``step`` the initial simplex step in unit coordinates
    (simplex refits); ``seed`` of the multiplicities (``None``: the calibration's); ``correction``
    ``"dof"`` (the resampled deviations widened for the parameters fitted on few
    effective blocks, :func:`small_sample_scale`) or ``"none"`` (the plain percentile
    bootstrap, known to be too narrow here); ``polish`` refits the GA's optimum on the
    full data first, with the resamples' local search, so that they start from a local
    minimum (the calibration then reports the polished estimate); ``ftol`` stops a refit
    (and the polish) when its last step gained at most that share of its cost; ``refit``
    how each resample is refit from the full-data optimum: ``"lm"`` (the default:
    bounded Levenberg-Marquardt on the resample's weighted residuals, Broyden updates
    of the Jacobian between finite-difference ones) or ``"simplex"`` (the GA's bounded
    Nelder-Mead); the two reach the same minima, the first in a fraction of the
    rollouts (compared in ``docs/guide/intervals.md``).
    """

    n: int = 200
    level: float = LEVEL
    block: float | None = None
    block_factor: float = BLOCK_FACTOR
    method: str = "blocks"
    budget: int = 0
    step: float = 0.05
    seed: int | None = None
    correction: str = "dof"
    refit: str = "lm"
    polish: bool = True
    ftol: float = 1e-9

    def __post_init__(self) -> None:
        check_int(self.n, "n", min=2)
        lv = self.level
        if isinstance(lv, bool) or not isinstance(lv, (int, float)) or not 0 < lv < 1:
            raise ValueError(f"level: must be in (0, 1), got {lv!r}")
        if self.block is not None and not (isinstance(self.block, (int, float))
                                           and math.isfinite(self.block) and self.block > 0):
            raise ValueError(f"block: must be a number of seconds > 0 or None, got "
                             f"{self.block!r}")
        bf = self.block_factor
        if isinstance(bf, bool) or not isinstance(bf, (int, float)) or not (
                math.isfinite(bf) and bf > 0):
            raise ValueError(f"block_factor: must be a number > 0, got {bf!r}")
        for name, choices in (("method", _METHODS), ("correction", CORRECTIONS),
                              ("refit", REFITS)):
            if getattr(self, name) not in choices:
                raise ValueError(f"{name}: must be one of {', '.join(choices)}, got "
                                 f"{getattr(self, name)!r}")
        check_int(self.budget, "budget", min=0)
        if not (isinstance(self.ftol, (int, float)) and not isinstance(self.ftol, bool)
                and 0 <= self.ftol < 1):
            raise ValueError(f"ftol: must be in [0, 1), got {self.ftol!r}")
        if not isinstance(self.polish, bool):
            raise TypeError(f"polish: must be True or False, got {self.polish!r}")
        if not (isinstance(self.step, (int, float)) and 0 < self.step <= 0.5):
            raise ValueError(f"step: must be in (0, 0.5], got {self.step!r}")
        if self.seed is not None:
            check_seed(self.seed)

    @classmethod
    def of(cls, value: Any) -> Intervals | None:
        """``value`` as options: ``None``/``False`` (no intervals), ``True`` (the
        defaults), an :class:`Intervals`, or a dict of its fields."""
        if value is None or value is False:
            return None
        if value is True:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, Mapping):
            return cls(**value)
        raise TypeError(f"intervals: expected True, False, None, avll.Intervals or a dict, "
                        f"got {value!r:.60}")


def block_length(residuals: Sequence[np.ndarray], dt: float, floor: float = MIN_BLOCK,
                 cap: float | None = None, factor: float = 1.0) -> float:
    """The block length (s) of a block bootstrap for serially correlated
    ``residuals`` (one or more series sampled every ``dt``): ``factor`` times the largest
    Politis-White (2004) automatic block length of the circular bootstrap over the series
    (with the Patton-Politis-White 2009 correction), at least ``floor``, at most ``cap``
    (the intervals use ``factor`` :data:`BLOCK_FACTOR`)."""
    best = 0.0
    for e in residuals:
        e = np.asarray(e, dtype=np.float64)
        e = e[np.isfinite(e)]
        if e.size < 16 or not np.any(e != e[0]):
            continue
        best = max(best, _politis_white(e))
    b = max(factor * (best * dt), float(floor))
    if cap is not None:
        b = min(b, max(float(cap), dt))
    return float(b)


def _politis_white(x: np.ndarray) -> float:
    """Politis-White optimal block length (samples) of the circular bootstrap."""
    n = x.size
    x = x - x.mean()
    kn = max(5, int(math.ceil(math.sqrt(math.log10(n)))))
    mmax = min(int(math.ceil(math.sqrt(n))) + kn, n - 1)
    # the autocovariances up to mmax by FFT
    f = np.fft.rfft(x, 2 * n)
    acov = np.fft.irfft(f * np.conj(f))[: mmax + 1] / n
    rho = acov / acov[0]
    c = 2.0 * math.sqrt(math.log10(n) / n)
    mhat = mmax
    for m in range(1, mmax - kn + 1):
        if np.all(np.abs(rho[m : m + kn]) < c):
            mhat = m
            break
    big_m = min(2 * mhat, mmax)
    k = np.arange(-big_m, big_m + 1)
    lam = np.clip(2.0 - 2.0 * np.abs(k) / big_m, 0.0, 1.0) if big_m > 0 else np.ones(1)
    r = acov[np.abs(k)]
    g = float(np.sum(lam * np.abs(k) * r))
    s0 = float(np.sum(lam * r))
    d_cb = (4.0 / 3.0) * s0 * s0
    if d_cb <= 0 or g == 0:
        return 1.0
    return float((2.0 * g * g / d_cb) ** (1.0 / 3.0) * n ** (1.0 / 3.0))


def _unit(x: np.ndarray, lo: float, hi: float, scale: str) -> np.ndarray:
    """Values in the GA's unit coordinates of the box ``[lo, hi]``."""
    if hi == lo:
        return np.zeros_like(x)
    if scale == "log":
        return np.log(np.clip(x, lo, hi) / lo) / math.log(hi / lo)
    return (np.clip(x, lo, hi) - lo) / (hi - lo)


def _from_unit(z: np.ndarray, lo: float, hi: float, scale: str) -> np.ndarray:
    """Values of the unit coordinates ``z`` of the box ``[lo, hi]`` (inverse of
    :func:`_unit` inside the box)."""
    if hi == lo:
        return np.full_like(z, lo)
    if scale == "log":
        return np.asarray(lo * (hi / lo) ** z)
    return np.asarray(lo + z * (hi - lo))


def small_sample_scale(blocks: float, params: int, level: float = LEVEL) -> float:
    """The factor by which the resampled deviations from the estimate are widened:
    ``sqrt(G / (G - p)) * t_{G-p}(q) / z(q)``, ``q = (1 + level) / 2``, for ``G``
    effective independent ``blocks`` (record length over block length, or the number
    of runs when whole runs are resampled) and ``p`` fitted ``params``.

    The first factor is the degrees-of-freedom correction of a residual-based
    variance (the cluster-robust CR2 correction with the average leverage ``p / G``
    of a block): the fit absorbs ``p`` of the ``G`` independent pieces of the errors,
    so the fitted residuals, which the bootstrap resamples, are smaller than the
    errors by ``(G - p) / G`` in variance. The second replaces the normal quantile by
    Student's with ``G - p`` degrees of freedom (the variance itself is estimated from
    ``G - p`` pieces). ``inf`` when ``G - p < 1``: fewer effective blocks than
    parameters determine nothing (the resamples become NaN and every interval
    ``undetermined``)."""
    from scipy import stats

    if not (math.isfinite(blocks) and blocks > 0):
        raise ValueError(f"blocks: must be a number > 0, got {blocks!r}")
    check_int(params, "params", min=0)
    if not 0 < level < 1:
        raise ValueError(f"level: must be in (0, 1), got {level!r}")
    nu = blocks - params
    if nu < 1:
        return math.inf
    q = 0.5 * (1.0 + level)
    return float(math.sqrt(blocks / nu) * stats.t.ppf(q, nu) / stats.norm.ppf(q))


def widen(samples: np.ndarray, estimate: np.ndarray,
          bounds: Sequence[tuple[float, float, str]], factor: float) -> np.ndarray:
    """``samples`` (n, d) with their deviations from ``estimate`` (d) multiplied by
    ``factor`` in the GA's unit coordinates of the box ``bounds`` (per column
    ``(lo, hi, scale)``), clipped to the box. ``factor = inf`` (no degrees of freedom
    left) gives NaN everywhere but in the fixed columns: nothing is determined."""
    x = np.asarray(samples, dtype=np.float64)
    out = x.copy()
    if not factor >= 1.0:
        raise ValueError(f"factor: must be >= 1, got {factor!r}")
    for j, (lo, hi, sc) in enumerate(bounds):
        if hi == lo:
            continue
        if math.isinf(factor):
            out[:, j] = np.nan
            continue
        z0 = float(_unit(np.array([estimate[j]], dtype=np.float64), lo, hi, sc)[0])
        zw = z0 + factor * (_unit(x[:, j], lo, hi, sc) - z0)
        out[:, j] = _from_unit(np.clip(zw, 0.0, 1.0), lo, hi, sc)
        out[~np.isfinite(x[:, j]), j] = np.nan
    return out


def symmetric_interval(estimate: float, samples: np.ndarray, level: float
                       ) -> tuple[float, float]:
    """The symmetric bootstrap interval at ``level`` (Hall 1988): ``estimate ± q``,
    ``q`` the ``level`` quantile of the finite samples' absolute deviations from the
    estimate. Unlike the equal-tailed percentile interval it always holds the estimate:
    where the refits drift to one side of it (a box, a curved valley), the percentile
    interval can leave out the estimate and the truth beside it. NaN when there is no
    finite sample or no finite estimate."""
    v = np.asarray(samples, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0 or not math.isfinite(estimate):
        return (math.nan, math.nan)
    q = float(np.quantile(np.abs(v - estimate), level))
    return (float(estimate - q), float(estimate + q))


def widen_values(estimate: float, values: np.ndarray, factor: float) -> np.ndarray:
    """A derived quantity's resampled ``values`` with their deviations from its
    full-data ``estimate`` multiplied by ``factor`` in the quantity's own units: the
    small-sample correction (:func:`small_sample_scale`) of a combination or of the
    band amplification. ``factor = inf`` (no degrees of freedom left) or a non-finite
    estimate gives NaN everywhere."""
    v = np.asarray(values, dtype=np.float64)
    if not factor >= 1.0:
        raise ValueError(f"factor: must be >= 1, got {factor!r}")
    if math.isinf(factor) or not math.isfinite(estimate):
        return np.full(v.shape, np.nan)
    return np.asarray(estimate + factor * (v - estimate))


def _linear_columns(cls: Any, x: np.ndarray) -> dict[str, np.ndarray]:
    """The common linear form's coefficients (``b1, b0, a2, a1, Td, K``) of every row
    of ``x`` (the model's parameters), vectorised: the model's own ``linear()`` on an
    instance whose fields are the parameter columns (built without the scalar checks)."""
    m = object.__new__(cls)
    for j, name in enumerate(cls.param_names()):
        object.__setattr__(m, name, x[:, j])
    return {k: np.broadcast_to(np.asarray(v, dtype=np.float64), (x.shape[0],)).copy()
            for k, v in m.linear().items()}


def _lower_combinations(cls: Any, x: np.ndarray) -> dict[str, np.ndarray]:
    """:func:`dc_gain` and :func:`low_frequency_delay` of every row of ``x`` (the
    model's parameters first)."""
    lin = _linear_columns(cls, x[:, :len(cls.param_names())])
    return {"dc_gain": dc_gain(lin), "low_frequency_delay": low_frequency_delay(lin)}


def dc_gain(lin: Mapping[str, np.ndarray]) -> np.ndarray:
    """Static gain ``b0 / (1 - K b0)`` of the lower level."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(lin["b0"] / (1.0 - lin["K"] * lin["b0"]))


def low_frequency_delay(lin: Mapping[str, np.ndarray]) -> np.ndarray:
    """Group delay (s) at ``ω -> 0`` of ``G / (1 - K G)``:
    ``(a1 - b1 / b0 + Td) / (1 - K b0)``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray((lin["a1"] - lin["b1"] / lin["b0"] + lin["Td"])
                          / (1.0 - lin["K"] * lin["b0"]))


@dataclass(frozen=True)
class Uncertainty:
    """The uncertainty of one calibration (see the module doc).

    ``names`` of the parameter row ``[model | effects | free upper gains]``;
    ``estimate`` the full-data optimum; ``samples`` (n, d) the resampled parameters
    the parameters' intervals come from: the refits' deviations from the estimate
    widened by ``widening`` (:func:`small_sample_scale` of ``blocks`` effective blocks
    and ``fitted`` parameters; 1 without correction) in unit coordinates, clipped to the
    box (the combinations' samples are the refits' values widened in their own units,
    :func:`widen_values`); ``refits`` (n, d) the refit parameters themselves (rows that did not run
    after a Ctrl-C are dropped from both); ``costs`` the refits' resampled costs;
    ``bounds`` the search box (name -> (lo, hi, scale)); ``upper`` the upper-level gains
    of the problem's (first) run, the free ones replaced per
    sample; ``mean_speed`` the problem's mean speed (m/s) or None; ``block_s`` and
    ``atom_s`` the block and atom lengths (s); ``combinations`` name -> samples and
    ``combination_estimates`` name -> full-data value; ``string_codes`` the
    exact-delay codes (0 locally unstable, 1 string unstable, 2 string stable) of the
    samples when computed (closed loop), ``string_certified`` whether each code is
    proven (False: the test could not decide -- a loop on a boundary or over its
    budget -- and the code is 0 or 1, never 2) and ``string_test`` the test used
    (:data:`STRING_TEST_EXACT` or :data:`STRING_TEST_CERTIFIED`). ``cost_given`` is the
    full-data cost at the optimum the stage was given (the GA's), ``cost_estimate``
    the one at ``estimate`` (lower when the polish moved it) and
    ``polish_evaluations`` the polish's rollouts; ``record_s`` the length of the
    problem's record (s, the runs' durations summed)."""

    model: str
    effects: tuple[str, ...]
    names: tuple[str, ...]
    estimate: np.ndarray
    samples: np.ndarray
    costs: np.ndarray
    level: float
    method: str
    block_s: float
    atom_s: float
    bounds: dict[str, tuple[float, float, str]]
    upper: dict[str, np.ndarray]
    upper_estimate: dict[str, float]
    mean_speed: float | None
    combinations: dict[str, np.ndarray] = field(default_factory=dict)
    combination_estimates: dict[str, float] = field(default_factory=dict)
    string_codes: np.ndarray | None = None
    string_code_estimate: int | None = None
    string_certified: np.ndarray | None = None
    string_test: str | None = None
    interrupted: bool = False
    evaluations: int = 0
    rollouts: int = 0
    refits: np.ndarray | None = None
    widening: float = 1.0
    blocks: float = math.nan
    fitted: int = 0
    cost_given: float = math.nan
    cost_estimate: float = math.nan
    polish_evaluations: int = 0
    record_s: float = math.nan

    # -- intervals --------------------------------------------------------------
    def _q(self, v: np.ndarray, estimate: float) -> tuple[float, float]:
        return symmetric_interval(float(estimate), v, self.level)

    def _param_interval(self, j: int) -> tuple[float, float]:
        """Parameter ``j``'s symmetric interval, in the GA's unit coordinates (where the
        samples were widened) and clipped to the box."""
        n = self.names[j]
        lo, hi, sc = self.bounds[n]
        if lo == hi:
            return (float(lo), float(hi))
        z = _unit(np.asarray(self.samples[:, j], dtype=np.float64), lo, hi, sc)
        ze = float(_unit(np.array([self.estimate[j]], dtype=np.float64), lo, hi, sc)[0])
        zl, zh = symmetric_interval(ze, z, self.level)
        if not (math.isfinite(zl) and math.isfinite(zh)):
            return (math.nan, math.nan)
        ql, qh = _from_unit(np.clip(np.array([zl, zh]), 0.0, 1.0), lo, hi, sc)
        return (float(ql), float(qh))

    def interval(self, name: str) -> tuple[float, float]:
        """The interval of a parameter or a combination (:attr:`intervals`)."""
        if name in self.names:
            return self._param_interval(self.names.index(name))
        return self._q(self.combinations[name], self.combination_estimates.get(name, math.nan))

    @property
    def intervals(self) -> dict[str, tuple[float, float]]:
        """Symmetric intervals at ``level`` (:func:`symmetric_interval`): parameters
        (in unit coordinates, clipped to the box), then combinations."""
        return {n: self.interval(n) for n in (*self.names, *self.combinations)}

    def ci(self) -> Any:
        """A DataFrame: rows the parameters and combinations, columns ``estimate``,
        ``median``, ``low``, ``high`` (symmetric interval at ``level``) and
        ``verdict``."""
        import pandas as pd

        iv, ver = self.intervals, self.verdicts()
        est = {**dict(zip(self.names, self.estimate, strict=True)), **self.combination_estimates}
        cols = {**{n: self.samples[:, j] for j, n in enumerate(self.names)}, **self.combinations}
        med = {n: float(np.nanmedian(v)) if np.isfinite(v).any() else math.nan
               for n, v in cols.items()}
        names = list(cols)
        return pd.DataFrame({"estimate": [float(est[n]) for n in names],
                             "median": [med[n] for n in names],
                             "low": [iv[n][0] for n in names],
                             "high": [iv[n][1] for n in names],
                             "verdict": [ver[n] for n in names]}, index=names)

    def unit_samples(self) -> np.ndarray:
        """The samples in the GA's unit coordinates of the box."""
        cols = [_unit(self.samples[:, j], *self.bounds[n]) for j, n in enumerate(self.names)]
        return np.column_stack(cols) if cols else np.zeros((len(self.samples), 0))

    @property
    def correlations(self) -> np.ndarray:
        """Correlation matrix (d, d) of the resampled parameters in unit coordinates
        (NaN for a parameter that does not vary)."""
        z = self.unit_samples()
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.corrcoef(z, rowvar=False) if z.shape[0] > 1 else np.full((z.shape[1],) * 2,
                                                                              np.nan)
        return np.atleast_2d(np.asarray(c, dtype=np.float64))

    def verdicts(self) -> dict[str, str]:
        """Per parameter and combination: ``"identified"``, ``"at bound"`` (the
        estimate is at a bound of the box), ``"reaches bound"`` (the interval does:
        the data close it on one side only), ``"wide"`` (the interval covers more
        than :data:`MAX_BOX_SHARE` of the box, or for a combination is wider than
        :data:`MAX_REL_WIDTH` of its estimate), ``"fixed"`` (lo == hi) or
        ``"undetermined"`` (no finite samples)."""
        out: dict[str, str] = {}
        for j, n in enumerate(self.names):
            lo, hi, sc = self.bounds[n]
            if lo == hi:
                out[n] = "fixed"
                continue
            ql, qh = self._param_interval(j)
            if not (math.isfinite(ql) and math.isfinite(qh)):
                out[n] = "undetermined"
                continue
            e = float(_unit(np.array([self.estimate[j]]), lo, hi, sc)[0])
            zl, zh = (float(_unit(np.array([v]), lo, hi, sc)[0]) for v in (ql, qh))
            if min(e, 1.0 - e) <= BOUND_TOL:
                out[n] = "at bound"
            elif zl <= BOUND_TOL or zh >= 1.0 - BOUND_TOL:
                out[n] = "reaches bound"
            elif zh - zl > MAX_BOX_SHARE:
                out[n] = "wide"
            else:
                out[n] = "identified"
        for n, v in self.combinations.items():
            est = self.combination_estimates.get(n, math.nan)
            ql, qh = self._q(v, est)
            if not (math.isfinite(ql) and math.isfinite(qh) and math.isfinite(est)):
                out[n] = "undetermined"
            elif qh - ql > MAX_REL_WIDTH * abs(est):
                out[n] = "wide"
            else:
                out[n] = "identified"
        return out

    def identified(self) -> list[str]:
        """Names of the parameters and combinations the data determine."""
        return [n for n, v in self.verdicts().items() if v == "identified"]

    @property
    def string_stable_probability(self) -> float | None:
        """Share of the resamples whose closed loop is string stable (locally
        unstable resamples count as not string stable), or None when not computed.
        Every verdict is a proof, not a frequency sample (:attr:`string_test`: the exact
        one-delay test for the base model, the certified interval-arithmetic test of
        every delay with structures); a resample the test cannot decide counts as not
        string stable (:attr:`string_uncertified_share`)."""
        if self.string_codes is None or self.string_codes.size == 0:
            return None
        return float(np.mean(self.string_codes == 2))

    @property
    def string_uncertified_share(self) -> float | None:
        """Share of the resamples whose stability test could not decide (counted as
        not string stable), or None when not computed."""
        if self.string_certified is None or self.string_certified.size == 0:
            return None
        return float(np.mean(~self.string_certified))

    @property
    def locally_unstable_share(self) -> float | None:
        """Share of the resamples whose closed loop is locally unstable."""
        if self.string_codes is None or self.string_codes.size == 0:
            return None
        return float(np.mean(self.string_codes == 0))

    # -- derived ------------------------------------------------------------------
    def models(self) -> list[Any]:
        """The resampled lower-level models (one per resample; for
        :func:`avll.maps.stability_probability` and the other sample-based maps)."""
        from .models import model_class

        cls = model_class(self.model)
        k = len(cls.param_names())
        out = []
        for row in self.samples:
            try:
                out.append(cls.from_array(row[:k]))
            except ValueError:
                continue
        return out

    def time_gap_effective(self, v_mean: float | None = None) -> tuple[float, np.ndarray]:
        """``Tg + Gmin / v̄`` at ``v_mean`` (default the problem's mean speed): the
        full-data value and the resamples'. With upper-level structures, their
        equilibrium time gap at ``v̄`` (``Tg_eq`` of :meth:`avll.WithEffects.upper_linear`,
        e.g. ``Tg + ch v̄`` of ``speed_gains``) in place of ``Tg``, as the OpenACC
        study's point estimate. With a small-sample correction the resamples' values are
        the refits' with their deviations widened (:func:`widen_values`)."""
        v = self.mean_speed if v_mean is None else float(v_mean)
        if v is None or not math.isfinite(v):
            raise ValueError("v_mean: the calibration has no mean speed; give v_mean")
        if self.refits is not None and self.widening != 1.0:
            # widened as a quantity of its own (see the module doc)
            est, raw = self._raw().time_gap_effective(v)
            return est, widen_values(est, raw, self.widening)
        v = max(v, 0.1)
        tg_est, tg = self._equilibrium_time_gaps(v)
        est = tg_est + self.upper_estimate["Gmin"] / v
        smp = np.asarray(tg + self.upper["Gmin"] / v, dtype=np.float64)
        if self.gap_loop_too_slow():
            smp = np.full_like(smp, np.nan)  # undetermined: see gap_loop_too_slow
        return float(est), smp

    def gap_loop_period(self) -> float:
        """``2 π / sqrt(kg G(0))`` (s) of the estimate: the natural period of the gap
        loop (the gap gain through the lower level's static gain ``G(0)``, the
        :func:`dc_gain`); ``inf`` when that gain is not positive (no gap feedback, or a
        lower level that does not answer a steady command)."""
        g = self.upper_estimate.get("kg", math.nan) * self.combination_estimates.get(
            "dc_gain", math.nan)
        return 2.0 * math.pi / math.sqrt(g) if g > 0 else math.inf

    def gap_loop_too_slow(self) -> bool:
        """Whether ``Tg + Gmin / v̄`` is undetermined by this fit: the gap loop's natural
        period (:meth:`gap_loop_period`) is longer than the record (:attr:`record_s`).
        The equilibrium gap ``Gmin + Tg v`` is where the gap feedback settles; a fit
        whose gap loop takes longer than the record to settle (``kg`` or the DC gain at
        zero: a corner local minimum of a closed-loop fit with free gains) cannot
        determine it, and the refits from that corner do not leave it."""
        return bool(math.isfinite(self.record_s) and self.gap_loop_period() > self.record_s)

    def gap_loop_reason(self) -> str:
        """Why :meth:`gap_loop_too_slow` holds, with the numbers."""
        return (f"undetermined: the fitted gap loop's natural period "
                f"{self.gap_loop_period():.3g} s exceeds the record ({self.record_s:.0f} s; "
                "kg or the lower level's DC gain at zero)")

    def _equilibrium_time_gaps(self, v: float) -> tuple[float, np.ndarray]:
        """The law's equilibrium time gap at speed ``v``, full-data and per resample:
        ``Tg`` without upper-level structures, their ``Tg_eq``
        (:meth:`avll.WithEffects.upper_linear`) with them."""
        from .effects import EFFECTS, WithEffects
        from .models import UpperLevel, model_class

        tg0, tg = float(self.upper_estimate["Tg"]), np.asarray(self.upper["Tg"], dtype=float)
        if not any(EFFECTS[e].level == "upper" for e in self.effects):
            return tg0, tg
        k = len(model_class(self.model).param_names())
        k += sum(len(EFFECTS[e].param_names()) for e in self.effects)

        def eq(row: np.ndarray, up: Mapping[str, float]) -> float:
            try:
                m = WithEffects.from_array(self.model, self.effects, row[:k])
                law = UpperLevel(**{n: float(up[n]) for n in ("kg", "kv", "Tg", "Gmin")})
                return float(m.upper_linear(law, v=float(v))["Tg_eq"])
            except ValueError:  # a resample outside a parameter's domain (NaN rows too)
                return math.nan

        per = np.array([eq(row, {n: self.upper[n][i] for n in self.upper})
                        for i, row in enumerate(self.samples)])
        return eq(self.estimate, self.upper_estimate), per

    def rows(self) -> np.ndarray:
        """The closed loops as parameter rows ``[model | effects | kg, kv, Tg, Gmin]``
        (the row order of :func:`avll.effect_stability.frequency_response_rows`): the
        full-data optimum first, then one row per resample."""
        from .defaults import UPPER_NAMES

        k = len(self.names) - sum(1 for n in self.names if n in UPPER_NAMES)
        up = np.column_stack([np.concatenate([[self.upper_estimate[n]], self.upper[n]])
                              for n in UPPER_NAMES])
        return np.ascontiguousarray(np.hstack([
            np.vstack([self.estimate[None, :k], self.samples[:, :k]]), up]))

    def band_amplification(self, lead_v: np.ndarray, dt: float,
                           band: Sequence[float] | None = None, *, v: float | None = None,
                           threads: int = 0, hold: float | None = None
                           ) -> tuple[float, np.ndarray]:
        """``|H|`` of the calibrated closed loop -- the base model with its effects of
        both levels, linearised at ``v`` (default: the mean of ``lead_v``), every delay
        exact -- as an RMS gain on the band-passed spectrum of the predecessor's speed
        ``lead_v`` (:func:`avll.effect_stability.band_amplification_rows`, every row in
        one Rust call; ``hold`` the loop's sample period, default ``dt``): the full-data
        value (NaN where its closed loop is locally unstable, when known) and the
        resamples'. With a small-sample correction (``widening > 1``) the resamples' are
        the refits' values with their deviations from the full-data one widened
        (:func:`widen_values`); without, the samples' (NaN where a closed loop is
        locally unstable, when known)."""
        from .effect_stability import band_amplification_rows

        if self.refits is not None and self.widening != 1.0:
            # the refits' |H|, widened as a quantity of its own (see the module doc)
            est, raw = self._raw().band_amplification(lead_v, dt, band, v=v,
                                                      threads=threads, hold=hold)
            wide = widen_values(est, raw, self.widening)
            return (math.nan if self.string_code_estimate == 0 else est), wide
        g = band_amplification_rows(self.model, self.rows(), lead_v, dt, band,
                                    effects=self.effects, v=v, threads=threads, hold=hold)
        if self.string_codes is not None:
            g[1:][self.string_codes == 0] = math.nan
        if self.string_code_estimate == 0:
            g[0] = math.nan
        return float(g[0]), g[1:]

    def uncorrected(self) -> Uncertainty:
        """A copy whose samples are the refits themselves (the plain percentile
        bootstrap, no widening; the exact-delay codes dropped), for comparison."""
        if self.refits is None or self.widening == 1.0:
            return self
        out = self._raw()
        if self.combinations:
            from .models import model_class

            full = _lower_combinations(model_class(self.model), self.refits)
            out = out.with_combinations(**{n: (self.combination_estimates[n], full[n])
                                           for n in self.combinations if n in full})
        if "time_gap_effective" in self.combinations and self.mean_speed is not None:
            out = out.with_combinations(time_gap_effective=out.time_gap_effective())
        return out

    def _raw(self) -> Uncertainty:
        """The refits as samples (their upper gains too), no widening, no exact-delay
        codes; the combinations left as they are (:meth:`uncorrected` recomputes them).
        What the quantities widened in their own units are computed from."""
        assert self.refits is not None
        up = {n: self.refits[:, self.names.index(n)].copy() if n in self.names else v
              for n, v in self.upper.items()}
        return replace(self, samples=self.refits, upper=up, widening=1.0, string_codes=None,
                       string_code_estimate=None, string_certified=None)

    def with_combinations(self, **more: tuple[float, np.ndarray]) -> Uncertainty:
        """A copy with more combinations (name -> (estimate, samples))."""
        return replace(
            self, combinations={**self.combinations, **{
                n: np.asarray(v, dtype=np.float64) for n, (_, v) in more.items()}},
            combination_estimates={**self.combination_estimates,
                                   **{n: float(e) for n, (e, _) in more.items()}})

    # -- output ---------------------------------------------------------------------
    def report(self, min_correl: float = MIN_CORREL) -> str:
        """A text report in the style of lmfit's ``fit_report``: values with their
        intervals and verdicts, identified combinations, correlations of at least
        ``min_correl`` (absolute), the resampling."""
        pct = f"{100 * self.level:g} %"
        ver = self.verdicts()
        iv = self.intervals
        lines = [f"[[Uncertainty]] {self.model}"
                 + (f" + {', '.join(self.effects)}" if self.effects else ""),
                 f"    resamples: {len(self.samples)} ({self.method}, block {self.block_s:.3g} s"
                 f", atoms {self.atom_s:.3g} s){' INTERRUPTED' if self.interrupted else ''}",
                 f"    deviations widened x{self.widening:.3g} ({self.blocks:.3g} effective "
                 f"blocks, {self.fitted} fitted parameters)",
                 f"    estimate: cost {self.cost_estimate:.6g}"
                 + (f" (polished from {self.cost_given:.6g} in {self.polish_evaluations} "
                    f"rollouts)" if self.cost_estimate < self.cost_given else ""),
                 f"[[Parameters]] (estimate, {pct} interval, verdict)"]
        w = max((len(n) for n in (*self.names, *self.combinations)), default=4) + 1
        for j, n in enumerate(self.names):
            lo, hi = iv[n]
            mark = "" if ver[n] == "identified" else "   (not a finding)"
            lines.append(f"    {n + ':':<{w}} {self.estimate[j]: .5g}  [{lo: .5g}, {hi: .5g}]  "
                         f"{ver[n]}{mark}")
        if self.combinations:
            lines.append(f"[[Combinations]] (estimate, {pct} interval, verdict)")
            for n in self.combinations:
                lo, hi = iv[n]
                est = self.combination_estimates.get(n, math.nan)
                lines.append(f"    {n + ':':<{w}} {est: .5g}  [{lo: .5g}, {hi: .5g}]  "
                             f"{ver[n]}")
        p = self.string_stable_probability
        if p is not None:
            how = self.string_test or "exact test, true delay"
            und = self.string_uncertified_share
            lines.append(f"    P(string stable): {p:.3f} (locally unstable: "
                         f"{self.locally_unstable_share:.3f}; {how}"
                         + (f"; undecided: {und:.3f}" if und else "") + ")")
        c = self.correlations
        pairs = [(abs(c[i, j]), self.names[i], self.names[j], c[i, j])
                 for i in range(len(self.names)) for j in range(i + 1, len(self.names))
                 if np.isfinite(c[i, j]) and abs(c[i, j]) >= min_correl]
        lines.append(f"[[Correlations]] (unreported correlations are < {min_correl:.3f})")
        for _, a, b, v in sorted(pairs, reverse=True):
            lines.append(f"    C({a}, {b}) = {v:+.3f}")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """Strict-JSON-ready summary: ``params_ci`` (name -> [low, high] or None),
        ``combinations_ci``, ``verdicts``, ``identified``, ``string_stable_probability``,
        the resampling settings."""
        def pair(t: tuple[float, float]) -> list[float] | None:
            return [t[0], t[1]] if all(math.isfinite(v) for v in t) else None

        iv = self.intervals
        return {
            "params_ci": {n: pair(iv[n]) for n in self.names},
            "combinations_ci": {n: pair(iv[n]) for n in self.combinations},
            "verdicts": self.verdicts(),
            "identified": self.identified(),
            "string_stable_probability": self.string_stable_probability,
            "string_test": self.string_test,
            "string_undecided_share": self.string_uncertified_share,
            "resamples": int(len(self.samples)),
            "method": self.method,
            "block_s": float(self.block_s),
            "level": float(self.level),
            "cost_given": finite_or_none(self.cost_given),
            "cost_estimate": finite_or_none(self.cost_estimate),
        }

    def to_dataset(self, **coords: Any) -> Any:
        """This calibration as an ``xarray.Dataset`` with one ``car`` (see
        :func:`to_dataset`)."""
        return to_dataset([self], **{k: [v] for k, v in coords.items()})


def to_dataset(items: Sequence[Any], car: Sequence[Any] | None = None,
               **coords: Sequence[Any]) -> Any:
    """Many calibrations' uncertainty (:class:`Uncertainty` objects, or calibration
    results with intervals) as one ``xarray.Dataset`` with dims ``car`` x
    ``parameter`` (the model's and effects' parameters and free gains, the union over
    ``items``): ``value``, ``low``, ``high`` and ``identified`` (bool), plus one
    variable per combination (``<name>``, ``<name>_low``, ``<name>_high``) over
    ``car``, ``string_stable_probability`` over ``car`` and the correlation matrix
    ``correlation`` (car x parameter x parameter2). ``coords`` add coordinates along
    ``car`` (e.g. ``file=``, ``setting=``); ``model`` is one automatically. The layout
    follows xarray's ``curvefit`` output (``*_coefficients`` over ``param``)."""
    import xarray as xr

    items = [getattr(u, "uncertainty", u) for u in items]
    if not items:
        raise ValueError("items: no calibrations given")
    for q, u in enumerate(items):
        if not isinstance(u, Uncertainty):
            raise TypeError(f"items[{q}]: expected an avll.Uncertainty or a calibration "
                            f"with intervals, got {type(u).__name__}")
    names = list(dict.fromkeys(n for u in items for n in u.names))
    comb = list(dict.fromkeys(n for u in items for n in u.combinations))
    nc, npar = len(items), len(names)
    val, lo, hi = (np.full((nc, npar), np.nan) for _ in range(3))
    ok = np.zeros((nc, npar), dtype=bool)
    cor = np.full((nc, npar, npar), np.nan)
    cv = {n: np.full((nc, 3), np.nan) for n in comb}
    cid = {n: np.zeros(nc, dtype=bool) for n in comb}
    pstab = np.full(nc, np.nan)
    for i, u in enumerate(items):
        iv, ver, c = u.intervals, u.verdicts(), u.correlations
        pos = [names.index(n) for n in u.names]
        for j, n in enumerate(u.names):
            val[i, pos[j]] = u.estimate[j]
            lo[i, pos[j]], hi[i, pos[j]] = iv[n]
            ok[i, pos[j]] = ver[n] == "identified"
        if c.size:
            cor[i][np.ix_(pos, pos)] = c
        for n in u.combinations:
            cv[n][i] = (u.combination_estimates.get(n, np.nan), *iv[n])
            cid[n][i] = ver[n] == "identified"
        p = u.string_stable_probability
        pstab[i] = np.nan if p is None else p
    car_c = list(range(nc)) if car is None else list(car)
    data: dict[str, Any] = {
        "value": (("car", "parameter"), val),
        "low": (("car", "parameter"), lo),
        "high": (("car", "parameter"), hi),
        "identified": (("car", "parameter"), ok),
        "correlation": (("car", "parameter", "parameter2"), cor),
        "string_stable_probability": (("car",), pstab),
    }
    for n in comb:
        data[n] = (("car",), cv[n][:, 0])
        data[f"{n}_low"] = (("car",), cv[n][:, 1])
        data[f"{n}_high"] = (("car",), cv[n][:, 2])
        data[f"{n}_identified"] = (("car",), cid[n])
    cds: dict[str, Any] = {"car": car_c, "parameter": names, "parameter2": names,
                           "model": ("car", [u.model for u in items])}
    for name, vals in coords.items():
        vals = list(vals)
        if len(vals) != nc:
            raise ValueError(f"{name}: {len(vals)} values for {nc} calibrations")
        cds[name] = ("car", vals)
    lv = {u.level for u in items}
    return xr.Dataset(data, coords=cds, attrs={
        "level": lv.pop() if len(lv) == 1 else "mixed",
        "intervals": "symmetric intervals of a block bootstrap over time refit from the "
                     "full-data optimum, the deviations widened for the parameters fitted "
                     "on few effective blocks (avll.uncertainty)",
        "identified": f"interval within {MAX_BOX_SHARE} of the search box (unit "
                      f"coordinates) and off the bounds; combinations: width within "
                      f"{MAX_REL_WIDTH} of the estimate"})


# ---------------------------------------------------------------------------
# The stage itself (called by avll.calibrate / calibrate_many)
# ---------------------------------------------------------------------------


def refit_budget(opts: Intervals, d: int) -> int:
    """Rollouts per resample refit: :attr:`Intervals.budget`, or when 0
    :data:`LM_BUDGET_PER_PARAM` ``d`` for Levenberg-Marquardt refits (0, Rust's
    ``200 d``, for simplex refits)."""
    if opts.budget or opts.refit != "lm":
        return int(opts.budget)
    return LM_BUDGET_PER_PARAM * int(d)


def _polish(prob: Any, subsets: Sequence[Sequence[int]], x0: np.ndarray, opts: Intervals,
            threads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """Each problem's optimum refit on its full data (one resample of unit weights, the
    refits' local search): the starts (kept where the refit did not lower the cost),
    their full-data costs, the costs at the given optima, the rollouts, and whether a
    Ctrl-C stopped it."""
    uniq = [sorted(set(int(i) for i in s)) for s in subsets]
    raws = _core.refit_resamples(
        prob.cls.name, lower_bounds=prob.lower, upper_bounds=prob.upper, scale=prob.scale,
        problems=[[int(i) for i in s] for s in subsets], x0=x0,
        atoms=[[len(prob.rs.runs[i]) for i in u] for u in uniq],
        resample_weights=[np.ones((1, len(u))) for u in uniq], budget=int(opts.budget),
        step=float(opts.step), ftol=float(opts.ftol), method=opts.refit,
        threads=int(threads), **prob.kw)
    x = x0.copy()
    given = np.array([float(raw["f_full"]) for raw in raws])
    f = given.copy()
    evals = np.zeros(len(subsets), dtype=np.int64)
    for k, raw in enumerate(raws):
        if bool(np.asarray(raw["done"])[0]):
            fk = float(np.asarray(raw["f"])[0])
            evals[k] = int(np.asarray(raw["evaluations"])[0])
            if math.isfinite(fk) and fk < given[k]:
                x[k] = np.asarray(raw["x"], dtype=np.float64)[0]
                f[k] = fk
    return x, f, given, evals, any(bool(r["interrupted"]) for r in raws)


def _plan(prob: Any, sub: Sequence[int], x0: np.ndarray, opts: Intervals, seed: int,
          k: int, threads: int) -> tuple[list[int], list[int], np.ndarray, float, float]:
    """The distinct runs of problem ``k``, their atom lengths (samples), the resample
    weights (n x atoms), the block and atom lengths (s)."""
    uniq = sorted(set(int(i) for i in sub))
    runs = [prob.rs.runs[i] for i in uniq]
    dt = max(float(r.dt) for r in runs)
    if opts.method == "runs" and len(uniq) < 2:
        raise ValueError("intervals: method='runs' needs a problem with at least two "
                         "distinct runs; use method='blocks'")
    shortest = min(len(r) for r in runs) * dt
    if opts.block is not None:
        block = float(opts.block)
    elif opts.method == "runs":
        block = shortest
    else:
        res = _score_series(prob, uniq, runs, x0, threads)
        block = block_length(res, dt, MIN_BLOCK, shortest / 3.0, opts.block_factor)
    rng = np.random.default_rng([int(seed), int(k)])
    atoms = [max(1, int(round(block / ATOMS_PER_BLOCK / float(r.dt)))) for r in runs]
    counts = [-(-len(r) // a) for r, a in zip(runs, atoms, strict=True)]
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(int)
    n = int(opts.n)
    w = np.zeros((n, int(starts[-1])))
    if opts.method == "runs":
        draws = rng.integers(0, len(uniq), size=(n, len(uniq)))
        mult = np.stack([np.bincount(d, minlength=len(uniq)) for d in draws]).astype(float)
        for j in range(len(counts)):
            w[:, starts[j] : starts[j + 1]] = mult[:, j : j + 1]
    else:
        for c, start in zip(counts, starts, strict=False):
            nb = -(-c // ATOMS_PER_BLOCK)
            s = rng.integers(0, c, size=(n, nb))
            idx = (s[:, :, None] + np.arange(ATOMS_PER_BLOCK)[None, None, :]) % c
            rows = np.repeat(np.arange(n), nb * ATOMS_PER_BLOCK)
            np.add.at(w, (rows, start + idx.ravel()), 1.0)
    atom_s = float(np.mean([a * float(r.dt) for a, r in zip(atoms, runs, strict=True)]))
    return uniq, atoms, np.ascontiguousarray(w), float(block), atom_s


#: Finite-difference step (unit coordinates) of the score series.
_SCORE_STEP = 1e-3


def _score_series(prob: Any, uniq: Sequence[int], runs: Sequence[Any], x0: np.ndarray,
                  threads: int) -> list[np.ndarray]:
    """The estimating-equation (score) series of the full-data fit, per run and fitted
    parameter: ``g_j(t) = Σ_c w_c (∂ŷ_c(t) / ∂z_j) (ŷ_c(t) - y_c(t))`` over the weighted
    channels ``c`` (acceleration, speed, position), ``z`` the GA's unit coordinates
    (forward differences of one batch of rollouts, stepped into the box). The cost's
    gradient is their sum; the bootstrap's spread of the refits is that of their
    resampled sums, so their serial correlation sets the block length."""
    free = [j for j, (lo, hi) in enumerate(zip(prob.lower, prob.upper, strict=True))
            if hi > lo]
    rows = [np.asarray(x0, dtype=np.float64).copy()]
    steps = []
    for j in free:
        lo, hi, sc = prob.lower[j], prob.upper[j], prob.scale[j]
        z = float(_unit(np.array([x0[j]], dtype=np.float64), lo, hi, sc)[0])
        h = _SCORE_STEP if z + _SCORE_STEP <= 1.0 else -_SCORE_STEP
        row = rows[0].copy()
        row[j] = float(_from_unit(np.array([z + h]), lo, hi, sc)[0])
        rows.append(row)
        steps.append(h)
    kw = {k2: v for k2, v in prob.kw.items() if k2 != "runs"}
    sim = np.asarray(_core.simulate_batch(
        prob.cls.name, np.ascontiguousarray(np.vstack(rows)), prob.rs._handle.take(list(uniq)),
        threads=int(threads), **kw))  # (a, v, x) x rows x samples
    off = np.concatenate([[0], np.cumsum([len(r) for r in runs])])
    w = prob.kw["weights"]
    out: list[np.ndarray] = []
    with np.errstate(invalid="ignore", over="ignore"):
        for q, r in enumerate(runs):
            sl = slice(int(off[q]), int(off[q + 1]))
            g = np.zeros((len(steps), len(r)))
            for c, meas in enumerate((r.a, r.v, r.x)):
                if w[c] > 0 and meas is not None:
                    e = sim[c, 0, sl] - meas
                    for i, h in enumerate(steps):
                        g[i] += w[c] * (sim[c, i + 1, sl] - sim[c, 0, sl]) / h * e
            out.extend(g)
    return out


def _upper_columns(prob: Any, run: Any, x: np.ndarray) -> dict[str, np.ndarray]:
    """kg, kv, Tg, Gmin per row of ``x``: the free ones from the rows, the others the
    run's."""
    from .defaults import UPPER_NAMES

    base = run.upper.to_array() if run.upper is not None else np.full(4, np.nan)
    nfree = len(prob.free)
    out = {n: np.full(x.shape[0], float(base[i])) for i, n in enumerate(UPPER_NAMES)}
    for j, i in enumerate(prob.free):
        out[UPPER_NAMES[i]] = x[:, x.shape[1] - nfree + j].copy()
    return out


#: How :attr:`Uncertainty.string_codes` are decided without structures.
STRING_TEST_EXACT = ("exact test, true delay (crossing frequencies and a certified "
                     "string sweep; avll.stability.exact_delay_codes)")
#: ... and with structures (every delay of the follower kept).
STRING_TEST_CERTIFIED = ("certified test, every delay exact (argument principle and "
                         "|Den|^2 - |Num|^2 swept in interval arithmetic; "
                         "avll.effect_stability.stability_codes_rows)")


def _exact_codes(model: str, cls: Any, x: np.ndarray, up: Mapping[str, np.ndarray],
                 threads: int, effects: Sequence[str] = (), v: float | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Exact-delay codes of each row's closed loop and whether each is certified; with
    ``effects`` (their parameters after the model's in ``x``) the certified test of
    every delay (:func:`avll.effect_stability.stability_codes_rows`, linearised at
    ``v``)."""
    k = len(cls.param_names())
    if effects:
        from .defaults import UPPER_NAMES
        from .effect_stability import stability_codes_rows
        from .effects import EFFECTS

        ne = sum(len(EFFECTS[e].param_names()) for e in effects)
        rows = np.hstack([x[:, :k + ne], np.column_stack([up[n] for n in UPPER_NAMES])])
        fin = np.all(np.isfinite(rows), axis=1)
        c, cert = stability_codes_rows(model, rows, effects=list(effects),
                                       v=0.0 if v is None else float(v), threads=threads)
        return np.where(fin, c, 0), np.where(fin, cert, True)
    ok = np.all(np.isfinite(x), axis=1) & np.isfinite(up["kg"]) & np.isfinite(up["Tg"]) & \
        np.isfinite(up["kv"])
    codes = np.zeros(x.shape[0], dtype=np.int64)
    cert = np.ones(x.shape[0], dtype=bool)
    if ok.any():
        c, settled = _core.delay_codes_rows(model, np.ascontiguousarray(x[ok, :k]),
                                            [float(v) for v in up["kg"][ok]],
                                            [float(v) for v in up["Tg"][ok]],
                                            [float(v) for v in up["kv"][ok]],
                                            threads=int(threads))
        codes[ok] = np.asarray(c, dtype=np.int64)
        cert[ok] = np.asarray(settled, dtype=bool)
    return codes, cert


def estimate(prob: Any, subsets: Sequence[Sequence[int]], x0s: Sequence[np.ndarray],
             opts: Intervals, *, seed: int, threads: int = 0,
             progress: bool | str | Callable[[dict[str, Any]], Any] = False,
             refit: Callable[..., list[dict[str, Any]]] | None = None
             ) -> list[Uncertainty]:
    """The uncertainty stage for the problems ``subsets`` (run positions, repeats
    count) of the calibration problem ``prob`` with full-data optima ``x0s``: one
    :class:`Uncertainty` per problem, each centred on its polished optimum
    (:attr:`Intervals.polish`; ``Uncertainty.estimate``). Used by :func:`avll.calibrate`.
    ``refit`` replaces the refits in this process: ``refit(subsets, x0, atoms, weights, opts,
    threads)`` returns what :func:`avll._core.refit_resamples` returns for the same
    multiplicities (drawn here), e.g. as ``dask.distributed`` tasks
    (:func:`avll.maps.bootstrap_distributed`)."""
    threads = check_threads(threads)
    seed = check_seed(seed if opts.seed is None else opts.seed)
    x0 = np.ascontiguousarray(np.vstack([np.asarray(x, dtype=np.float64) for x in x0s]))
    n_p = len(subsets)
    f_est = f_given = np.full(n_p, np.nan)
    p_evals = np.zeros(n_p, dtype=np.int64)
    if opts.polish:
        x0, f_est, f_given, p_evals, stopped = _polish(prob, subsets, x0, opts, threads)
        if stopped:
            _sigint.clear()
            return [_stopped(prob, s, x0[k], opts, f_given[k]) for k, s in enumerate(subsets)]
    plans = [_plan(prob, s, x0[k], opts, seed, k, threads) for k, s in enumerate(subsets)]
    problems = [[int(i) for i in s] for s in subsets]
    atoms, weights = [p[1] for p in plans], [p[2] for p in plans]
    # the refits' own budget (the polish above kept the options' one)
    ropts = replace(opts, budget=refit_budget(opts, x0.shape[1]))
    bar: Any = None
    if callable(progress):
        cb: Any = progress
    else:
        from .progress import Progress

        bar = Progress(len(subsets) * int(opts.n), "intervals", unit="refit", mode=progress)
        seen: dict[int, int] = {}

        def cb(info: dict[str, Any]) -> None:
            seen[int(info["problem"])] = int(info["done"])
            bar.advance_to(sum(seen.values()))
    done = False
    try:
        if refit is None:
            raws = _core.refit_resamples(
                prob.cls.name, lower_bounds=prob.lower, upper_bounds=prob.upper,
                scale=prob.scale, problems=problems, x0=x0, atoms=atoms,
                resample_weights=weights, budget=ropts.budget, step=float(opts.step),
                ftol=float(opts.ftol), method=opts.refit,
                progress=cb if (callable(progress) or bar.mode != "none") else None,
                threads=int(threads), **prob.kw)
        else:
            raws = refit(problems, x0, atoms, weights, ropts, threads)
        done = not any(bool(r["interrupted"]) for r in raws)
        if not done:
            _sigint.clear()
    finally:
        if bar is not None:
            bar.close(complete=done)
    from .models import model_class

    cls = model_class(prob.cls.name)
    out = []
    for k, (raw, plan) in enumerate(zip(raws, plans, strict=True)):
        ran = np.asarray(raw["done"], dtype=bool)
        xs = np.asarray(raw["x"], dtype=np.float64)[ran]
        costs = np.asarray(raw["f"], dtype=np.float64)[ran]
        keep = np.isfinite(costs)
        xs, costs = xs[keep], costs[keep]
        runs = [prob.rs.runs[i] for i in plan[0]]
        record_s = float(sum(len(r) * float(r.dt) for r in runs))
        # effective independent pieces: blocks of the record, or whole runs
        blocks = float(len(runs)) if opts.method == "runs" else record_s / plan[3]
        fitted = sum(1 for lo, hi in zip(prob.lower, prob.upper, strict=True) if hi > lo)
        fac = (1.0 if opts.correction == "none" else
               small_sample_scale(blocks, fitted, float(opts.level)))
        refits = xs
        xs = widen(refits, x0[k], [prob.box[n] for n in prob.names], fac) if fac != 1.0 \
            else refits.copy()
        run0 = runs[0]
        up = _upper_columns(prob, run0, xs)
        up0 = {n: float(v[0]) for n, v in _upper_columns(prob, run0, x0[k][None, :]).items()}
        vs = [r.v for r in runs if r.v is not None]
        vbar = float(np.mean(np.concatenate(vs))) if vs else None
        # the combinations of the refits, widened as quantities of their own
        comb = {n: np.concatenate([v[:1], widen_values(float(v[0]), v[1:], fac)])
                for n, v in _lower_combinations(cls, np.vstack([x0[k][None, :], refits])).items()}
        u = Uncertainty(
            model=prob.cls.name, effects=tuple(prob.effects), names=tuple(prob.names),
            estimate=x0[k].copy(), samples=xs, costs=costs, level=float(opts.level),
            method=opts.method, block_s=plan[3], atom_s=plan[4], bounds=prob.box, upper=up,
            upper_estimate=up0, mean_speed=vbar,
            combinations={n: v[1:] for n, v in comb.items()},
            combination_estimates={n: float(v[0]) for n, v in comb.items()},
            interrupted=not bool(ran.all()),
            evaluations=int(np.sum(np.asarray(raw["evaluations"])[ran])),
            rollouts=int(raw["rollouts"]), refits=refits, widening=float(fac),
            blocks=blocks, fitted=int(fitted),
            cost_given=float(f_given[k] if opts.polish else raw["f_full"]),
            cost_estimate=float(f_est[k] if opts.polish else raw["f_full"]),
            polish_evaluations=int(p_evals[k]),
            record_s=record_s)
        if prob.closed_loop and vbar is not None and math.isfinite(up0["Tg"]):
            u = u.with_combinations(time_gap_effective=u.time_gap_effective())
        if prob.closed_loop and math.isfinite(fac):
            codes, cert = _exact_codes(prob.cls.name, cls, xs, up, threads, prob.effects,
                                       vbar)
            c0, _ = _exact_codes(prob.cls.name, cls, x0[k][None, :],
                                 {n: np.array([v]) for n, v in up0.items()}, threads,
                                 prob.effects, vbar)
            u = replace(u, string_codes=codes, string_code_estimate=int(c0[0]),
                        string_certified=cert,
                        string_test=STRING_TEST_CERTIFIED if prob.effects else
                        STRING_TEST_EXACT)
        out.append(u)
    return out


def _stopped(prob: Any, sub: Sequence[int], x0: np.ndarray, opts: Intervals,
             cost: float) -> Uncertainty:
    """The uncertainty of a problem whose polish a Ctrl-C stopped: no resample refit."""
    d = len(prob.names)
    up0 = {n: float(v[0]) for n, v in
           _upper_columns(prob, prob.rs.runs[int(sub[0])], x0[None, :]).items()}
    return Uncertainty(
        model=prob.cls.name, effects=tuple(prob.effects), names=tuple(prob.names),
        estimate=x0.copy(), samples=np.empty((0, d)), costs=np.empty(0),
        level=float(opts.level), method=opts.method, block_s=math.nan, atom_s=math.nan,
        bounds=prob.box, upper={n: np.empty(0) for n in up0}, upper_estimate=up0,
        mean_speed=None, interrupted=True, refits=np.empty((0, d)), cost_given=cost,
        cost_estimate=cost)
