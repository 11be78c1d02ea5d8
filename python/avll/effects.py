"""Effects: self-contained extensions of any base model.

Each effect is a small frozen dataclass with its own bounded parameters, and the
registry name that scripts depend on. Two levels (the class attribute ``level``):
the *lower level* -- ``asymmetric``, ``saturation``, ``rate_limit``, ``deadband``,
``speed_drag``, ``grade``, ``delay``, ``road_load``, ``power_limit``, ``sensor`` --
between the command and the vehicle, and the *upper level* -- ``perception``,
``speed_gains``, ``closing``, ``feedforward``, ``comfort`` -- the structures of the
car-following law that the constant-time-gap law (paper Eq. 3) lacks, which act only
in a closed loop (behind a recorded leader, in a platoon). The registry (names,
parameter order, calibration bounds, neutral values, exogenous signals, level,
exclusions, canonical order) is read from the Rust core (``_core.effect_info()``); the
classes add the physical validation. A base model with effects is a
:class:`WithEffects`, which every rollout and batched call takes in place of a base
model (:func:`avll.simulate`, :func:`avll.simulate_full`, :func:`avll.closed_loop`,
:func:`avll.platoon`, :func:`avll.batch_cost`, :func:`avll.calibrate`); they run in the
Rust engine (``rust/effects/``), which equals the linear rollouts exactly when no
effect is given.

Definitions (``u`` command, ``u_ref = u' + K a`` the inner loop's reference input,
``a`` the actual acceleration, ``v`` the actual speed):

* ``delay(tau)``: ``u'(t) = u(t - tau)``, a command transport delay outside the
  inner loop, fractional by linear interpolation between samples;
* ``rate_limit(j_max)``: ``u'`` follows ``u`` with slew rate at most ``j_max``
  (m/s³ for an acceleration command: a jerk limit);
* ``deadband(delta)``: ``u' = sign(u) max(|u| - delta, 0)`` (for a speed command, on
  the speed error);
* ``asymmetric(kb, rb)``: while braking the lower level is ``kb G(rb s)``: braking
  gain ratio ``kb`` and time-scale ratio ``rb`` (1, 1 = symmetric);
* ``saturation(a_max, d_max)``: ``a = clip(a_lin, -d_max, a_max)``;
* ``speed_drag(c0, c2)``: ``a += -(c0 s(v) + c2 v |v|)``, ``s(v) = clip(v/0.1, -1, 1)``;
* ``grade(g_eff)``: ``a += -g_eff * exo_grade`` (``g_eff = 9.81`` m/s²: no compensation);
* ``road_load(c0, c1, c2)``: ``a += -(c0 s(v) + c1 v + c2 v |v|)``, the full coast-down
  polynomial (``speed_drag`` is its ``c1 = 0`` case; the two are not offered together);
* ``power_limit(p, v_b)``: ``a = min(a_lin, p / max(|v|, v_b))``, a traction limit from
  the specific power ``p`` = P/m (W/kg) with the constant (torque) limit ``p / v_b``
  below the base speed ``v_b``;
* ``sensor(tau, bias)``: the *observed* acceleration is ``1/(tau s + 1) a + bias``
  (exact ZOH of the lag); the dynamics, the speed and every feedback use the true ``a``.

Upper level (``gap = x_p - x`` and ``dv = v_p - v`` the radar's signals, ``v`` the own
speed; the law ``u = kg (gap - Tg v - Gmin) + kv dv`` evaluated in the stages
perceive, gains, shape, feedforward, limit; see ``rust/effects/mod.rs``):

* ``perception(tau)``: ``gap`` and ``dv`` seen ``tau`` late (fractional delay); the own
  speed is not delayed;
* ``speed_gains(ch, cs)``: ``Tg(v) = Tg + ch v`` (desired gap ``Gmin + Tg v + ch v²``),
  ``kg, kv`` divided by ``max(1 + cs v, 0.1)``;
* ``closing(rg, rv)``: the gap term ``kg e`` times ``rg`` when ``e < 0`` (closer than
  desired), the speed term ``kv dv`` times ``rv`` when ``dv < 0`` (closing in);
* ``feedforward(ka, tau)``: ``u += ka s/(tau s + 1) (v + dv)``, a gain on the filtered
  derivative of the perceived predecessor speed;
* ``comfort(a_max, d_max, j_max)``: the command clipped to ``[-d_max, a_max]`` and
  slew-limited to ``j_max`` (refused together with ``rate_limit``, the same slew limit).

Their small-signal forms (:meth:`WithEffects.upper_linear`) enter the follower's exact
frequency response (:func:`avll.effect_stability.frequency_response`).

Command hooks apply in the canonical order (:data:`CANONICAL_ORDER`); see
``rust/effects/mod.rs``. The acceleration-level effects (``saturation``,
``power_limit``, ``speed_drag``, ``road_load``, ``grade``) also apply to a speed-command
model: they act on the acceleration that integrates into its actual speed (the
derivative of the speed response), and the inner loop's ``K`` feeds back the actual
speed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import astuple, dataclass, fields
from typing import Any, ClassVar

import numpy as np

from . import _core
from .models import LowerLevelModel, _check, model_class

__all__ = [
    "Effect",
    "Asymmetric",
    "Saturation",
    "RateLimit",
    "Deadband",
    "SpeedDrag",
    "Grade",
    "Delay",
    "RoadLoad",
    "PowerLimit",
    "Sensor",
    "Perception",
    "SpeedGains",
    "Closing",
    "Feedforward",
    "Comfort",
    "EFFECTS",
    "CANONICAL_ORDER",
    "WithEffects",
    "effect_class",
    "equivalent_model",
    "exo_needs",
]


#: The Rust registry by name (canonical order), as ``_core.effect_info()`` gives it.
_INFO: dict[str, dict[str, Any]] = {str(d["name"]): dict(d) for d in _core.effect_info()}


@dataclass(frozen=True)
class Effect:
    """Base class of the effects. ``bounds`` are the calibration search bounds;
    ``neutral`` the parameters at which the effect is (or tends to) the identity;
    ``exo`` the exogenous signal it reads; ``needs_speed`` whether it reads the actual
    speed; ``level`` ``"lower"`` or ``"upper"`` (an upper-level structure of the
    car-following law, which acts only in a closed loop); ``excludes`` an effect the
    library refuses together with this one (not identifiable together). All are taken
    from the Rust registry when a subclass names itself.

    How a calibration and the diagnosis (:mod:`avll.diagnose`) treat the effect is
    declared here too, so that a new effect is one class: ``fixed`` (command kind ->
    parameter -> value) pins parameters a command kind cannot identify (a speed
    command has no braking gain); ``signature`` is how the
    diagnosis probes it: ``"linear"`` (one signature column per free parameter, the
    rule for any effect that declares nothing), ``"setting"`` (one column per trial
    setting, profiled: threshold effects), ``"each"`` (one column per parameter of a
    trial setting) or ``"scaled"`` (one column, the hint scales the setting);
    ``trials`` are the fixed trial settings (empty: from the data, or the generic
    steps of :mod:`avll.diagnose.signatures`)."""

    name: ClassVar[str] = ""
    bounds: ClassVar[tuple[tuple[float, float], ...]] = ()
    neutral: ClassVar[tuple[float, ...]] = ()
    exo: ClassVar[str | None] = None
    accel_only: ClassVar[bool] = False
    needs_speed: ClassVar[bool] = False
    level: ClassVar[str] = "lower"
    fixed: ClassVar[dict[str, dict[str, float]]] = {}
    excludes: ClassVar[str | None] = None
    signature: ClassVar[str] = "linear"
    trials: ClassVar[tuple[dict[str, float], ...]] = ()
    #: The parameters that must be > 0 and those that must be >= 0.
    positive: ClassVar[tuple[str, ...]] = ()
    nonneg: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "name" not in cls.__dict__:
            return  # a subclass of a registered effect keeps its registry entry
        name = cls.__dict__["name"]
        if name not in _INFO:
            raise TypeError(f"effect class {cls.__name__}: {name!r} is not in the Rust registry")
        info = _INFO[name]
        cls.bounds = tuple((float(a), float(b)) for a, b in info["bounds"])
        cls.neutral = tuple(float(x) for x in info["neutral"])
        cls.exo = None if info["exo"] is None else str(info["exo"])
        cls.accel_only = bool(info["accel_only"])
        cls.needs_speed = bool(info["needs_speed"])
        cls.level = str(info["level"])
        cls.excludes = None if info["excludes"] is None else str(info["excludes"])

    def __post_init__(self) -> None:
        for f in fields(self):
            _check(f"{self.name}.{f.name}", getattr(self, f.name))
        for p in self.positive:
            _check(f"{self.name}.{p}", getattr(self, p), positive=True)
        for p in self.nonneg:
            _check(f"{self.name}.{p}", getattr(self, p), nonneg=True)

    @classmethod
    def param_names(cls) -> tuple[str, ...]:
        """Parameter names in array order."""
        return tuple(f.name for f in fields(cls))

    def to_array(self) -> np.ndarray:
        """The parameters as a float64 array."""
        return np.array(astuple(self), dtype=np.float64)

    @classmethod
    def from_array(cls, values: Any) -> Effect:
        """Builds the effect from values in :meth:`param_names` order."""
        vals = [float(v) for v in np.asarray(values, dtype=np.float64).ravel()]
        if len(vals) != len(cls.param_names()):
            raise ValueError(
                f"params: {cls.__name__} takes {len(cls.param_names())} values, got {len(vals)}"
            )
        return cls(*vals)

    def to_dict(self) -> dict[str, float]:
        """The parameters by name."""
        return {n: float(v) for n, v in zip(self.param_names(), astuple(self), strict=True)}


@dataclass(frozen=True)
class Delay(Effect):
    """Extra command transport delay ``tau`` (s), outside the inner loop."""

    tau: float = 0.0
    name: ClassVar[str] = "delay"
    signature: ClassVar[str] = "setting"
    trials: ClassVar[tuple[dict[str, float], ...]] = tuple(
        {"tau": t} for t in (0.05, 0.1, 0.2, 0.35, 0.5, 0.8))
    nonneg: ClassVar[tuple[str, ...]] = ("tau",)


@dataclass(frozen=True)
class RateLimit(Effect):
    """Slew-rate limit ``j_max`` of the command (m/s³ for an acceleration command)."""

    j_max: float = 30.0
    name: ClassVar[str] = "rate_limit"
    signature: ClassVar[str] = "setting"
    positive: ClassVar[tuple[str, ...]] = ("j_max",)


@dataclass(frozen=True)
class Deadband(Effect):
    """Continuous dead zone of half-width ``delta`` around zero demand."""

    delta: float = 0.0
    name: ClassVar[str] = "deadband"
    signature: ClassVar[str] = "setting"
    nonneg: ClassVar[tuple[str, ...]] = ("delta",)


@dataclass(frozen=True)
class Asymmetric(Effect):
    """Braking gain ratio ``kb`` and braking time-scale ratio ``rb``."""

    kb: float = 1.0
    rb: float = 1.0
    name: ClassVar[str] = "asymmetric"
    fixed: ClassVar[dict[str, dict[str, float]]] = {"speed": {"kb": 1.0}}
    trials: ClassVar[tuple[dict[str, float], ...]] = ({"kb": 0.8, "rb": 1.25},)
    positive: ClassVar[tuple[str, ...]] = ("kb", "rb")


@dataclass(frozen=True)
class Saturation(Effect):
    """Acceleration limit ``a_max`` and deceleration limit ``d_max`` (m/s², > 0)."""

    a_max: float = 6.0
    d_max: float = 10.0
    name: ClassVar[str] = "saturation"
    signature: ClassVar[str] = "each"
    positive: ClassVar[tuple[str, ...]] = ("a_max", "d_max")


@dataclass(frozen=True)
class SpeedDrag(Effect):
    """Uncompensated resistance ``c0`` (m/s²) + ``c2 v²`` (``c2`` in 1/m)."""

    c0: float = 0.0
    c2: float = 0.0
    name: ClassVar[str] = "speed_drag"
    trials: ClassVar[tuple[dict[str, float], ...]] = ({"c0": 0.05, "c2": 0.001},)


@dataclass(frozen=True)
class Grade(Effect):
    """Uncompensated grade term ``-g_eff * exo_grade`` (``g_eff`` in m/s²)."""

    g_eff: float = 0.0
    name: ClassVar[str] = "grade"
    signature: ClassVar[str] = "scaled"
    trials: ClassVar[tuple[dict[str, float], ...]] = ({"g_eff": 5.0},)


@dataclass(frozen=True)
class RoadLoad(Effect):
    """Uncompensated road load ``a += -(c0 s(v) + c1 v + c2 v |v|)``, ``s(v) =
    clip(v/0.1, -1, 1)``: the coast-down polynomial ``(A + B v + C v²)/m`` with ``c0``
    (m/s²), ``c1`` (1/s), ``c2`` (1/m), all ``>= 0`` (resistive). ``speed_drag`` is its
    ``c1 = 0`` case; the two are refused together (not identifiable).

    Calibration bounds: ``c0`` in [0, 0.6] m/s² (rolling resistance ``f_r g`` is about
    0.1 m/s² at ``f_r = 0.01``; soft surfaces and brake drag reach a few times that);
    ``c1`` in [0, 0.03] 1/s (coast-down fits give ``B/m`` of 0.001-0.01 1/s); ``c2`` in
    [0, 0.002] 1/m (``rho Cd A/(2 m)`` is 2-4e-4 1/m for cars and loaded trucks; a
    headwind as fast as the vehicle quadruples it).

    Linearisation at a speed ``v``: the speed feedback ``-beta dv``, ``beta = c1 +
    2 c2 v`` (1/s), the factor ``s/(s + beta)`` on the acceleration; exact as a base
    model only for ``beta = 0`` (``WithEffects.linear(terms=True)`` returns ``beta``)."""

    c0: float = 0.0
    c1: float = 0.0
    c2: float = 0.0
    name: ClassVar[str] = "road_load"
    nonneg: ClassVar[tuple[str, ...]] = ("c0", "c1", "c2")


@dataclass(frozen=True)
class PowerLimit(Effect):
    """Traction limit from power: ``a = min(a_lin, p / max(|v|, v_b))`` with the specific
    power ``p`` = P/m (W/kg = m²/s³) at the wheels and the base speed ``v_b`` (m/s)
    below which the cap is the constant torque limit ``p / v_b`` (and stays finite at
    rest). Braking is not limited.

    Calibration bounds: ``p`` in [5, 500] W/kg (a loaded 40-60 t truck with 300-400 kW
    has 5-10 W/kg, hypercars about 500 W/kg); ``v_b`` in [0.5, 20] m/s (the corner of the
    torque-power curve: a few m/s for an engine in first gear, 10-20 m/s for an
    electric motor). At the neutral ``(500, 0.5)`` the cap exceeds the friction limit
    (~10 m/s²) below 50 m/s.

    Linearisation: the identity (small signals about cruising stay below the cap,
    which is positive at every speed); the limit itself is amplitude dependent."""

    p: float = 500.0
    v_b: float = 0.5
    name: ClassVar[str] = "power_limit"
    positive: ClassVar[tuple[str, ...]] = ("p", "v_b")


@dataclass(frozen=True)
class Sensor(Effect):
    """Bias and first-order lag of the *measured* acceleration: the recorded and
    compared acceleration is ``a_obs = 1/(tau s + 1) a + bias`` (``tau`` in s, ``bias``
    in m/s²), while the dynamics, the speed and every feedback use the true ``a``.
    Discretized exactly for ``a[n]`` held over ``(t[n-1], t[n]]``: ``f[n] = alpha f[n-1]
    + (1 - alpha) a[n]``, ``alpha = exp(-dt/tau)`` (``tau = 0``: no lag), ``f[-1] = a[0]``.

    Calibration bounds: ``tau`` in [0, 1] s (accelerometer and CAN filtering, typically
    0.02-0.5 s); ``bias`` in [-0.5, 0.5] m/s² (a mounting pitch of a few degrees gives
    ``g sin(pitch)`` of a few tenths; more is a calibration error to fix in the data).

    Linearisation: the identity (the vehicle is unchanged); the observation filter and
    offset are returned by ``WithEffects.linear(terms=True)``."""

    tau: float = 0.0
    bias: float = 0.0
    name: ClassVar[str] = "sensor"
    nonneg: ClassVar[tuple[str, ...]] = ("tau",)


@dataclass(frozen=True)
class Perception(Effect):
    """Upper level: the radar's gap and relative speed reach the law ``tau`` (s) late
    (a fractional delay); the own speed is not delayed.

    Calibration bounds: ``tau`` in [0, 1.5] s (radar cycles of 50-100 ms plus tracking
    and filtering; identified ACC reaction delays are 0.3-1 s, part of which the lower
    level's ``Td`` holds). Small signal: ``e^{-tau s}`` on the radar terms
    ``(kg + kv s)(X_p - X)``; the own speed's ``kg Tg v`` is not delayed."""

    tau: float = 0.0
    name: ClassVar[str] = "perception"
    signature: ClassVar[str] = "setting"
    trials: ClassVar[tuple[dict[str, float], ...]] = tuple(
        {"tau": t} for t in (0.1, 0.2, 0.35, 0.5, 0.8))
    nonneg: ClassVar[tuple[str, ...]] = ("tau",)


@dataclass(frozen=True)
class SpeedGains(Effect):
    """Upper level: a time gap and gains that depend on the own speed ``v``:
    ``Tg(v) = Tg + ch v`` (``ch`` in s²/m; desired gap ``Gmin + Tg v + ch v²``, the
    variable-time-headway policy) and ``kg, kv`` divided by ``max(1 + cs v, 0.1)``
    (``cs`` in s/m: softer gains at speed for ``cs > 0``).

    Calibration bounds: ``ch`` in [-0.03, 0.06] s²/m (at 25 m/s the time gap moves
    by -0.75 to +1.5 s), ``cs`` in [-0.01, 0.05] s/m. Small signal at the operating
    speed ``v``: ``kg(v)``, ``kv(v)`` and the time gap ``Tg + 2 ch v`` (the slope of
    the desired gap; the equilibrium headway is ``Tg + ch v + Gmin/v``)."""

    ch: float = 0.0
    cs: float = 0.0
    name: ClassVar[str] = "speed_gains"


@dataclass(frozen=True)
class Closing(Effect):
    """Upper level: other gains while closing in. The law's gap term ``kg e`` is
    multiplied by ``rg`` when ``e < 0`` (closer than desired), its speed term ``kv dv``
    by ``rv`` when ``dv < 0`` (the predecessor slower). ACCs react harder to a closing
    gap: ``rg, rv > 1``.

    Calibration bounds: ``rg``, ``rv`` in [0.25, 4]. Small signal: the average slopes
    ``kg (1 + rg)/2``, ``kv (1 + rv)/2`` (the odd part; the even part shifts the mean
    gap error under an oscillation and returns through the closed loop as harmonics:
    an error of the order ``((r - 1)/(r + 1))^2``)."""

    rg: float = 1.0
    rv: float = 1.0
    name: ClassVar[str] = "closing"
    nonneg: ClassVar[tuple[str, ...]] = ("rg", "rv")


@dataclass(frozen=True)
class Feedforward(Effect):
    """Upper level: ``u += ka â`` with ``â = s/(tau s + 1) vp`` the filtered derivative
    of the perceived predecessor speed ``vp = v + dv`` (``ka`` in s, ``tau`` in s),
    discretized exactly for ``vp`` held over each interval, ``â = 0`` at the start.

    Calibration bounds: ``ka`` in [0, 1.5] s, ``tau`` in [0.2, 3] s. At ``ka = 0`` the
    filter has no effect (its neutral ``tau = 1`` s is a placeholder). Small signal:
    ``ka s/(tau s + 1)`` on ``V + e^{-delay s}(V_p - V)``."""

    ka: float = 0.0
    tau: float = 1.0
    name: ClassVar[str] = "feedforward"
    # At ka = 0 a change of tau alone changes nothing: one signature column from a
    # trial setting of both.
    signature: ClassVar[str] = "scaled"
    trials: ClassVar[tuple[dict[str, float], ...]] = ({"ka": 0.5, "tau": 0.8},)
    positive: ClassVar[tuple[str, ...]] = ("tau",)


@dataclass(frozen=True)
class Comfort(Effect):
    """Upper level: the law's command clipped to ``[-d_max, a_max]`` (m/s²) and
    slew-limited to ``j_max`` (m/s³), starting from 0 (the lower level at rest).

    Calibration bounds: ``a_max`` in [0.3, 4], ``d_max`` in [0.5, 8], ``j_max`` in
    [0.5, 30] (ISO 15622 caps ACC decelerations at 3.5-5 m/s², accelerations at 2-4
    m/s², and recommends jerks of 2.5-5 m/s³). Small signal: the identity inside the
    limits. Refused together with ``rate_limit`` (the same slew limit)."""

    a_max: float = 4.0
    d_max: float = 8.0
    j_max: float = 30.0
    name: ClassVar[str] = "comfort"
    signature: ClassVar[str] = "each"
    trials: ClassVar[tuple[dict[str, float], ...]] = (
        {"a_max": 1.0, "d_max": 1.5, "j_max": 2.5},)
    positive: ClassVar[tuple[str, ...]] = ("a_max", "d_max", "j_max")


def _registry() -> dict[str, type[Effect]]:
    classes = {c.name: c for c in Effect.__subclasses__() if "name" in c.__dict__}
    missing = [n for n in _INFO if n not in classes]
    if missing:
        raise ImportError(f"avll.effects: no Python class for the Rust effects {missing}")
    for n, c in classes.items():
        if list(c.param_names()) != list(_INFO[n]["params"]):
            raise ImportError(
                f"avll.effects: {c.__name__} parameters {c.param_names()} differ from the "
                f"Rust registry's {_INFO[n]['params']}"
            )
    return {n: classes[n] for n in _INFO}


#: The registered effects by name, in the canonical application order (the Rust
#: registry's).
EFFECTS: dict[str, type[Effect]] = _registry()
CANONICAL_ORDER: tuple[str, ...] = tuple(EFFECTS)


def effect_class(name: str | type[Effect] | Effect) -> type[Effect]:
    """The effect class for a registry name."""
    if isinstance(name, Effect):
        return type(name)
    if isinstance(name, type) and issubclass(name, Effect):
        return name
    try:
        return EFFECTS[str(name)]
    except KeyError:
        raise ValueError(
            f"effects: unknown effect {name!r}; known: {', '.join(EFFECTS)}"
        ) from None


def canonical(names: Sequence[str]) -> tuple[str, ...]:
    """Effect names sorted into the canonical order (duplicates rejected)."""
    for n in names:
        effect_class(n)
    if len(set(names)) != len(names):
        raise ValueError(f"effects: duplicate effect in {list(names)}")
    for n in names:
        x = EFFECTS[n].excludes
        if x is not None and x in names:
            raise ValueError(f"effects: {n!r} and {x!r} together: one contains the other, so "
                             "their parameters are not identifiable together; use one")
    return tuple(sorted(names, key=CANONICAL_ORDER.index))


@dataclass(frozen=True)
class WithEffects:
    """A base lower-level model extended by effects (at most one of each kind),
    kept in the canonical order."""

    base: LowerLevelModel
    effects: tuple[Effect, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.base, LowerLevelModel):
            raise ValueError(f"base: expected an avll model, got {type(self.base).__name__}")
        effs = tuple(self.effects)
        for e in effs:
            if not isinstance(e, Effect):
                raise ValueError(f"effects: expected Effect objects, got {type(e).__name__}")
        canonical([e.name for e in effs])  # known, no duplicates, no excluded pairs
        object.__setattr__(
            self, "effects", tuple(sorted(effs, key=lambda e: CANONICAL_ORDER.index(e.name)))
        )

    @property
    def name(self) -> str:
        """``base`` or ``base+effect+...``."""
        return "+".join([self.base.name, *self.effect_names])

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    @property
    def lower(self) -> tuple[Effect, ...]:
        """The lower-level effects (between the command and the vehicle)."""
        return tuple(e for e in self.effects if e.level == "lower")

    @property
    def upper(self) -> tuple[Effect, ...]:
        """The upper-level structures (of the car-following law; closed loop only)."""
        return tuple(e for e in self.effects if e.level == "upper")

    def upper_linear(self, upper: Any, *, v: float = 0.0) -> dict[str, float]:
        """The small-signal form of the law ``upper`` (an :class:`avll.UpperLevel`) with
        this model's upper-level structures at speed ``v``: ``kg``, ``kv``, ``Tg`` (the
        small-signal time gap, the slope of the desired gap), ``Tg_eq`` (the
        equilibrium's: the desired gap at ``v`` is ``Gmin + Tg_eq v``), ``Gmin``,
        ``delay`` (the radar terms' perception delay, s), ``ff_gain`` and ``ff_tau``
        (the feedforward ``ff_gain s/(ff_tau s + 1)`` on the perceived predecessor
        speed); see ``rust/effects/mod.rs`` (``UpperLin``). Without structures:
        ``upper``'s gains, no delay, no feedforward."""
        from .models import UpperLevel

        if not isinstance(upper, UpperLevel):
            raise TypeError(f"upper: expected an avll.UpperLevel, got {upper!r:.60}")
        up = self.upper
        return dict(_core.linearize_upper(
            [e.name for e in up], [float(x) for e in up for x in e.to_array()],
            float(upper.kg), float(upper.kv), float(upper.Tg), float(upper.Gmin), float(v)))

    def param_names(self) -> tuple[str, ...]:
        """Base parameter names then ``effect.param`` names."""
        return self.base.param_names() + tuple(
            f"{e.name}.{p}" for e in self.effects for p in e.param_names()
        )

    def to_array(self) -> np.ndarray:
        """Base parameters then effect parameters (canonical order)."""
        return np.concatenate([self.base.to_array(), *[e.to_array() for e in self.effects]])

    @classmethod
    def from_array(
        cls, base: str | type[LowerLevelModel], effects: Sequence[str], values: Any
    ) -> WithEffects:
        """Builds base + effects from a parameter row (effects in canonical order)."""
        bcls = model_class(base)
        names = canonical(list(effects))
        vals = np.asarray(values, dtype=np.float64).ravel()
        nb = len(bcls.param_names())
        need = nb + sum(len(EFFECTS[n].param_names()) for n in names)
        if vals.size != need:
            raise ValueError(f"values: expected {need} values, got {vals.size}")
        out, o = [], nb
        for n in names:
            k = len(EFFECTS[n].param_names())
            out.append(EFFECTS[n].from_array(vals[o : o + k]))
            o += k
        return cls(bcls.from_array(vals[:nb]), tuple(out))

    def linear(self, *, v: float = 0.0, side: int = 0, terms: bool = False) -> dict[str, float]:
        """The small-signal equivalent ``b1, b0, a2, a1, Td, K`` at speed ``v`` on
        ``side`` (1 acceleration, -1 braking, 0 their average), for the stability
        engine. Raises ``ValueError`` when an effect has no such equivalent
        (``speed_drag``/``road_load`` with a speed feedback ``beta != 0`` at ``v``,
        ``delay`` with ``K != 0``). ``saturation``, ``power_limit``, ``rate_limit``,
        ``deadband``, ``grade`` and ``sensor`` are the identity in the small signal, and
        so is every upper-level structure (see :meth:`upper_linear`).

        With ``terms=True`` the speed-dependent resistances do not fail: the result
        is the lower level's own equivalent plus ``speed_feedback`` (``beta``, 1/s: the
        actual acceleration gets ``-beta dv``), ``obs_tau`` (s) and ``obs_bias`` (m/s²),
        the filter ``1/(obs_tau s + 1)`` and offset of the *observed* acceleration
        (``sensor``; not a dynamic of the vehicle), and ``command_delay`` (s), the
        ``delay`` effect's factor ``e^{-tau s}`` outside the inner loop (with ``K = 0``
        the non-``terms`` form adds it to ``Td`` instead)."""
        return dict(_core.linearize_effects(
            self.base.name, [float(x) for x in self.base.to_array()], list(self.effect_names),
            [float(x) for e in self.effects for x in e.to_array()], float(v), int(side),
            terms=bool(terms)))


def equivalent_model(
    model: WithEffects, *, v: float = 0.0, side: int = 0
) -> LowerLevelModel:
    """The small-signal equivalent (:meth:`WithEffects.linear`) as a base-model
    object for the stability functions: a :class:`~avll.Proposed` (``m1 = b1, m2 = a2,
    m3 = a1, K0 = b0``) when the rational part is of second order, a
    :class:`~avll.FirstOrderLag` when it is a unit-gain lag without dead time or
    feedback; ``ValueError`` otherwise (e.g. a first-order lag with a braking gain)."""
    from .models import FirstOrderLag, Proposed

    c = model.linear(v=v, side=side)
    if c["a2"] > 0:
        return Proposed(m1=c["b1"], m2=c["a2"], m3=c["a1"], K0=c["b0"], Td=c["Td"], K=c["K"])
    if c["b1"] == 0 and c["b0"] == 1 and c["Td"] == 0 and c["K"] == 0 and c["a1"] > 0:
        return FirstOrderLag(Td=c["a1"])
    raise ValueError(
        f"model: the equivalent {c} is neither second order nor a unit-gain first-order lag"
    )


def exo_needs(effects: Sequence[str]) -> dict[str, str]:
    """The exogenous signal each of ``effects`` reads (effect name -> signal name)."""
    return {n: s for n in effects if (s := EFFECTS[n].exo) is not None}
