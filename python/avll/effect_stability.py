"""What the effects do to the stability conclusions.

:func:`effect_stability` answers, for a lower-level model with effects
(:class:`avll.WithEffects`) under a constant-time-gap upper level (paper Eq. 3):

1. **Linearised** (every effect that has a small-signal form; the only answer for
   smooth effects): the base model and the model with effects linearised at the
   operating speed ``v0`` (:meth:`avll.WithEffects.linear`; for ``asymmetric`` on
   the accelerating side, the braking side and their average) side by side, each
   with

   * the stability code at the given gains (:func:`avll.stability.stability_points`,
     Padé order ``pade_order``; 0 locally unstable, 1 string unstable, 2 stable);
   * the smallest stable ``Tg`` at the given ``kg, kv``
     (:func:`avll.stability.stable_intervals`, string level);
   * the paper's thresholds as true extrema: the minimum stable ``Tg`` over the
     ``kg, kv`` box (:func:`avll.stability.min_stable_tg`) and the kv threshold
     (:func:`avll.stability.kv_supremum`);
   * ``|H(jw)|``, the follower's exact frequency response (:func:`frequency_response`:
     Eq. 8 with the true delays and every effect's small-signal form, both levels) at
     the disturbance frequency and its peak over a frequency grid (``OMEGA_GRID``; a
     sampled maximum, not a certificate).

   ``speed_drag``/``road_load`` at ``v0`` add a speed feedback ``beta`` to the plant
   (``a = G (u + K a) - beta v``, the ``speed_feedback`` of
   ``WithEffects.linear(terms=True)``), a ``delay`` with ``K != 0`` a factor
   ``e^{-tau s}`` outside the inner loop, ``perception`` a delay on the radar terms,
   ``feedforward`` a term on the predecessor speed: no second-order form under Eq. 3
   holds them, so only ``|H(jw)|`` is given, not the engine's verdicts; ``closing``
   and ``speed_gains`` change the law's small-signal gains, at which the engine's
   code is then given (:meth:`avll.WithEffects.upper_linear`).

2. **In the time domain** (amplitude-dependent effects: ``saturation``,
   ``power_limit``, ``rate_limit``, ``asymmetric``, ``deadband``, but computed for
   any model): a platoon of ``n_cars`` followers behind a leader whose speed is
   ``v0 + A w(t) sin(w t)`` (``w(t)`` a raised-cosine ramp over the first period),
   simulated with the nonlinear effects by the Rust platoon (:func:`avll.platoon`,
   time-major: follower ``i`` follows follower ``i-1``'s simulated position and speed,
   starting at ``v0`` and the equilibrium gap ``Gmin + Tg v0``, with ``speed_gains``
   ``Gmin + Tg(v0) v0``). After ``warm_periods`` periods, the speed of every car over the
   next ``measure_periods`` periods is fitted by least squares with
   ``c0 + c1 t + s sin(w t) + c cos(w t)``; the **amplification of car i** is the
   ratio of its fundamental amplitude ``sqrt(s² + c²)`` to car ``i-1``'s (car 0 the
   leader; undefined, NaN, behind a car whose amplitude is below ``1e-6 A``). For a
   linear model this is ``|H(jw)|`` whatever ``A`` (the tests check it, to the O(dt)
   error of evaluating the upper law at the samples); an amplitude-dependent effect
   makes it depend on ``A``. A car whose trajectory diverges (NaN) and every car
   behind it have no amplification. Also reported: the ratio of the half ranges
   (half the peak-to-peak speed; with strong nonlinearity the oscillation moves into
   harmonics and slower motion, and the fundamental alone understates it), the
   lowest speed (the models have no standstill: a negative speed is flagged) and the
   drift of each car's fundamental between the two halves of the window (a car that
   is not in a steady oscillation, e.g. a growing one, is flagged). ``asymmetric`` is
   positively homogeneous (a gain and a time scale per sign): about an equilibrium
   with zero command its amplification does not depend on ``A`` either, although it
   differs from each side's linearisation.

The result (:class:`EffectStability`) has :meth:`~EffectStability.to_dict`
(strict JSON) and :meth:`~EffectStability.plot`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from . import _core
from ._limits import check_int, check_number, check_threads
from .effects import EFFECTS, WithEffects, canonical, equivalent_model
from .models import LowerLevelModel, UpperLevel, model_class
from .paper import PADE_ORDER
from .progress import resolve_mode
from .rollout import platoon
from .stability import (
    EXACT_BUDGET,
    MIN_TG_BOX,
    kv_supremum,
    min_stable_tg,
    stability_points,
    stable_intervals,
)

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = [
    "AMPLITUDE_DEPENDENT",
    "OMEGA_GRID",
    "DRIFT_TOL",
    "LinearStability",
    "EffectStability",
    "effect_stability",
    "frequency_response",
    "frequency_response_rows",
    "band_amplification_rows",
    "stability_codes_rows",
    "sine_leader",
    "fundamental_amplitude",
    "car_ratios",
]

#: Effects whose action depends on the size of the disturbance.
AMPLITUDE_DEPENDENT: frozenset[str] = frozenset(
    {"saturation", "power_limit", "rate_limit", "asymmetric", "deadband"}
)
#: Largest relative change of a car's fitted fundamental between the two halves of
#: the measurement window that still counts as a steady oscillation.
DRIFT_TOL = 0.05
#: Frequencies (rad/s) over which the peak ``|H(jw)|`` is sampled.
OMEGA_GRID: np.ndarray = np.logspace(-3, math.log10(30.0), 2000)


def _with_effects(model: Any) -> WithEffects:
    """``model`` as an :class:`avll.WithEffects` (a base model: with no effects)."""
    if isinstance(model, LowerLevelModel):
        model = WithEffects(model, ())
    if not isinstance(model, WithEffects):
        raise TypeError(f"model: expected a model or WithEffects, got {type(model).__name__}")
    return model


def _omega(omega: Any) -> np.ndarray:
    """``omega`` (rad/s) as a C-contiguous 1-D float array, finite and > 0."""
    w = np.ascontiguousarray(np.atleast_1d(np.asarray(omega, dtype=np.float64)))
    if w.ndim != 1 or np.any(~np.isfinite(w)) or np.any(w <= 0):
        raise ValueError("omega: frequencies must be finite and > 0")
    return w


def frequency_response(
    model: LowerLevelModel | WithEffects, upper: UpperLevel, omega: Any, *, v: float = 0.0,
    side: int = 0, hold: float = 0.0,
) -> np.ndarray:
    """The follower's exact frequency response ``H(jw)`` (predecessor speed to
    follower speed; paper Eq. 8 with the true delays), complex, over ``omega`` (rad/s,
    finite and > 0): the one frequency response of the library
    (:func:`avll.studies.openacc.transfer_gain` is its modulus).

    ``model``: a base model or an :class:`avll.WithEffects`, linearised at the speed
    ``v`` (m/s; for ``asymmetric``, on ``side``: 1 accelerating, -1 braking, 0 their
    average): the lower level ``G_fb = G e^{-command_delay s} / (1 - K G + beta/s)``
    (:meth:`avll.WithEffects.linear` with ``terms=True``: a ``delay`` outside the
    inner loop, the speed feedback ``beta`` of ``speed_drag``/``road_load``), and the
    upper level with its structures (:meth:`avll.WithEffects.upper_linear`: the
    radar terms' perception delay ``e^{-delay s}``, the feedforward ``ka s/(tau s +
    1)`` on the perceived predecessor speed, the gains of ``closing`` (averaged) and
    ``speed_gains`` (at ``v``)). Computed in Rust (``rust/effects/mod.rs``,
    ``response``); :func:`avll.reference.effects.frequency_response` is its numpy
    oracle.

    ``hold`` (s): the sample period the loop runs at (0: the continuous loop of Eq. 8).
    A rollout at ``dt`` holds the law's command and the inner feedback over each
    sample, which below the Nyquist frequency acts as a dead time of ``dt / 2`` added
    to the lower level's: a model calibrated on runs sampled at ``dt`` describes the
    follower through ``hold=dt`` (see ``docs/guide/intervals.md``, "The sampled
    loop")."""
    model = _with_effects(model)
    if not isinstance(upper, UpperLevel):
        raise TypeError(f"upper: expected an avll.UpperLevel, got {upper!r:.60}")
    w = _omega(omega)
    return np.asarray(_core.follower_response(
        model.base.name, model.base.values(), list(model.effect_names),
        [float(x) for e in model.effects for x in e.to_array()], float(upper.kg),
        float(upper.kv), float(upper.Tg), float(upper.Gmin), w, float(v), int(side),
        float(hold)))


def _rows_arg(model: Any, rows: Any, effects: Sequence[str]) -> tuple[str, list[str], np.ndarray]:
    """The model's name, the effects (canonical order) and the rows as a C-contiguous
    float array, checked (``ValueError`` naming the argument)."""
    name = model_class(model).name
    for e in effects:
        if e not in EFFECTS:
            raise ValueError(f"effects: unknown effect {e!r}; known: {', '.join(EFFECTS)}")
    effs = list(canonical(list(effects)))
    if list(effects) != effs:
        raise ValueError(f"effects: give them in their canonical order ({', '.join(effs)}), "
                         f"the order of the rows' columns")
    try:
        r = np.ascontiguousarray(np.asarray(rows, dtype=np.float64))
    except (TypeError, ValueError):
        raise ValueError(f"rows: expected a 2-D array of numbers, got {rows!r:.60}") from None
    if r.ndim == 1:
        r = r[None, :]
    if r.ndim != 2:
        raise ValueError(f"rows: expected a 2-D array (rows x parameters), got shape {r.shape}")
    return name, effs, r


def frequency_response_rows(
    model: Any, rows: Any, omega: Any, *, effects: Sequence[str] = (), v: float = 0.0,
    side: int = 0, threads: int = 0, hold: float = 0.0,
) -> np.ndarray:
    """:func:`frequency_response` of many parameter rows at once, in Rust (one call, in
    parallel over rows): ``rows`` (``n x d``) are ``[model | effects | kg, kv, Tg,
    Gmin]`` -- e.g. a calibration's resamples (:meth:`avll.Uncertainty.rows`) -- with the
    ``effects``' parameters in their canonical order (the order of ``effects``, which
    must be canonical), each linearised at the speed ``v`` on ``side``, the loop run at
    sample period ``hold`` (:func:`frequency_response`). Returns the complex ``H(jw)``
    (``n x len(omega)``), NaN for a row whose parameters the model, an effect or the
    law refuses."""
    name, effs, r = _rows_arg(model, rows, effects)
    return np.asarray(_core.follower_response_rows(
        name, r, effs, _omega(omega), v=float(v), side=int(side), threads=check_threads(threads),
        hold=float(hold)))


def band_amplification_rows(
    model: Any, rows: Any, lead_v: Any, dt: float, band: Sequence[float] | None = None, *,
    effects: Sequence[str] = (), v: float | None = None, trim: float | None = None,
    threads: int = 0, hold: float | None = None,
) -> np.ndarray:
    """The band amplification of many parameter rows (:func:`frequency_response_rows`):
    ``sqrt(sum |H(f)|^2 w(f))`` over the periodogram bins of the band-passed predecessor
    speed ``lead_v`` (:func:`avll.spectral.band_weights`, the study's weighting), one
    value per row (NaN without a bin or for a refused row). ``v`` is the linearisation
    speed (default: the mean of ``lead_v``); ``hold`` the sample period of the loop
    (:func:`frequency_response`; default ``dt``: rows calibrated on runs sampled at
    ``dt``)."""
    from .spectral import DEFAULT_BAND, TRIM, band_weights

    lv = np.asarray(lead_v, dtype=np.float64)
    f, w = band_weights(lv, dt, DEFAULT_BAND if band is None else band,
                        TRIM if trim is None else trim)
    _, _, r = _rows_arg(model, rows, effects)
    if f.size == 0:
        return np.full(r.shape[0], np.nan)
    vv = float(np.mean(lv)) if v is None else float(v)
    h = np.abs(frequency_response_rows(model, r, 2.0 * np.pi * f, effects=effects, v=vv,
                                       threads=threads,
                                       hold=float(dt) if hold is None else hold))
    return np.asarray(np.sqrt(np.sum(h * h * w[None, :], axis=1)))


def stability_codes_rows(
    model: Any, rows: Any, *, effects: Sequence[str] = (), v: float = 0.0, side: int = 0,
    budget: int = EXACT_BUDGET, threads: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Certified stability codes (0 locally unstable, 1 string unstable, 2 string
    stable) of the closed loops of many parameter rows ``[model | effects | kg, kv, Tg,
    Gmin]`` linearised at ``v``, and whether each is certified: every delay kept exactly
    (the lower level's dead time, a command ``delay`` outside its inner loop,
    ``perception``'s delay of the radar terms) with ``feedforward``'s filter and the
    speed feedback of ``speed_drag``/``road_load`` (``rust/effects/follower.rs``: the
    argument principle for the local test, the sign of ``|D|^2 - |N|^2`` for the string
    test, both swept in interval arithmetic, so a verdict is a proof, not a sample; an
    undecided test -- a loop on the boundary, or over ``budget`` interval evaluations --
    gives code 0 or 1 uncertified). Without structures the verdicts are those of
    :func:`avll.stability.exact_delay_codes`."""
    name, effs, r = _rows_arg(model, rows, effects)
    c, ok = _core.follower_codes_rows(name, r, effs, v=float(v), side=int(side),
                                      budget=check_int(budget, "budget", min=1),
                                      threads=check_threads(threads))
    return np.asarray(c, dtype=np.int64), np.asarray(ok, dtype=bool)


_KEYS = ("b1", "b0", "a2", "a1", "Td", "K")


@dataclass(frozen=True)
class _SmallSignal:
    """The small-signal parts the report shows: the lower level's coefficients, its
    speed feedback (``drag``) and outer command delay (``tau``), whether an
    observation-only effect is present, and the upper level's small-signal form."""

    coeffs: dict[str, float]
    drag: float
    tau: float
    observation: bool
    upper: dict[str, float]

    @property
    def engine(self) -> bool:
        """Whether the stability engine's form (a second-order ``Linear`` under Eq. 3)
        holds it: no speed feedback, no outer delay, no perception delay, no
        feedforward."""
        u = self.upper
        return not (self.drag or self.tau or u["delay"] or u["ff_gain"])


def _small_signal(model: WithEffects, upper: UpperLevel, v0: float, side: int) -> _SmallSignal:
    """The small-signal form; ``ValueError`` with the reason when there is none."""
    d = dict(model.linear(v=v0, side=side, terms=True))
    obs = bool(d.get("obs_tau", 0.0) or d.get("obs_bias", 0.0))
    coeffs = {k: float(d[k]) for k in _KEYS}
    tau = float(d["command_delay"])
    if coeffs["K"] == 0.0:  # without inner feedback an outer delay is part of Td
        coeffs["Td"] += tau
        tau = 0.0
    return _SmallSignal(coeffs, float(d["speed_feedback"]), tau, obs,
                        model.upper_linear(upper, v=v0))


def _none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True)
class LinearStability:
    """Stability of one linearisation (``label``: ``base``, ``with effects``,
    ``with effects, accelerating`` or ``with effects, braking``). ``None`` fields
    are explained in ``notes``. ``gain_at_omega`` is ``|H(jw)|`` at the disturbance
    frequency; ``peak_gain`` / ``peak_omega`` the sampled maximum over
    :data:`OMEGA_GRID`; ``code`` the map code at the given gains; ``tg_min_at_gains``
    the smallest string-stable ``Tg`` at the given ``kg, kv``; ``min_stable_tg`` and
    ``kv_threshold`` the extrema over the boxes given to :func:`effect_stability`."""

    label: str
    side: int
    coeffs: dict[str, float] | None
    drag: float
    outer_delay: float
    gain_at_omega: float | None
    peak_gain: float | None
    peak_omega: float | None
    code: int | None
    tg_min_at_gains: float | None
    min_stable_tg: float | None
    kv_threshold: float | None
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (the fields, ``notes`` as a list)."""
        return {**asdict(self), "notes": list(self.notes)}


def _linear_entry(
    label: str, model: WithEffects, side: int, v0: float, upper: UpperLevel, omega: float,
    boxes: dict[str, tuple[float, float]], pade_order: int, thresholds: bool,
) -> LinearStability:
    notes: list[str] = []
    try:
        ss = _small_signal(model, upper, v0, side)
    except ValueError as e:
        return LinearStability(label, side, None, 0.0, 0.0, None, None, None, None, None, None,
                               None, (f"no small-signal form: {e}",))  # fmt: skip
    h = np.abs(frequency_response(model, upper, OMEGA_GRID, v=v0, side=side))
    h_w = float(np.abs(frequency_response(model, upper, [omega], v=v0, side=side))[0])
    j = int(np.argmax(h))
    code = tg_at = tg_min = kv_thr = None
    if ss.observation:
        notes.append("sensor lag/bias act on the observed acceleration only: no effect on "
                     "stability")
    # The law as the small signal sees it (upper-level structures: closing's average
    # gains, speed_gains' gains and time-gap slope at v0).
    u = ss.upper
    if model.upper and ss.engine:
        notes.append(f"upper-level structures: the engine's verdicts are at the small-signal "
                     f"gains kg={u['kg']:.4g}, kv={u['kv']:.4g}, Tg={u['Tg']:.4g} s")
    if not ss.engine:
        notes.append("speed feedback, outer command delay, perception delay or feedforward: "
                     "the stability engine's form (a second-order lower level under Eq. 3) "
                     "does not hold it; |H(jw)| only")
    else:
        try:
            eq = equivalent_model(model, v=v0, side=side)
        except ValueError as e:
            eq = None
            notes.append(f"no engine model: {e}")
        if eq is not None:
            code = int(stability_points(eq, u["kg"], u["Tg"], u["kv"], pade_order))
            ivs = stable_intervals(eq, "tg", kg=u["kg"], kv=u["kv"], pade_order=pade_order,
                                   search_range=boxes["tg"])  # fmt: skip
            tg_at = float(ivs[0][0]) if ivs else None
            if not ivs:
                notes.append(f"no string-stable Tg in {list(boxes['tg'])} at kg={u['kg']:g}, "
                             f"kv={u['kv']:g}")
            if thresholds:
                e1 = min_stable_tg(eq, boxes["kg"], boxes["kv"], pade_order,
                                   tg_range=boxes["tg"])  # fmt: skip
                e2 = kv_supremum(eq, boxes["kg"], boxes["tg"], pade_order)
                tg_min, kv_thr = _none(e1.value), _none(e2.value)
    return LinearStability(
        label, side, {k: float(v) for k, v in ss.coeffs.items()}, float(ss.drag),
        float(ss.tau), _none(h_w), _none(float(h[j])), float(OMEGA_GRID[j]), code, tg_at,
        tg_min, kv_thr, tuple(notes),
    )  # fmt: skip


@dataclass(frozen=True)
class EffectStability:
    """The result of :func:`effect_stability`.

    ``linear``: the :class:`LinearStability` entries (``base`` first).
    ``amplitudes`` (m/s, the leader's speed amplitude) x cars: ``speed_amplitude``
    (shape ``(n_amp, n_cars + 1)``, the fitted fundamental amplitude of each car's
    speed, the leader first), ``amplification`` (shape ``(n_amp, n_cars)``, car ``i``
    over car ``i-1``; NaN where a car diverged), ``half_range`` (half the
    peak-to-peak speed over the measurement window, harmonics included).
    ``range_amplification``: the same ratio of ``half_range`` (what a driver sees:
    with strong nonlinearity the oscillation moves into harmonics and slower
    components, so the two ratios differ; for a linear model both are ``|H(jw)|``).
    ``min_speed`` (shape ``(n_amp, n_cars + 1)``): the lowest speed over the
    measurement window; the lower-level models have no standstill, so a negative value
    is flagged in ``notes`` (the simulation is not physical there).
    ``drift`` (shape ``(n_amp, n_cars + 1)``): the fundamental amplitude fitted on the
    second half of the measurement window over the first half's, minus 1; beyond
    ``DRIFT_TOL`` in magnitude the car is not in a steady oscillation (e.g. a locally
    unstable loop that grows) and ``notes`` says so: its amplification then describes
    growth, not a steady ratio.
    ``linear_gain``: ``|H(jw)|`` of the with-effects linearisation at ``omega``
    (side average), the value a linear model's amplification equals."""

    model: str
    effects: tuple[str, ...]
    amplitude_dependent: tuple[str, ...]
    upper: UpperLevel
    v0: float
    omega: float
    dt: float
    warm_periods: int
    measure_periods: int
    linear: tuple[LinearStability, ...]
    amplitudes: np.ndarray
    speed_amplitude: np.ndarray
    amplification: np.ndarray
    half_range: np.ndarray
    range_amplification: np.ndarray
    min_speed: np.ndarray
    drift: np.ndarray
    linear_gain: float | None
    notes: tuple[str, ...] = field(default=())

    @property
    def period(self) -> float:
        """The disturbance period ``2 pi / omega`` (s)."""
        return 2 * math.pi / self.omega

    def mean_amplification(self) -> np.ndarray:
        """Geometric mean of the per-car amplification for each amplitude (NaN when a
        car diverged)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.exp(np.mean(np.log(self.amplification), axis=1))

    def to_dict(self) -> dict[str, Any]:
        """A strict-JSON dict: non-finite numbers are ``null`` with the reason in
        ``null_reasons``."""

        def arr(a: np.ndarray) -> list[Any]:
            return [arr(x) if isinstance(x, np.ndarray) else _none(float(x)) for x in a]

        reasons = {}
        if not np.all(np.isfinite(self.amplification)):
            reasons["amplification"] = ("null where the car (or one ahead of it) diverged or "
                                        "its fundamental amplitude is zero")
        if not np.all(np.isfinite(self.range_amplification)):
            reasons["range_amplification"] = ("null where the car (or one ahead of it) "
                                              "diverged or did not move")
        if not np.all(np.isfinite(self.speed_amplitude)):
            reasons["speed_amplitude"] = "null for the cars behind a diverged car"
            reasons["half_range"] = reasons["min_speed"] = reasons["speed_amplitude"]
        if self.linear_gain is None:
            reasons["linear_gain"] = "the model with effects has no small-signal form"
        return {
            "model": self.model,
            "effects": list(self.effects),
            "amplitude_dependent": list(self.amplitude_dependent),
            "upper": {"kg": self.upper.kg, "kv": self.upper.kv, "Tg": self.upper.Tg,
                      "Gmin": self.upper.Gmin},
            "v0": self.v0, "omega": self.omega, "period": self.period, "dt": self.dt,
            "warm_periods": self.warm_periods, "measure_periods": self.measure_periods,
            "linear": [e.to_dict() for e in self.linear],
            "linear_gain": self.linear_gain,
            "amplitudes": arr(self.amplitudes),
            "speed_amplitude": arr(self.speed_amplitude),
            "amplification": arr(self.amplification),
            "mean_amplification": arr(self.mean_amplification()),
            "half_range": arr(self.half_range),
            "range_amplification": arr(self.range_amplification),
            "min_speed": arr(self.min_speed),
            "drift": arr(self.drift),
            "notes": list(self.notes),
            "null_reasons": reasons,
        }  # fmt: skip

    def plot(self) -> Figure:
        """Two panels: the amplification per car against the disturbance amplitude
        (with the linearised ``|H(jw)|``), and the speed amplitude along the platoon
        relative to the leader's (:func:`avll.plotting.amplitude_amplification`)."""
        from .plotting import amplitude_amplification

        return amplitude_amplification(self)


def sine_leader(v0: float, amplitude: float, omega: float, dt: float, warm_periods: int,
                measure_periods: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The leader of the time-domain experiment (see the module doc): ``(t, x, v,
    measured)``, its sample times, position and speed ``v0 + A w(t) sin(w t)`` (the
    raised-cosine ramp ``w`` over the first period), and the mask of the
    ``measure_periods`` periods after the ``warm_periods`` first."""
    per = 2 * math.pi / omega
    n = int(math.ceil((warm_periods + measure_periods) * per / dt)) + 1
    t = np.arange(n) * dt
    ramp = np.where(t < per, 0.5 * (1 - np.cos(np.pi * t / per)), 1.0)
    measured = (t >= warm_periods * per) & (t < (warm_periods + measure_periods) * per)
    v = v0 + amplitude * ramp * np.sin(omega * t)
    x = np.concatenate([[0.0], np.cumsum(0.5 * dt * (v[1:] + v[:-1]))])
    return t, x, v, measured


def fundamental_amplitude(t: np.ndarray, v: np.ndarray, omega: float) -> float:
    """The amplitude ``sqrt(s² + c²)`` of ``v`` fitted by least squares with
    ``c0 + c1 (t - mean t) + s sin(w t) + c cos(w t)``."""
    tc = t - t.mean()
    x = np.column_stack([np.ones_like(t), tc, np.sin(omega * t), np.cos(omega * t)])
    coef, *_ = np.linalg.lstsq(x, v, rcond=None)
    return float(math.hypot(coef[2], coef[3]))


def car_ratios(x: np.ndarray, amps: np.ndarray) -> np.ndarray:
    """``x`` (amplitudes x cars, the leader first) of each car over the car ahead's; NaN
    where not finite. A car whose value is below 1e-6 A did not oscillate (e.g. a dead
    band swallowed the disturbance): the ratio behind it is undefined."""
    prev = x[:, :-1]
    ok = np.isfinite(prev) & (prev > 1e-6 * amps[:, None])
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(ok, x[:, 1:] / np.where(ok, prev, 1.0), np.nan)
    r[~np.isfinite(r)] = np.nan
    return r


def _upper_arg(upper: Any) -> UpperLevel:
    if isinstance(upper, UpperLevel):
        return upper
    if isinstance(upper, Mapping):
        unknown = set(upper) - {"kg", "kv", "Tg", "Gmin"}
        if unknown:
            raise ValueError(f"upper: unknown keys {sorted(unknown)} (kg, kv, Tg, Gmin)")
        if "kg" not in upper or "Tg" not in upper:
            raise ValueError("upper: needs at least 'kg' and 'Tg'")
        return UpperLevel(**{k: check_number(v, f"upper[{k!r}]") for k, v in upper.items()})
    raise TypeError(f"upper: expected an avll.UpperLevel or a dict, got {type(upper).__name__}")


def effect_stability(
    model: WithEffects | LowerLevelModel,
    upper: UpperLevel | Mapping[str, float],
    *,
    v0: float = 15.0,
    amplitudes: Sequence[float] = (0.1, 0.5, 1.0, 2.0, 4.0),
    n_cars: int = 5,
    period: float | str = 20.0,
    dt: float = 0.05,
    warm_periods: int = 6,
    measure_periods: int = 4,
    pade_order: int = PADE_ORDER,
    thresholds: bool = True,
    kg_range: tuple[float, float] = MIN_TG_BOX["kg"],
    kv_range: tuple[float, float] = MIN_TG_BOX["kv"],
    tg_range: tuple[float, float] = MIN_TG_BOX["Tg"],
    progress: bool | str = False,
) -> EffectStability:
    """The stability of ``model`` (a base model or base + effects) under the
    constant-time-gap ``upper`` level (an :class:`avll.UpperLevel` or a dict with
    ``kg``, ``Tg`` and optionally ``kv``, ``Gmin``, as in ``LoopResult.to_dict()``),
    linearised at ``v0`` (m/s) and simulated in the time domain for leader speed
    amplitudes ``amplitudes`` (m/s) with ``n_cars`` followers (see the module doc for
    the method).

    ``period``: the disturbance period in s, or ``"peak"`` for the frequency of the
    largest ``|H(jw)|`` of the linearised model with effects (base model if none)
    between periods of 4 and 60 s. ``warm_periods`` periods are simulated before the
    ``measure_periods`` whose fundamental amplitude is fitted. ``thresholds=False``
    skips the (slower, ~1 s each) extrema searches; ``kg_range``, ``kv_range`` and
    ``tg_range`` are their boxes (the paper's: Tg in [0, 15] s). ``progress`` shows
    the amplitudes done (one platoon each) on stderr (``True``/``"auto"``, ``"bar"``,
    ``"log"``, ``False``/``"none"``: see :mod:`avll.progress`)."""
    model = _with_effects(model)
    upper = _upper_arg(upper)
    v0 = check_number(v0, "v0", positive=True)
    dt = check_number(dt, "dt", positive=True)
    n_cars = check_int(n_cars, "n_cars", min=1, max=200)
    resolve_mode(progress)  # a bad mode refused before any work
    warm_periods = check_int(warm_periods, "warm_periods", min=1)
    measure_periods = check_int(measure_periods, "measure_periods", min=1)
    amps = np.array([check_number(a, "amplitudes", positive=True) for a in amplitudes])
    if amps.size == 0:
        raise ValueError("amplitudes: give at least one amplitude")
    if np.any(amps >= v0):
        raise ValueError(f"amplitudes: must be < v0 = {v0:g} m/s (the leader would reverse)")
    boxes: dict[str, tuple[float, float]] = {}
    for key, rng in (("kg", kg_range), ("kv", kv_range), ("tg", tg_range)):
        lo, hi = (check_number(x, f"{key}_range") for x in rng)
        if not lo < hi:
            raise ValueError(f"{key}_range: must be (lo, hi) with lo < hi, got {rng!r}")
        boxes[key] = (lo, hi)
    names = model.effect_names
    notes: list[str] = []
    base = WithEffects(model.base, ())
    sides = (0, 1, -1) if "asymmetric" in names else (0,)
    labels = {0: "with effects", 1: "with effects, accelerating", -1: "with effects, braking"}
    # Frequency.
    if period == "peak":
        grid = np.linspace(2 * math.pi / 60.0, 2 * math.pi / 4.0, 400)
        for m in (model, base):
            try:
                lin = np.abs(frequency_response(m, upper, grid, v=v0))
                break
            except ValueError:
                pass
        else:
            raise ValueError("period: 'peak' needs a linearisable model; give a period in s")
        omega = float(grid[int(np.argmax(lin))])
    elif isinstance(period, str):
        raise ValueError(f"period: a number of seconds or 'peak', got {period!r}")
    else:
        omega = 2 * math.pi / check_number(period, "period", positive=True)
    if 2 * math.pi / omega < 20 * dt:
        raise ValueError(f"period: {2 * math.pi / omega:g} s is under 20 samples of dt={dt:g}")
    entries = [_linear_entry("base", base, 0, v0, upper, omega, boxes, pade_order, thresholds)]
    if names:
        entries += [_linear_entry(labels[s], model, s, v0, upper, omega, boxes, pade_order,
                                  thresholds) for s in sides]  # fmt: skip
    lin_gain = entries[1].gain_at_omega if names else entries[0].gain_at_omega
    # Time domain.
    t, _, _, meas = sine_leader(v0, 0.0, omega, dt, warm_periods, measure_periods)
    exo = {str(EFFECTS[e].exo): np.zeros(t.size) for e in names if EFFECTS[e].exo}
    n_amp = amps.size
    speed_amp, half, vmin, drift = (np.full((n_amp, n_cars + 1), np.nan) for _ in range(4))
    tm = t[meas]
    first_half = tm < tm[0] + 0.5 * (tm[-1] - tm[0] + dt)

    def fit(v: np.ndarray) -> tuple[float, float]:
        vm = v[meas]
        a1 = fundamental_amplitude(tm[first_half], vm[first_half], omega)
        a2 = fundamental_amplitude(tm[~first_half], vm[~first_half], omega)
        return fundamental_amplitude(tm, vm, omega), (a2 / a1 - 1.0 if a1 > 0 else math.nan)

    from .progress import Progress

    with Progress(n_amp, "platoon", unit="amplitude", mode=progress) as bar:
        for k, a in enumerate(amps):
            _, lx, lv, _ = sine_leader(v0, a, omega, dt, warm_periods, measure_periods)
            # every follower at once, time-major in the Rust platoon
            tr = platoon(model, lx, lv, dt, upper, n_cars, exo=exo)
            vs = np.vstack([lv, tr.v])
            alive = np.all(np.isfinite(tr.v), axis=1) & np.all(np.isfinite(tr.x), axis=1)
            n_ok = int(np.argmin(alive)) if not alive.all() else n_cars
            if n_ok < n_cars:
                notes.append(f"A={a:g} m/s: car {n_ok + 1} diverged")
            for i in range(n_ok + 1):
                speed_amp[k, i], drift[k, i] = fit(vs[i])
                half[k, i] = 0.5 * float(np.ptp(vs[i][meas]))
                vmin[k, i] = float(vs[i][meas].min())
            bar.update(1)
    ampl, rampl = car_ratios(speed_amp, amps), car_ratios(half, amps)
    for k, a in enumerate(amps):
        moving = np.flatnonzero(np.abs(drift[k, 1:]) > DRIFT_TOL)
        if moving.size:
            i = int(moving[0]) + 1
            notes.append(f"A={a:g} m/s: car {i} is not in a steady oscillation (fundamental "
                         f"{100 * drift[k, i]:+.0f} % from the first to the second half of "
                         "the window)")
        neg = np.flatnonzero(vmin[k, 1:] < 0)
        if neg.size:
            notes.append(f"A={a:g} m/s: car {int(neg[0]) + 1} reaches a negative speed "
                         f"({vmin[k, 1 + neg[0]]:.3g} m/s; the model has no standstill)")
    return EffectStability(
        model=model.name, effects=names,
        amplitude_dependent=tuple(e for e in names if e in AMPLITUDE_DEPENDENT),
        upper=upper, v0=float(v0), omega=omega, dt=float(dt), warm_periods=warm_periods,
        measure_periods=measure_periods, linear=tuple(entries), amplitudes=amps,
        speed_amplitude=speed_amp, amplification=ampl, half_range=half,
        range_amplification=rampl, min_speed=vmin, drift=drift,
        linear_gain=lin_gain, notes=tuple(notes),
    )  # fmt: skip
