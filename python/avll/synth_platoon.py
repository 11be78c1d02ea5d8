"""Synthetic platoons with a known truth, in the OpenACC loader's form.

A leader and ``n`` followers, each follower with its own known lower level (any of the
three models, optionally with effects) and constant-time-gap upper level (paper Eq. 3:
``kg, kv, Tg, Gmin``), recorded as a GNSS-equipped campaign would record them. The
runs have the form :func:`avll.io.openacc_native.load_openacc_native` returns (one
:class:`avll.Run` per follower: ``v``, ``x`` from 0, ``lead_x = x + spacing``,
``lead_v`` the predecessor's *measured* speed, ``a`` derived from the measured speed as
the loader does, ``meta`` with ``file``, ``car``, ``setting``, ``position``, ...), so the
OpenACC study and the estimators consume them unchanged; ``meta["truth"]`` and
:attr:`SynthPlatoon.truth` hold what the estimators should find.

**The plant (near-continuous).**
Every car is simulated by the library's closed loop (:func:`avll.closed_loop`)
at ``fine_dt`` (:data:`FINE_DT`, 0.01 s by default: the upper law evaluated and the
lower level stepped at 100 Hz), behind the previous car's *true* position and speed
(the radar sees the true spacing), then sampled every ``dt`` (0.1 s). A follower-side
disturbance -- the road, the wind, the ACC's own hunting, uncorrelated with the
predecessor -- enters as an acceleration ``d(t)`` added to the car's acceleration,
through the library's ``grade`` effect (``a += -g_eff exo_grade`` with ``g_eff = 1``,
``exo_grade = -d``): ``d`` is an AR(1) (Ornstein-Uhlenbeck) process of standard deviation
``disturbance_std`` (m/s², :data:`DISTURBANCE_STD` by default) and correlation time
``disturbance_tau`` (s, :data:`DISTURBANCE_TAU`), per car.

**The leader.**
Cruise at ``v_mean`` plus a sum of ``n_tones`` sinusoids of random frequencies
(log-uniform over ``band``, 0.02-0.2 Hz by default: periods of 5-50 s) and phases,
scaled to the band RMS ``band_rms``, plus three slow tones (0.003-0.015 Hz) of RMS
``drift_rms`` below the band (real leaders drift too, and the estimators must not
mistake it for the band). The oscillation fades in over ``ramp`` s from a steady state,
so every follower starts at equilibrium (speed ``v_mean``, gap ``Gmin + Tg v_mean``,
lower level at rest) and no start transient enters the record; the first ``warmup`` s
are simulated but not recorded. Position is the exact integral of the speed.

**Equipment** (:data:`EQUIPMENT`).
Measurement noise per campaign's equipment, each a white part plus a smooth coloured
part (white noise through two first-order lags of time constant ``*_tau``), on speed
(m/s), position (arc length, m) and spacing (m). A car's speed noise is the same
realisation in its own run (``v``) and in its follower's (``lead_v``), as in a file. The presets:

* ``"zalazone"``: VBOX-like, fused and smoothed (ZalaZone's notes: VBOX, u-blox 9 and
  a tracker app "fused and interpolated to 10 Hz using 2nd degree B-splines"). The
  white speed noise left in the files is tiny (the robust second-difference level of
  the followers' ``Speed2..11`` in ``short_setting/dynamic_part12.csv`` is
  0.0005-0.0013 m/s, their >1 Hz RMS 0.0008-0.003 m/s), so the noise must be slow:
  0.02 m/s smooth coloured noise with 1 s time constants (the VBOX's quoted speed
  accuracy is 0.1 km/h = 0.028 m/s) plus 0.001 m/s white; position 0.05 m coloured
  (5 s) plus 0.01 m white; spacing 0.1 m coloured (5 s) plus 0.002 m white.
* ``"jrc"``: an unfiltered u-blox-9-like receiver (JRC's notes: "Ublox 9 and OBD
  ... Data are not filtered", raw Doppler speed, cubic splines to 10 Hz). The
  second-difference level of ``Speed1..3`` in JRC low-speed ``part1.csv`` and
  ``part11.csv`` is 0.012-0.064 m/s (>1 Hz RMS 0.054-0.074 m/s): 0.05 m/s white plus
  0.02 m/s coloured (2 s); position 0.3 m white plus 0.5 m coloured (10 s: the slow
  wander of a standalone receiver); spacing from two such receivers, 0.5 m coloured
  (10 s) plus 0.02 m white (the files' ``IVS`` second-difference level after the
  splines is 0.005-0.008 m).
* ``"none"``: no noise (the true states).

**The truth.**
Per follower (:class:`CarTruth`): the model and its parameters, the upper law, the
effects, the disturbance, the closed loop's ``|H(j 2 pi f)|`` (paper Eq. 8 with the true
delay, :func:`avll.studies.openacc.transfer_gain`; with effects, on their small-signal
equivalent at the mean speed) on the band's bins, the **band gain** -- ``|H|`` as an RMS
gain on the true predecessor's band-passed speed spectrum
(:func:`avll.studies.openacc.predicted_amplification` with the true car), the quantity
both measured estimators aim at -- and ``Tg + Gmin / v_mean`` (the identified
combination, ``v_mean`` the car's true mean speed over the record). The band RMS
ratio of the *true* speeds (``rms_ratio_true``) is kept as well: it differs from the
band gain by the follower's disturbance alone.

**Hidden upper-level structure** (:class:`HiddenUpper`, the ``hidden`` argument).
Real ACCs are more than Eq. 3, and a generator that only knows Eq. 3 cannot test
whether the library finds what they have. A follower can carry structures in its
upper level that the generator implements with its own law (``rust/sim/synth.rs``,
written independently of the library's upper-level effects, with other mechanisms):
a **radar** that measures the gap and relative speed at its own update period (a random
phase per car) and delivers them a latency later, held in between; a **feedforward**
on the perceived predecessor speed differenced over a window; a smooth
**closing/opening asymmetry** (the gap and speed terms scaled by a logistic blend
between 1 and ``ratio``). The truth's ``|H|`` then comes from this law's own
small-signal form (:meth:`HiddenUpper.response`: the radar as a latency times the
zero-order hold of its period, the window's difference, the blend's average slope
``(1 + ratio)/2``, the describing function of the asymmetry's odd part; its even part
shifts the mean gap and makes even harmonics, which in the closed loop return into the
fundamental: an approximation of the order ``((ratio - 1)/(ratio + 1))^2``, 3 % at
``ratio = 1.8`` and 0.1 Hz in the tests), and ``truth["hidden"]`` lists the structures.

Seeded: one random stream per ``(seed, purpose, car)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from . import _core
from ._limits import check_int, check_number, check_seed
from .data import Run
from .effects import Effect, Grade, WithEffects
from .models import LowerLevelModel, UpperLevel, model_class
from .paper import MODELS, TABLE_II_PARAMS
from .rollout import Trajectory, closed_loop
from .spectral import DEFAULT_BAND, check_band
from .synth import _ar1

__all__ = [
    "Equipment",
    "EQUIPMENT",
    "HiddenUpper",
    "CarTruth",
    "SynthPlatoon",
    "leader_speed",
    "DISTURBANCE_STD",
    "DISTURBANCE_TAU",
    "FINE_DT",
    "random_car",
    "synth_platoon",
    "validate_amplification",
    "validate_intervals",
    "StructureRow",
    "StructureSummary",
    "StructureCheck",
    "validate_structure",
    "synth_campaign",
    "SelectionRow",
    "SelectionSummary",
    "SelectionCheck",
    "validate_selection",
]

#: The follower-side disturbance every car gets unless told otherwise (one decision for
#: :class:`CarTruth`, :func:`random_car`, :func:`synth_platoon` and
#: :func:`synth_campaign`): an AR(1) acceleration of standard deviation 0.05 m/s² ...
DISTURBANCE_STD: float = 0.05
#: ... and correlation time 3 s (the road, the wind, the ACC's own hunting: slow against
#: the recorded 0.1 s, uncorrelated with the predecessor; see the module doc).
DISTURBANCE_TAU: float = 3.0
#: The plant's period (s) unless told otherwise: the upper law evaluated and the lower
#: level stepped at 100 Hz, ten steps per recorded 0.1 s sample (near-continuous, see
#: the module doc).
FINE_DT: float = 0.01


@dataclass(frozen=True)
class Equipment:
    """Measurement noise (standard deviations; ``*_tau`` correlation times in s of the
    coloured parts): speed (m/s), position (m), spacing (m)."""

    name: str
    speed_white: float = 0.0
    speed_coloured: float = 0.0
    speed_tau: float = 1.0
    position_white: float = 0.0
    position_coloured: float = 0.0
    position_tau: float = 5.0
    spacing_white: float = 0.0
    spacing_coloured: float = 0.0
    spacing_tau: float = 5.0

    def __post_init__(self) -> None:
        for k in ("speed_white", "speed_coloured", "position_white", "position_coloured",
                  "spacing_white", "spacing_coloured"):
            check_number(getattr(self, k), k, nonneg=True)
        for k in ("speed_tau", "position_tau", "spacing_tau"):
            check_number(getattr(self, k), k, positive=True)


#: Equipment presets (see the module doc for the justification of each number).
EQUIPMENT: dict[str, Equipment] = {
    "zalazone": Equipment("zalazone", speed_white=0.001, speed_coloured=0.02, speed_tau=1.0,
                          position_white=0.01, position_coloured=0.05, position_tau=5.0,
                          spacing_white=0.002, spacing_coloured=0.1, spacing_tau=5.0),
    "jrc": Equipment("jrc", speed_white=0.05, speed_coloured=0.02, speed_tau=2.0,
                     position_white=0.3, position_coloured=0.5, position_tau=10.0,
                     spacing_white=0.02, spacing_coloured=0.5, spacing_tau=10.0),
    "none": Equipment("none"),
}


@dataclass(frozen=True)
class HiddenUpper:
    """Structures hidden in a follower's upper level (the generator's own law, see the
    module doc; neutral by default): a radar of update period ``radar_period`` (s, 0:
    every sample; each car a random phase) and latency ``radar_latency`` (s); a
    feedforward ``ff_gain (vp(t) - vp(t - ff_window)) / ff_window`` on the perceived
    predecessor speed (``ff_gain`` in s); the gap and speed terms scaled by ``1 +
    (ratio - 1) / (1 + exp(z / width))`` of the gap error (``width_gap``, m) and the
    relative speed (``width_speed``, m/s): ``ratio`` on the closing side, 1 on the
    opening side."""

    radar_period: float = 0.0
    radar_latency: float = 0.0
    ff_gain: float = 0.0
    ff_window: float = 1.0
    ratio: float = 1.0
    width_gap: float = 1.0
    width_speed: float = 0.2

    def __post_init__(self) -> None:
        for k in ("radar_period", "radar_latency", "ff_gain"):
            check_number(getattr(self, k), k, nonneg=True)
        for k in ("ff_window", "ratio", "width_gap", "width_speed"):
            check_number(getattr(self, k), k, positive=True)

    @property
    def neutral(self) -> bool:
        """Whether the law is Eq. 3 itself."""
        return (self.radar_period == 0 and self.radar_latency == 0 and self.ff_gain == 0
                and self.ratio == 1)

    def row(self, phase: float) -> list[float]:
        """The law's parameters in the order of the Rust generator (``HiddenParams``)."""
        return [self.radar_period, phase, self.radar_latency, self.ff_gain, self.ff_window,
                self.ratio, self.width_gap, self.width_speed]

    def response(self, model: Any, upper: UpperLevel, omega: Any, *, v: float,
                 fine_dt: float) -> np.ndarray:
        """The follower's ``H(jw)`` with this law (small signal about the speed ``v``;
        ``model`` a base model or an :class:`avll.WithEffects` with lower-level effects
        only; ``fine_dt`` the rate the law runs at, which rounds the window and holds
        the command, half a period more dead time, see
        :func:`avll.effect_stability.frequency_response`):
        ``G_fb P / (s² + G_fb Q)`` with ``G_fb`` the lower level
        (``G e^{-tau_c s} / (1 - K G + beta/s)``), ``P = (kg' + kv' s) D + F s D``,
        ``Q = (kg' + kv' s) D + kg' Tg s - F s (1 - D)``, ``D = e^{-latency s} (1 -
        e^{-period s}) / (period s)`` (the radar's latency and hold; 1 for a period of
        0), ``F = ff_gain (1 - e^{-W s}) / W`` (``W`` the window in whole samples), and
        ``kg', kv' = kg, kv (1 + ratio)/2``."""
        m = model if isinstance(model, WithEffects) else WithEffects(model, ())
        if m.upper:
            raise ValueError("model: the hidden law replaces the upper-level effects")
        c = m.linear(v=v, terms=True)
        s = 1j * np.asarray(omega, dtype=np.float64)
        # the generator runs at fine_dt: its hold adds fine_dt / 2 to the dead time
        g = (c["b1"] * s + c["b0"]) * np.exp(-(c["Td"] + 0.5 * fine_dt) * s) / (
            c["a2"] * s * s + c["a1"] * s + 1.0)
        gfb = g * np.exp(-c["command_delay"] * s) / (1.0 - c["K"] * g
                                                     + c["speed_feedback"] / s)
        d = np.exp(-self.radar_latency * s)
        if self.radar_period > 0:
            d = d * (1.0 - np.exp(-self.radar_period * s)) / (self.radar_period * s)
        w = max(round(self.ff_window / fine_dt), 1) * fine_dt
        f = self.ff_gain * (1.0 - np.exp(-w * s)) / w
        kg, kv = upper.kg * 0.5 * (1 + self.ratio), upper.kv * 0.5 * (1 + self.ratio)
        p = (kg + kv * s) * d + f * s * d
        q = (kg + kv * s) * d + kg * upper.Tg * s - f * s * (1.0 - d)
        return np.asarray(gfb * p / (s * s + gfb * q))


@dataclass(frozen=True)
class CarTruth:
    """One follower: lower level ``model``, upper level ``upper``, optional ``effects``
    (of either level; not ``grade``: the disturbance uses it), its own acceleration
    disturbance (``disturbance_std`` m/s², ``disturbance_tau`` s) and structures
    ``hidden`` in its upper level (:class:`HiddenUpper`; then no upper-level effect)."""

    model: LowerLevelModel
    upper: UpperLevel
    effects: tuple[Effect, ...] = ()
    disturbance_std: float = DISTURBANCE_STD
    disturbance_tau: float = DISTURBANCE_TAU
    hidden: HiddenUpper | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.model, LowerLevelModel):
            raise ValueError(f"model: expected an avll model, got {type(self.model).__name__}")
        if not isinstance(self.upper, UpperLevel):
            raise ValueError(f"upper: expected an avll.UpperLevel, got {self.upper!r:.60}")
        for e in self.effects:
            if not isinstance(e, Effect):
                raise ValueError(f"effects: expected Effect objects, got {type(e).__name__}")
            if e.name == "grade":
                raise ValueError("effects: 'grade' carries the follower's disturbance here; "
                                 "give the disturbance by disturbance_std/disturbance_tau")
        check_number(self.disturbance_std, "disturbance_std", nonneg=True)
        check_number(self.disturbance_tau, "disturbance_tau", positive=True)
        if self.hidden is not None:
            if not isinstance(self.hidden, HiddenUpper):
                raise ValueError(f"hidden: expected an avll.synth_platoon.HiddenUpper, got "
                                 f"{self.hidden!r:.60}")
            if any(e.level == "upper" for e in self.effects):
                raise ValueError("hidden: the hidden law replaces the upper-level effects; "
                                 "give one or the other")


@dataclass
class SynthPlatoon:
    """Result of :func:`synth_platoon`: ``runs`` (one per follower, loader form),
    ``truth`` (one dict per follower, also in each run's ``meta["truth"]``), the true
    trajectories at the recorded rate (``t``, ``v``, ``x``: (cars + 1, samples), row 0
    the leader) and the settings."""

    runs: list[Run]
    truth: list[dict[str, Any]]
    t: np.ndarray
    v: np.ndarray
    x: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)


def _smooth(rng: np.random.Generator, n: int, dt: float, std: float, tau: float) -> np.ndarray:
    """A stationary, smooth (differentiable) coloured noise of standard deviation
    ``std``: white noise through two first-order lags of time constant ``tau``
    (a critically damped second-order process, as a fused and spline-smoothed
    GNSS/inertial estimate errs), started after ``10 tau`` of burn-in."""
    if std <= 0 or n == 0:
        return np.zeros(n)
    from scipy import signal

    phi = math.exp(-dt / tau)
    burn = int(math.ceil(10 * tau / dt))
    w = rng.normal(0.0, 1.0, n + burn)
    y = signal.lfilter([1.0], [1.0, -phi], signal.lfilter([1.0], [1.0, -phi], w))[burn:]
    var = (1 + phi * phi) / (1 - phi * phi) ** 3  # variance of the cascade, unit input
    return np.asarray(y) * (std / math.sqrt(var))


def _noise(rng: np.random.Generator, n: int, dt: float, white: float, coloured: float,
           tau: float) -> np.ndarray:
    e = _smooth(rng, n, dt, coloured, tau)
    return e + rng.normal(0.0, white, n) if white > 0 else e


def leader_speed(
    t: np.ndarray,
    rng: np.random.Generator,
    *,
    v_mean: float,
    band_rms: float,
    drift_rms: float,
    band: Sequence[float] = DEFAULT_BAND,
    n_tones: int = 24,
    ramp: float = 30.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The leader's speed and position at times ``t`` (see the module doc): cruise at
    ``v_mean``, ``n_tones`` tones log-uniform in ``band`` of RMS ``band_rms``, three
    slow tones of RMS ``drift_rms``, all faded in by a raised cosine over ``ramp`` s."""
    lo, hi = (float(b) for b in band)
    f = np.exp(rng.uniform(math.log(lo), math.log(hi), n_tones))
    fd = rng.uniform(0.003, 0.015, 3)
    freqs = np.concatenate([f, fd])
    amps = np.concatenate([np.full(n_tones, band_rms * math.sqrt(2.0 / n_tones)),
                           np.full(3, drift_rms * math.sqrt(2.0 / 3.0))])
    ph = rng.uniform(0.0, 2 * math.pi, freqs.size)
    w = 2 * math.pi * freqs
    # s(t) = sum A sin(w t + p); its integral from 0 is sum A (cos p - cos(w t + p)) / w.
    s = np.sin(np.outer(t, w) + ph) @ amps
    si = (np.cos(ph)[None, :] - np.cos(np.outer(t, w) + ph)) @ (amps / w)
    # fade in: e(t) = (1 - cos(pi t / ramp)) / 2 until ramp; the position integrates
    # e s numerically (trapezoid on the fine grid) where e < 1, exactly afterwards.
    e = (np.where(t < ramp, 0.5 * (1.0 - np.cos(np.pi * np.minimum(t, ramp) / ramp)), 1.0)
         if ramp > 0 else np.ones_like(t))
    osc = e * s
    v = v_mean + osc
    xo = np.concatenate([[0.0], np.cumsum(0.5 * np.diff(t) * (osc[1:] + osc[:-1]))])
    k = int(np.searchsorted(t, ramp))
    if k < t.size:
        xo[k:] = xo[k] + (si[k:] - si[k])
    x = v_mean * (t - t[0]) + xo
    return v, x


_UPPER_RANGE = {"kg": (0.08, 0.25), "kv": (0.2, 0.6), "Tg": (1.0, 2.0), "Gmin": (2.0, 5.0)}


def _settles(car: CarTruth, fine_dt: float, v: float = 20.0) -> bool:
    """Whether a car with a hidden law returns to its equilibrium behind a leader at a
    constant speed ``v`` after starting 3 m too close (300 s, no disturbance): the
    local stability test for laws whose small-signal form has no engine (radar hold,
    window difference)."""
    assert car.hidden is not None
    n = int(round(300.0 / fine_dt))
    lv = np.full(n, v)
    lx = 1000.0 + v * fine_dt * np.arange(n, dtype=np.float64)
    gap = car.upper.Gmin + car.upper.Tg * v - 3.0
    a, vv, _, _ = _core.synth_closed_loop(
        car.model.name, car.model.values(), lx, lv, fine_dt, car.upper.kg, car.upper.kv,
        car.upper.Tg, car.upper.Gmin, v, float(lx[0] - gap), car.hidden.row(0.0))
    dev = np.abs(vv - v)
    if not np.all(np.isfinite(dev)):
        return False
    return bool(dev[-int(60.0 / fine_dt):].max() < 0.02 * max(dev.max(), 1e-12))


def random_car(rng: np.random.Generator, model: str = "proposed", *,
               disturbance_std: float = DISTURBANCE_STD,
               disturbance_tau: float = DISTURBANCE_TAU,
               effects: Sequence[Effect] = (), hidden: HiddenUpper | None = None,
               fine_dt: float = FINE_DT) -> CarTruth:
    """A locally stable car drawn at random: the model's Table II parameters each
    scaled by a factor in [0.7, 1.3] (``Td`` drawn in [0.2, 0.9] s), the upper law
    uniformly in kg [0.08, 0.25] 1/s², kv [0.2, 0.6] 1/s, Tg [1, 2] s, Gmin [2, 5] m;
    redrawn until the closed loop with the true delay is locally stable (with a
    ``hidden`` law, also until it settles in the time domain at ``fine_dt``,
    :func:`_settles`)."""
    from .stability import exact_delay_codes

    cls = model_class(model)
    base = TABLE_II_PARAMS[cls.name]
    for _ in range(100):
        p = {k: v * rng.uniform(0.7, 1.3) for k, v in base.items()}
        p["Td"] = rng.uniform(0.2, 0.9)
        m = cls(**p)
        u = UpperLevel(**{k: float(rng.uniform(*r)) for k, r in _UPPER_RANGE.items()})
        try:
            lin = WithEffects(m, tuple(effects)).linear() if effects else m.linear()
            if lin["K"] * lin["b0"] >= 1:
                continue
            codes, _ = exact_delay_codes(m, u.kg, u.Tg, u.kv)
        except ValueError:
            continue
        if int(codes[0]) > 0:
            car = CarTruth(m, u, tuple(effects), disturbance_std, disturbance_tau, hidden)
            if hidden is None or hidden.neutral or _settles(car, fine_dt):
                return car
    raise ValueError(f"model: no locally stable {cls.name} car found in 100 draws")


def _truth_entry(car: CarTruth, lead_v_true: np.ndarray, v_true: np.ndarray, dt: float,
                 band: Sequence[float], fine_dt: float) -> dict[str, Any]:
    from .spectral import band_rms_gain
    from .studies.openacc import amplification, time_gap_effective, transfer_gain

    v_mean = float(np.mean(v_true))
    lin_model = WithEffects(car.model, car.effects)
    f = np.fft.rfftfreq(lead_v_true.size, dt)
    lo, hi = (float(b) for b in band)
    fb = f[(f >= lo) & (f <= hi)]
    hid = car.hidden

    def gain_of(fh: np.ndarray) -> np.ndarray:
        if hid is None or hid.neutral:
            return transfer_gain(lin_model, car.upper, fh, v=v_mean, hold=fine_dt)
        return np.abs(hid.response(lin_model, car.upper, 2 * np.pi * fh, v=v_mean,
                                   fine_dt=fine_dt))

    h = gain_of(fb)
    gain = band_rms_gain(gain_of, lead_v_true, dt, band)
    ratio = amplification(v_true, lead_v_true, dt, band)[0]
    return {
        "model": car.model.name,
        "params": {k: float(v) for k, v in car.model.to_dict().items()},
        "upper": asdict(car.upper),
        "effects": [{"name": e.name, **{k: float(v) for k, v in
                                        zip(e.param_names(), e.to_array(), strict=True)}}
                    for e in car.effects],
        "hidden": None if hid is None else {k: float(v) for k, v in asdict(hid).items()},
        "disturbance_std": car.disturbance_std,
        "disturbance_tau": car.disturbance_tau,
        "band": [lo, hi],
        "band_gain": float(gain),
        "freqs": fb.tolist(),
        "H_abs": np.asarray(h, dtype=float).tolist(),
        "v_mean": v_mean,
        # the law's equilibrium headway at the mean speed (speed_gains: Tg + ch v),
        # as the study defines it
        "time_gap_effective": time_gap_effective(lin_model, car.upper, v_mean),
        "rms_ratio_true": float(ratio),
    }


def synth_platoon(
    cars: Sequence[CarTruth] | int = 5,
    *,
    seed: int = 0,
    equipment: str | Equipment = "zalazone",
    duration: float = 600.0,
    dt: float = 0.1,
    fine_dt: float = FINE_DT,
    warmup: float = 60.0,
    v_mean: float = 20.0,
    band_rms: float = 0.8,
    drift_rms: float = 0.5,
    band: Sequence[float] = DEFAULT_BAND,
    models: Sequence[str] = MODELS,
    disturbance_std: float = DISTURBANCE_STD,
    disturbance_tau: float = DISTURBANCE_TAU,
    hidden: HiddenUpper | None = None,
    setting: str = "M",
    file_name: str | None = None,
) -> SynthPlatoon:
    """A platoon of the module doc: ``cars`` followers (given as :class:`CarTruth`, or
    a number of random ones from :func:`random_car`, cycling through ``models``, with
    ``disturbance_std``/``_tau`` and the structures ``hidden`` in their upper level),
    recorded for ``duration`` s at ``dt`` after ``warmup`` s, with ``equipment`` noise
    (a name of :data:`EQUIPMENT` or an :class:`Equipment`). Deterministic in ``seed``.
    A follower that diverges is a ``ValueError`` naming it."""
    seed = check_seed(seed)
    dt = check_number(dt, "dt", positive=True)
    fine_dt = check_number(fine_dt, "fine_dt", positive=True)
    duration = check_number(duration, "duration", positive=True)
    warmup = check_number(warmup, "warmup", nonneg=True)
    v_mean = check_number(v_mean, "v_mean", positive=True)
    band_rms = check_number(band_rms, "band_rms", nonneg=True)
    drift_rms = check_number(drift_rms, "drift_rms", nonneg=True)
    sub = dt / fine_dt
    if abs(sub - round(sub)) > 1e-9 or round(sub) < 1:
        raise ValueError(f"fine_dt: must divide dt ({dt:g} s) a whole number of times, "
                         f"got {fine_dt:g} s")
    sub = int(round(sub))
    if duration < 20 * dt:
        raise ValueError(f"duration: must be >= 20 dt, got {duration:g} s")
    lo, hi = check_band(band, dt)
    if isinstance(equipment, str):
        if equipment not in EQUIPMENT:
            raise ValueError(f"equipment: unknown {equipment!r}; known: {', '.join(EQUIPMENT)}")
        eq = EQUIPMENT[equipment]
    elif isinstance(equipment, Equipment):
        eq = equipment
    else:
        raise ValueError(f"equipment: expected a name or an Equipment, got {equipment!r:.60}")
    if isinstance(cars, (int, np.integer)) and not isinstance(cars, bool):
        nc = check_int(int(cars), "cars", min=1, max=50)
        if not models:
            raise ValueError("models: no model given")
        rng_c = np.random.default_rng([seed, 11])
        if hidden is not None and not isinstance(hidden, HiddenUpper):
            raise ValueError(f"hidden: expected a HiddenUpper, got {hidden!r:.60}")
        truths = [random_car(rng_c, models[i % len(models)], disturbance_std=disturbance_std,
                             disturbance_tau=disturbance_tau, hidden=hidden, fine_dt=fine_dt)
                  for i in range(nc)]  # fmt: skip
    else:
        if isinstance(cars, (bool, str, bytes)) or not hasattr(cars, "__iter__"):
            raise ValueError(f"cars: expected CarTruth objects or a number, got {cars!r:.60}")
        truths = list(cars)
        if not truths:
            raise ValueError("cars: no car given")
        for c in truths:
            if not isinstance(c, CarTruth):
                raise ValueError(f"cars: expected CarTruth objects or a number, got "
                                 f"{type(c).__name__}")
    n_rec = int(round(duration / dt))
    n_warm = int(round(warmup / dt))
    n_fine = (n_rec + n_warm) * sub
    tf = np.arange(n_fine) * fine_dt
    lv, lx = leader_speed(tf, np.random.default_rng([seed, 1]), v_mean=v_mean,
                          band_rms=band_rms, drift_rms=drift_rms, band=(lo, hi),
                          ramp=min(30.0, 0.5 * warmup) if warmup > 0 else 0.0)
    if lv.min() <= 0.5:
        raise ValueError(f"band_rms, drift_rms: the leader's speed drops to {lv.min():.2f} m/s "
                         f"around v_mean={v_mean:g} m/s; use a larger v_mean")
    vs, xs = [lv], [lx]
    for i, car in enumerate(truths, start=1):
        d = _ar1(np.random.default_rng([seed, 2, i]), n_fine,
                 math.exp(-fine_dt / car.disturbance_tau), car.disturbance_std)
        mod = WithEffects(car.model, (*car.effects, Grade(g_eff=1.0)))
        v_start = float(vs[-1][0])
        gap0 = car.upper.Gmin + mod.upper_linear(car.upper, v=v_start)["Tg_eq"] * v_start
        up = car.upper
        if car.hidden is not None and not car.hidden.neutral:
            phase = float(np.random.default_rng([seed, 5, i]).uniform(
                0.0, car.hidden.radar_period)) if car.hidden.radar_period > 0 else 0.0
            tr = Trajectory(*_core.synth_closed_loop(
                mod.base.name, mod.base.values(), xs[-1], vs[-1], fine_dt, up.kg, up.kv, up.Tg,
                up.Gmin, v_start, float(xs[-1][0] - gap0), car.hidden.row(phase),
                effects=list(mod.effect_names),
                effect_params=[float(x) for e in mod.effects for x in e.to_array()],
                exo={"grade": np.ascontiguousarray(-d)}))
        else:
            tr = closed_loop(mod, xs[-1], vs[-1], fine_dt, up, v0=v_start,
                             x0=float(xs[-1][0] - gap0), exo={"grade": -d})
        if not (np.all(np.isfinite(tr.v)) and np.all(np.isfinite(tr.x))):
            raise ValueError(f"cars: follower {i} ({car.model!r}, {car.upper!r}) diverges")
        vs.append(np.asarray(tr.v))
        xs.append(np.asarray(tr.x))
    keep = slice(n_warm * sub, None, sub)
    v_true = np.array([v[keep] for v in vs])
    x_true = np.array([x[keep] for x in xs])
    t = np.arange(n_rec) * dt
    v_meas = np.empty_like(v_true)
    x_meas = np.empty_like(x_true)
    for i in range(v_true.shape[0]):
        rng = np.random.default_rng([seed, 3, i])
        v_meas[i] = v_true[i] + _noise(rng, n_rec, dt, eq.speed_white, eq.speed_coloured,
                                       eq.speed_tau)
        x_meas[i] = (x_true[i] - x_true[i, 0]) + _noise(
            rng, n_rec, dt, eq.position_white, eq.position_coloured, eq.position_tau)
    from .io.openacc_native import derive_acceleration

    stem = file_name or f"synthetic_{eq.name}_seed{seed}.csv"
    names = ["leader"] + [f"car{i}" for i in range(1, len(truths) + 1)]
    runs, truth = [], []
    for i in range(1, v_true.shape[0]):
        rng = np.random.default_rng([seed, 4, i])
        gap = (x_true[i - 1] - x_true[i]) + _noise(rng, n_rec, dt, eq.spacing_white,
                                                   eq.spacing_coloured, eq.spacing_tau)
        te = _truth_entry(truths[i - 1], v_true[i - 1], v_true[i], dt, (lo, hi), fine_dt)
        truth.append(te)
        meta = {
            "format": "openacc", "synthetic": True, "generator": "avll.synth_platoon",
            "seed": int(seed), "equipment": eq.name, "file": stem, "folder": "synthetic",
            "date": "2026-01-01", "car": names[i], "lead_car": names[i - 1],
            "setting": setting, "acc": True, "setting_in_file": setting, "position": i - 1,
            "vehicle_index": i, "lead_index": i - 1, "track": "synthetic",
            "n_vehicles": len(names), "vehicle_order": names, "t_start": 0.0,
            "t_end": float(t[-1]), "cleaning": [], "truth": te,
        }
        runs.append(Run(
            run_id=f"{stem.rsplit('.', 1)[0]}/v{i - 1}-v{i}", t=t,
            a=derive_acceleration(v_meas[i], dt), command_kind="acceleration", command=None,
            v=v_meas[i], x=x_meas[i], lead_x=x_meas[i] + gap, lead_v=v_meas[i - 1],
            lead_a=derive_acceleration(v_meas[i - 1], dt), meta=meta))
    settings = {"seed": int(seed), "equipment": eq.name, "duration": duration, "dt": dt,
                "fine_dt": fine_dt, "warmup": warmup, "v_mean": v_mean,
                "band_rms": band_rms, "drift_rms": drift_rms, "band": [lo, hi]}
    return SynthPlatoon(runs, truth, t, v_true, x_true, settings)


def _mean(xs: Any) -> float | None:
    return float(np.mean(xs)) if len(xs) else None


def _median(xs: Any) -> float | None:
    return float(np.median(xs)) if len(xs) else None


def _summary(err: list[float], inside: list[bool], missing: int) -> dict[str, Any]:
    e = np.asarray(err, dtype=float)
    return {"n": int(e.size), "missing": int(missing), "median_error": _median(e),
            "mean_error": _mean(e), "median_abs_error": _median(np.abs(e)),
            "within_10pct": _mean(np.abs(e) <= 0.10), "coverage": _mean(inside)}


def validate_amplification(
    seeds: Sequence[int],
    *,
    cars: int = 5,
    band: Sequence[float] = DEFAULT_BAND,
    n_boot: int | None = None,
    **platoon: Any,
) -> dict[str, Any]:
    """Both measured-amplification estimators against the truth on the platoons of
    ``seeds`` (``cars`` random followers each, ``platoon`` options to
    :func:`synth_platoon`): the band RMS ratio with its circular block bootstrap
    interval, exactly as the OpenACC study measures it
    (:func:`avll.studies.openacc.measured_amplification`; ``n_boot`` resamples,
    ``None`` the study's :data:`~avll.studies.openacc.N_BOOT`) and the H1 band gain
    (:func:`avll.spectral.h1_band_gain`), each against the true band gain. Returns
    ``{"rows": [...], "rms_ratio": summary, "h1": summary}``; a summary has ``n``,
    ``missing`` (no estimate), ``median_error``, ``mean_error``,
    ``median_abs_error`` (errors ``estimate / truth - 1``), ``within_10pct`` and
    ``coverage`` (share of 95 % intervals that contain the truth)."""
    from .spectral import h1_band_gain
    from .studies.openacc import N_BOOT, measured_amplification

    rows: list[dict[str, Any]] = []
    for s in seeds:
        pl = synth_platoon(cars, seed=int(s), band=band, **platoon)
        for j, (r, tr) in enumerate(zip(pl.runs, pl.truth, strict=True)):
            assert r.v is not None and r.lead_v is not None
            ma = measured_amplification(r.v, r.lead_v, r.dt, band=band, seed=[int(s), j],
                                        n_boot=N_BOOT if n_boot is None else n_boot)
            ci = ma["ci"] if None not in ma["ci"] else None
            g = h1_band_gain(r.lead_v, r.v, r.dt, band)
            rows.append({"seed": int(s), "car": r.meta["car"], "model": tr["model"],
                         "truth": tr["band_gain"], "rms_ratio": ma["amplification"],
                         "rms_ratio_ci": ci,
                         "rms_ratio_reason": ma.get("amplification_reason", ma.get("ci_reason")),
                         "h1": g.gain, "h1_ci": None if g.ci is None else list(g.ci),
                         "coherence": g.coherence, "h1_reason": g.reason,
                         "rms_ratio_true": tr["rms_ratio_true"]})
    out: dict[str, Any] = {"rows": rows}
    for key in ("rms_ratio", "h1"):
        ok = [r for r in rows if r[key] is not None and math.isfinite(r[key])]
        cis = [(r[f"{key}_ci"], r["truth"]) for r in ok if r[f"{key}_ci"] is not None]
        out[key] = _summary([r[key] / r["truth"] - 1.0 for r in ok],
                            [bool(ci[0] <= truth <= ci[1]) for ci, truth in cis],
                            len(rows) - len(ok))
    out["h1"]["median_coherence"] = _median([r["coherence"] for r in rows
                                             if r["coherence"] is not None])
    return out


def validate_intervals(seeds: Sequence[int], cars: int = 6, *, n: int = 200,
                       duration: float = 300.0, starts: int = 2, threads: int = 0,
                       options: Mapping[str, Any] | None = None, **platoon: Any
                       ) -> dict[str, Any]:
    """Coverage on a known truth: for each seed a synthetic platoon
    (:func:`avll.synth_platoon.synth_platoon`, proposed lower levels, ``cars``
    followers, ``duration`` s, ``platoon`` further options), each follower calibrated
    closed loop as the OpenACC study does (:data:`avll.studies.openacc.WEIGHTS`, every
    upper gain free, ``Gmin`` in [0, 10] m) with ``n`` resamples. Per car: whether the
    95 % intervals of the band amplification and of ``Tg + Gmin / v̄`` hold the truth,
    the estimates' relative errors and the intervals' relative widths, and the same
    for the intervals of the same refits without the small-sample widening
    (``uncorrected``). A car whose record has fewer effective blocks than fitted
    parameters gets no interval (:func:`avll.uncertainty.small_sample_scale` is
    infinite: ``determined`` False, ``inside`` None), nor for ``Tg + Gmin / v̄`` one
    whose fitted gap loop is slower than its record
    (:meth:`avll.Uncertainty.gap_loop_too_slow`). Returns ``rows`` and a ``summary``
    per quantity: ``coverage`` over the cars with an interval, ``coverage_all``
    counting a car without one as covered (its interval is the whole line),
    ``undetermined`` (share of cars without),
    the share of estimates within 10 % (a car without an estimate, its calibrated
    closed loop locally unstable, is not within), ``no_estimate`` (their number),
    the mean and median absolute error of the others, the median relative width
    (cars with an interval); and ``median_widening`` (the median factor by which
    the resampled deviations were widened, finite ones). ``options``: further fields
    of the :class:`avll.Intervals` (e.g. ``refit``, ``ftol``, ``polish``; ``None``:
    the defaults)."""
    from .calibration import calibrate_many
    from .defaults import UPPER_NAMES
    from .studies.openacc import GMIN_MAX, WEIGHTS
    from .uncertainty import Intervals

    rows: list[dict[str, Any]] = []
    opts = Intervals(n=n, **dict(options or {}))
    models = platoon.pop("models", ("proposed",))  # every seed's platoon, not the first's only
    for seed in seeds:
        sp = synth_platoon(cars, seed=int(seed), duration=duration, models=models, **platoon)
        res = calibrate_many("proposed", sp.runs, "per_run", seed=int(seed), starts=starts,
                             closed_loop=True, upper_free=UPPER_NAMES, weights=WEIGHTS,
                             bounds={"Gmin": (0.0, GMIN_MAX)}, intervals=opts,
                             threads=threads)
        costs = _fit_and_truth_costs(res, sp)
        for r, run, tr, cost in zip(res, sp.runs, sp.truth, costs, strict=True):
            u = r.uncertainty
            assert run.lead_v is not None and run.v is not None
            row: dict[str, Any] = {"seed": int(seed), "car": run.run_id,
                                   "block_s": u.block_s, "blocks": u.blocks,
                                   "widening": u.widening,
                                   "gap_loop_slow": bool(u.gap_loop_too_slow()),
                                   "cost_fit": cost[0], "cost_truth": cost[1]}
            amp, amps = u.band_amplification(run.lead_v, run.dt)
            tge, tges = u.time_gap_effective(float(np.mean(run.v)))
            raw = u.uncorrected()
            _, amps_raw = raw.band_amplification(run.lead_v, run.dt)
            _, tges_raw = raw.time_gap_effective(float(np.mean(run.v)))
            for key, est, smp, truth, smp_raw in (
                    ("amplification", amp, amps, tr["band_gain"], amps_raw),
                    ("time_gap_effective", tge, tges, tr["time_gap_effective"], tges_raw)):
                rlo, rhi = raw._q(smp_raw, est)
                lo, hi = u._q(smp, est)
                det = math.isfinite(lo) and math.isfinite(hi)
                row[key] = {"truth": float(truth), "estimate": float(est),
                            "low": lo, "high": hi, "determined": det,
                            "inside": bool(lo <= truth <= hi) if det else None,
                            "error": float(est / truth - 1.0),
                            "rel_width": float((hi - lo) / truth) if det else math.inf,
                            # the same refits without the small-sample widening
                            "uncorrected": {"low": rlo, "high": rhi,
                                            "inside": bool(rlo <= truth <= rhi) if det
                                            else None,
                                            "rel_width": float((rhi - rlo) / truth)}}
            rows.append(row)
    summary: dict[str, Any] = {"cars": len(rows), "seeds": [int(s) for s in seeds],
                               "resamples": int(n), "level": opts.level,
                               "refit": opts.refit, "polish": bool(opts.polish),
                               "ftol": float(opts.ftol),
                               "block_factor": float(opts.block_factor),
                               "median_widening": _median([r["widening"] for r in rows
                                                           if math.isfinite(r["widening"])]),
                               "median_block_s": float(np.median([r["block_s"] for r in rows]))}
    slow = [r for r in rows if r["gap_loop_slow"]]
    # the data, not the optimiser: such a fit costs less than the true parameters
    summary["gap_loop_slow"] = len(slow)
    summary["gap_loop_slow_below_truth_cost"] = sum(
        1 for r in slow if r["cost_fit"] < r["cost_truth"])
    from scipy import stats

    zq = float(stats.norm.ppf(0.5 + opts.level / 2.0))
    for key in ("amplification", "time_gap_effective"):
        d_all = [r[key] for r in rows]
        d = [x for x in d_all if x["determined"]]
        err_all = np.array([x["error"] for x in d_all])
        # an estimate whose closed loop is locally unstable has no amplification (NaN)
        err = err_all[np.isfinite(err_all)]
        # how far the truth lies outside, in interval widths (0 inside)
        miss = [max(x["low"] - x["truth"], x["truth"] - x["high"], 0.0)
                / max(x["high"] - x["low"], 1e-300) for x in d if not x["inside"]]
        summary[key] = {
            "coverage": _mean([x["inside"] for x in d]),
            "coverage_all": _mean([x["inside"] is not False for x in d_all]),
            "undetermined": _mean([not x["determined"] for x in d_all]),
            "within_10pct": _mean(np.abs(err_all) <= 0.10),
            "no_estimate": int(np.sum(~np.isfinite(err_all))),
            "mean_error": _mean(err),
            "median_abs_error": _median(np.abs(err)),
            "median_rel_width": _median([x["rel_width"] for x in d]),
            "uncorrected_coverage": _mean([x["uncorrected"]["inside"] for x in d]),
            "uncorrected_median_rel_width": _median([x["uncorrected"]["rel_width"] for x in d]),
            "median_miss_in_widths": float(np.median(miss)) if miss else 0.0,
            # (estimate - truth) / half-width x z: a standard deviation of one is nominal
            "standardised_error_sd": float(np.std([
                (x["estimate"] - x["truth"]) / max((x["high"] - x["low"]) / 2.0, 1e-300) * zq
                for x in d])) if d else None,
        }
    return {"rows": rows, "summary": summary}


def _fit_and_truth_costs(res: Sequence[Any], sp: SynthPlatoon) -> list[tuple[float, float]]:
    """Per car, the closed-loop cost (the OpenACC study's weights) of the fitted
    parameters and of the true ones on the car's run (NaN for the truth when the car's
    true structure is not the proposed model with Eq. 3)."""
    from .defaults import UPPER_NAMES
    from .models import Proposed
    from .rollout import batch_cost
    from .studies.openacc import WEIGHTS

    out = []
    for r, run, tr in zip(res, sp.runs, sp.truth, strict=True):
        rows = [np.asarray(r.x, dtype=np.float64)]
        plain = tr["model"] == "proposed" and not tr["effects"] and tr["hidden"] is None
        if plain:
            rows.append(np.array([tr["params"][k] for k in Proposed.param_names()]
                                 + [tr["upper"][k] for k in UPPER_NAMES]))
        c = batch_cost("proposed", np.vstack(rows), [run], closed_loop=True,
                       upper_free=list(range(len(UPPER_NAMES))), weights=WEIGHTS, threads=1)
        out.append((float(c[0, 0]), float(c[1, 0]) if plain else math.nan))
    return out


@dataclass(frozen=True)
class StructureRow:
    """One synthetic car of :func:`validate_structure`: the truth (``band_gain``,
    ``time_gap``: ``Tg + Gmin/v̄`` of the true law), and per fit (``base``: the base
    model and Eq. 3; ``candidates``: with the candidate structures) the predicted band
    amplification (``|H|`` on the predecessor's measured spectrum), the calibrated
    ``Tg + Gmin/v̄``, the calibration cost and the held-out cost (the last part of the
    run, not used by the calibration), and the candidates' fitted parameters."""

    seed: int
    car: str
    band_gain: float
    time_gap: float
    base_amplification: float
    base_time_gap: float
    base_cost: float
    base_heldout: float
    amplification: float
    time_gap_fit: float
    cost: float
    heldout: float
    params: dict[str, float]


@dataclass(frozen=True)
class StructureSummary:
    """Errors ``predicted / truth - 1`` over the cars of one fit: the amplification's
    mean, median and shares within 5 % and below the truth, ``Tg + Gmin/v̄``'s median
    (signed and absolute) error, and the median relative change of the held-out cost
    against the base fit (negative: the fit predicts the held-out data better)."""

    n: int
    mean_error: float
    median_error: float
    within_5pct: float
    underestimated: float
    time_gap_median_error: float
    time_gap_median_abs_error: float
    heldout_change: float


@dataclass(frozen=True)
class StructureCheck:
    """Result of :func:`validate_structure`: ``rows`` per car, ``base`` and
    ``candidates`` their summaries, and the settings."""

    rows: tuple[StructureRow, ...]
    base: StructureSummary
    candidates: StructureSummary
    settings: dict[str, Any]


def _errors(e: np.ndarray, g: np.ndarray) -> dict[str, Any]:
    """The fields :class:`StructureSummary` and :class:`SelectionSummary` share, of the
    amplification's errors ``e`` and the time gap's ``g`` (NaN when there are none)."""
    def stat(f: Any, x: np.ndarray) -> float:
        return float(f(x)) if x.size else math.nan

    return {"n": int(e.size), "mean_error": stat(np.mean, e), "median_error": stat(np.median, e),
            "within_5pct": stat(np.mean, np.abs(e) <= 0.05),
            "underestimated": stat(np.mean, e < 0), "time_gap_median_error": stat(np.median, g),
            "time_gap_median_abs_error": stat(np.median, np.abs(g))}


def _col(rows: Sequence[Any], name: str) -> np.ndarray:
    return np.array([getattr(r, name) for r in rows], dtype=float)


def _head(run: Run, k: int) -> Run:
    """The run's first ``k`` samples, a run of its own."""
    cut = {f: getattr(run, f)[:k] for f in ("t", "a", "v", "x", "lead_x", "lead_v", "lead_a")
           if getattr(run, f) is not None}
    return replace(run, run_id=f"{run.run_id}/cal", **cut)


def validate_structure(
    seeds: Sequence[int],
    *,
    hidden: HiddenUpper | None,
    candidates: Sequence[str],
    cars: int = 5,
    model: str = "proposed",
    heldout: float = 1.0 / 3.0,
    max_generations: int | None = None,
    starts: int = 1,
    seed: int = 0,
    threads: int = 0,
    **platoon: Any,
) -> StructureCheck:
    """The blind test of the upper-level structures: on the platoons of ``seeds``
    (``cars`` random ``model`` followers, the structures ``hidden`` in their upper
    level -- or none -- and ``platoon`` options to :func:`synth_platoon`), each car is
    calibrated in closed loop (the OpenACC study's weights and ``Gmin`` box, every
    upper-level gain free) on the first ``1 - heldout`` of its run, once as the base
    model (Eq. 3) and once with the upper-level ``candidates`` (one
    :func:`avll.calibrate` with ``subsets`` per fit and platoon), and both fits are
    compared with the truth: the band amplification predicted by ``|H|`` (the fit's
    small-signal form, :func:`avll.studies.openacc.predicted_amplification`, on the
    whole run's measured predecessor) against the true band gain, ``Tg + Gmin/v̄``
    against the true law's, and the cost on the held-out part (the study's objective
    over the last ``heldout`` of each run, the fit simulated over the whole run so that
    the held-out part continues the calibrated part instead of restarting it).
    Deterministic in ``seeds`` and ``seed``."""
    from .calibration import calibrate
    from .effects import effect_class
    from .rollout import simulate_batch
    from .studies.openacc import (
        GMIN_MAX,
        WEIGHTS,
        predicted_amplification,
        time_gap_effective,
    )

    names = list(candidates)
    if not names:
        raise ValueError("candidates: give at least one upper-level structure")
    for n in names:
        if effect_class(n).level != "upper":
            raise ValueError(f"candidates: {n!r} is not an upper-level structure")
    heldout = check_number(heldout, "heldout", positive=True)
    if heldout >= 0.9:
        raise ValueError(f"heldout: must be < 0.9, got {heldout:g}")
    free = ["kg", "kv", "Tg", "Gmin"]
    opts: dict[str, Any] = {} if max_generations is None else {"max_generations": max_generations}
    rows: list[StructureRow] = []
    for s in seeds:
        pl = synth_platoon(cars, seed=int(s), models=(model,), hidden=hidden, **platoon)
        k = int(round(len(pl.runs[0]) * (1.0 - heldout)))
        cal = [_head(r, k) for r in pl.runs]
        fits = {}
        for key, effs in (("base", []), ("candidates", names)):
            res = calibrate(model, cal, effects=effs, subsets="per_run", closed_loop=True,
                            upper_free=free, weights=WEIGHTS, seed=seed, starts=starts,
                            threads=threads, bounds={"Gmin": (0.0, GMIN_MAX)}, **opts)
            out = []
            for r, c in zip(pl.runs, res, strict=True):
                up = UpperLevel(**c.upper)
                m = c.with_effects if c.with_effects is not None else WithEffects(c.model, ())
                assert r.lead_v is not None and r.v is not None
                vbar = float(np.mean(r.v))
                row = np.concatenate([m.to_array(), up.to_array()])[None, :]
                # the whole run simulated (no restart), its error on the held-out part
                sim = simulate_batch(model, row, [r], effects=list(m.effect_names),
                                     closed_loop=True, upper_free=[0, 1, 2, 3],
                                     threads=threads)  # fmt: skip
                assert r.x is not None
                h = float(sum(w * np.mean((got[0][k:] - want[k:]) ** 2) for w, got, want in
                              zip(WEIGHTS, (sim.a[0], sim.v[0], sim.x[0]), (r.a, r.v, r.x),
                                  strict=True)))  # fmt: skip
                out.append((predicted_amplification(m, up, r.lead_v, r.dt),
                            time_gap_effective(m, up, vbar), c.cost, h,
                            {k2: v for k2, v in c.params.items() if "." in k2}))
            fits[key] = out
        for r, tr, b, c in zip(pl.runs, pl.truth, fits["base"], fits["candidates"], strict=True):
            rows.append(StructureRow(int(s), str(r.meta["car"]), float(tr["band_gain"]),
                                     float(tr["time_gap_effective"]), b[0], b[1], b[2], b[3],
                                     c[0], c[1], c[2], c[3], c[4]))

    def summary(amp: str, tg: str, held: str) -> StructureSummary:
        return StructureSummary(**_errors(_col(rows, amp) / _col(rows, "band_gain") - 1.0,
                                          _col(rows, tg) / _col(rows, "time_gap") - 1.0),
                                heldout_change=float(np.median(
                                    _col(rows, held) / _col(rows, "base_heldout") - 1.0)))

    base = summary("base_amplification", "base_time_gap", "base_heldout")
    cand = summary("amplification", "time_gap_fit", "heldout")
    settings = {"seeds": [int(s) for s in seeds], "cars": cars, "model": model,
                "hidden": None if hidden is None else hidden.__dict__.copy(),
                "candidates": names, "heldout": heldout, "max_generations": max_generations,
                "starts": starts, "seed": seed, **platoon}
    return StructureCheck(tuple(rows), base, cand, settings)


def synth_campaign(cars: int, files: int, *, seed: int, hidden: HiddenUpper | None = None,
                   model: str = "proposed", **platoon: Any) -> list[Run]:
    """A synthetic campaign of ``files`` recordings of the same ``cars`` random
    ``model`` followers (the structures ``hidden`` in their upper law, or none): each
    file a :func:`synth_platoon` of its own leader, disturbances and noise (seed
    ``[seed, j]`` for file ``j``), every run's ``meta`` naming its file, car,
    setting ``"M"``, ACC and the campaign ``"synthetic"`` (so the OpenACC study's
    out-of-sample folds are the car's other files), its truth in ``meta["truth"]``.
    ``platoon`` options go to :func:`synth_platoon`. Deterministic in ``seed``."""
    nc = check_int(cars, "cars", min=1, max=50)
    nf = check_int(files, "files", min=1, max=50)
    seed = check_seed(seed)
    rng = np.random.default_rng([seed, 17])
    fine = float(platoon.get("fine_dt", FINE_DT))
    truths = [random_car(rng, model, hidden=hidden, fine_dt=fine,
                         disturbance_std=float(platoon.get("disturbance_std", DISTURBANCE_STD)),
                         disturbance_tau=float(platoon.get("disturbance_tau", DISTURBANCE_TAU)))
              for _ in range(nc)]  # fmt: skip
    kw = {k: v for k, v in platoon.items() if k not in ("disturbance_std", "disturbance_tau")}
    runs: list[Run] = []
    for j in range(nf):
        stem = f"synthetic_seed{seed}_file{j}.csv"
        pl = synth_platoon(truths, seed=int(np.random.SeedSequence([seed, j]).generate_state(1)[0]),
                           file_name=stem, **kw)
        for r in pl.runs:
            runs.append(replace(r, meta={**r.meta, "campaign": "synthetic", "file": stem}))
    return runs


@dataclass(frozen=True)
class SelectionRow:
    """One held-out run of :func:`validate_selection`: its truth (``band_gain``,
    ``time_gap``) and the out-of-sample predictions of the base model and of the
    study's final model (``|H|`` band amplification and ``Tg + Gmin/v̄`` from the
    car's other files), with the final model's structures."""

    seed: int
    file: str
    car: str
    band_gain: float
    time_gap: float
    base_amplification: float
    base_time_gap: float
    amplification: float
    time_gap_fit: float
    effects: tuple[str, ...]


@dataclass(frozen=True)
class SelectionSummary:
    """Errors ``predicted / truth - 1`` of one model over the held-out runs: the
    amplification's mean, median, share within 5 %, share underestimated; the median
    (signed and absolute) error of ``Tg + Gmin/v̄``."""

    n: int
    mean_error: float
    median_error: float
    within_5pct: float
    underestimated: float
    time_gap_median_error: float
    time_gap_median_abs_error: float


@dataclass(frozen=True)
class SelectionCheck:
    """Result of :func:`validate_selection`: ``rows``, the ``base`` and ``final``
    summaries, the share of runs whose final model carries a structure
    (``with_structures``), the structures accepted (name -> runs), the selection's
    wall time per seed (``seconds``) and the settings."""

    rows: tuple[SelectionRow, ...]
    base: SelectionSummary
    final: SelectionSummary
    with_structures: float
    accepted: dict[str, int]
    seconds: tuple[float, ...]
    settings: dict[str, Any]


def _num(x: Any) -> float:
    return math.nan if x is None else float(x)


def validate_selection(
    seeds: Sequence[int],
    *,
    hidden: HiddenUpper | None,
    cars: int = 4,
    files: int = 3,
    model: str = "proposed",
    candidates: Sequence[str] | None = None,
    max_generations: int | None = None,
    pop_size: int | None = None,
    starts: int | None = None,
    seed: int = 0,
    threads: int = 0,
    **platoon: Any,
) -> SelectionCheck:
    """The blind test of the OpenACC study's structure selection: for each of
    ``seeds`` a synthetic campaign (:func:`synth_campaign`: ``cars`` followers with
    ``hidden`` structures, or none, each recorded in ``files`` files) goes through
    :func:`avll.studies.openacc.openacc_study` itself (``model`` only, no intervals,
    no figures; ``candidates`` the selection's, default its own), and each held-out
    run's out-of-sample prediction (a model calibrated on the car's other files) is
    compared with the truth, for the base model (``base_model``) and the final one:
    the band amplification (``|H|`` on the run's predecessor spectrum, vs the truth's
    small-signal band gain) and ``Tg + Gmin/v̄``. Deterministic in ``seeds`` and
    ``seed``."""
    from .studies.openacc import openacc_study

    rows: list[SelectionRow] = []
    secs: list[float] = []
    acc: dict[str, int] = {}
    for s in seeds:
        runs = synth_campaign(cars, files, seed=int(s), hidden=hidden, model=model, **platoon)
        st = openacc_study(runs, model=model, models=(model,), seed=seed, threads=threads,
                           max_generations=max_generations, pop_size=pop_size,
                           starts=starts, intervals=False, figures=False,
                           structures=True if candidates is None else list(candidates))
        sel = st.summary["structure_selection"]
        secs.append(float(sel.get("seconds") or 0.0) + float(sel.get("final_fits_seconds")
                                                              or 0.0))
        truth = {r.run_id: r.meta["truth"] for r in runs}
        for c in st.summary["cars"]:
            tr = truth[c["run_id"]]
            b = c["base_model"]
            effs = tuple(c["final_model_effects"])
            for e in effs:
                acc[e] = acc.get(e, 0) + 1
            rows.append(SelectionRow(int(s), str(c["file"]), str(c["car"]),
                                     float(tr["band_gain"]), float(tr["time_gap_effective"]),
                                     _num(b["amplification_predicted_oos"]),
                                     _num(b["time_gap_effective_oos"]),
                                     _num(c["amplification_predicted_oos"]),
                                     _num(c["time_gap_effective_oos"]), effs))

    def summary(amp: str, tg: str) -> SelectionSummary:
        a, g = _col(rows, amp), _col(rows, tg) / _col(rows, "time_gap") - 1.0
        ok = np.isfinite(a)
        return SelectionSummary(**_errors(a[ok] / _col(rows, "band_gain")[ok] - 1.0,
                                          g[np.isfinite(g)]))

    base = summary("base_amplification", "base_time_gap")
    final = summary("amplification", "time_gap_fit")
    settings = {"seeds": [int(x) for x in seeds], "cars": cars, "files": files,
                "model": model, "hidden": None if hidden is None else hidden.__dict__.copy(),
                "candidates": None if candidates is None else list(candidates),
                "max_generations": max_generations, "pop_size": pop_size, "starts": starts,
                "seed": seed, **platoon}
    return SelectionCheck(tuple(rows), base, final,
                          float(np.mean([bool(r.effects) for r in rows])) if rows else 0.0,
                          acc, tuple(secs), settings)
