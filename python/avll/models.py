"""Parameter objects of the lower-level controller models (paper Eqs. 1, 2, 5)
and of the upper-level constant-time-gap law (Eq. 3).

Every model is a small frozen dataclass with the paper's parameter names. A
model's ``name`` is the short name used by the Rust core, the CLI and JSON files
(``"first"``, ``"second"``, ``"proposed"``).
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "LowerLevelModel",
    "FirstOrderLag",
    "SecondOrder",
    "Proposed",
    "UpperLevel",
    "MODELS",
    "model_class",
    "pade",
]


#: The paper's Padé order of the delay and standstill spacing (m), the defaults of
#: :meth:`LowerLevelModel.transfer_function` and :class:`UpperLevel`: written here, as
#: :mod:`avll.paper` builds on this module, and named by it (``PADE_ORDER``, ``GMIN``).
PADE_ORDER, GMIN = 2, 9.5


def _check(name: str, value: float, *, positive: bool = False, nonneg: bool = False) -> None:
    if not isinstance(value, (int, float, np.floating, np.integer)) or isinstance(value, bool):
        raise ValueError(f"{name}: must be a number, got {value!r}")
    try:
        finite = math.isfinite(value)
    except OverflowError:  # an int beyond the float range
        raise ValueError(f"{name}: must be finite, got {value!r:.40}") from None
    if not finite:
        raise ValueError(f"{name}: must be finite, got {value}")
    if positive and not value > 0:
        raise ValueError(f"{name}: must be > 0, got {value}")
    if nonneg and not value >= 0:
        raise ValueError(f"{name}: must be >= 0, got {value}")


@functools.cache
def _names(cls: type) -> tuple[str, ...]:
    """A dataclass's field names, cached per class."""
    return tuple(f.name for f in fields(cls))


@dataclass(frozen=True)
class LowerLevelModel(ABC):
    """Base class: a strictly proper rational part, a dead time and an inner feedback.

    ``G(s) = (b1 s + b0) e^{-Td s} / (a2 s^2 + a1 s + 1)`` and ``G_fb = G / (1 - K G)``.
    """

    name: ClassVar[str] = ""
    #: The parameters that must be > 0 and those that must be >= 0.
    positive: ClassVar[tuple[str, ...]] = ()
    nonneg: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        for n in _names(type(self)):
            _check(n, getattr(self, n), positive=n in self.positive, nonneg=n in self.nonneg)

    @classmethod
    def param_names(cls) -> tuple[str, ...]:
        """The parameter names in array order (the paper's notation)."""
        return _names(cls)

    def values(self) -> list[float]:
        """The parameters as floats, in :meth:`param_names` order (no copy of the
        object: cheap enough for a per-call path)."""
        return [float(getattr(self, n)) for n in _names(type(self))]

    def to_array(self) -> np.ndarray:
        """The parameters as a float64 array, in :meth:`param_names` order."""
        return np.array(self.values(), dtype=np.float64)

    @classmethod
    def from_array(cls, values: Any) -> LowerLevelModel:
        """Builds the model from values in :meth:`param_names` order."""
        try:
            vals = [float(v) for v in np.asarray(values, dtype=np.float64).ravel()]
        except (TypeError, ValueError, OverflowError) as e:
            raise ValueError(f"params: expected numbers ({e})") from None
        names = cls.param_names()
        if len(vals) != len(names):
            raise ValueError(
                f"params: {cls.__name__} takes {len(names)} values ({', '.join(names)}), "
                f"got {len(vals)}"
            )
        return cls(*vals)

    def to_dict(self) -> dict[str, float]:
        """The parameters by name."""
        return dict(zip(_names(type(self)), self.values(), strict=True))

    @abstractmethod
    def linear(self) -> dict[str, float]:
        """Coefficients ``b1, b0, a2, a1, Td, K`` of the common linear form."""

    @property
    def dc_gain(self) -> float:
        """Static gain of the lower level, ``K0 / (1 - K K0)``."""
        c = self.linear()
        return c["b0"] / (1.0 - c["K"] * c["b0"])

    def transfer_function(self, pade_order: int = PADE_ORDER) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator (highest power first) of ``G_fb(s)`` with the dead
        time replaced by its Padé approximation of ``pade_order`` (exact when Td = 0):
        ``G_fb = Ga / (Gb - K Ga)``, ``Ga = (b1 s + b0) Q(-s)``,
        ``Gb = (a2 s^2 + a1 s + 1) Q(s)``."""
        c = self.linear()
        pn, pd = pade(c["Td"], pade_order)
        ga = np.polymul(np.trim_zeros(np.array([c["b1"], c["b0"]]), "f"), pn)
        gb = np.polymul(np.trim_zeros(np.array([c["a2"], c["a1"], 1.0]), "f"), pd)
        den = np.polysub(gb, c["K"] * ga)
        return np.trim_zeros(ga, "f"), np.trim_zeros(den, "f")

    def to_scipy(self, pade_order: int = PADE_ORDER) -> Any:
        """A continuous ``scipy.signal.TransferFunction`` of ``G_fb`` (dead time by Padé)."""
        from scipy import signal

        return signal.TransferFunction(*self.transfer_function(pade_order))

    def to_control(self, pade_order: int = PADE_ORDER) -> Any:
        """A ``control.TransferFunction`` of ``G_fb`` (python-control, an optional
        dependency: ``pip install avll[control]``), dead time by Padé."""
        try:
            import control
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("to_control() needs python-control: pip install control") from e
        return control.tf(*self.transfer_function(pade_order))


@dataclass(frozen=True)
class FirstOrderLag(LowerLevelModel):
    """First-order lag, paper Eq. 1: ``1 / (Td s + 1)``; ``Td`` (s) is the time constant."""

    Td: float
    name: ClassVar[str] = "first"
    positive: ClassVar[tuple[str, ...]] = ("Td",)

    def linear(self) -> dict[str, float]:
        """``1/(Td s + 1)``: no dead time, the lag time constant as ``a1``."""
        return {"b1": 0.0, "b0": 1.0, "a2": 0.0, "a1": self.Td, "Td": 0.0, "K": 0.0}


@dataclass(frozen=True)
class SecondOrder(LowerLevelModel):
    """Second-order response with dead time, Eq. 2 with ``m1 = 0``:
    ``K0 e^{-Td s} / (m2 s^2 + m3 s + 1)``."""

    K0: float
    m2: float
    m3: float
    Td: float
    name: ClassVar[str] = "second"
    positive: ClassVar[tuple[str, ...]] = ("m2",)
    nonneg: ClassVar[tuple[str, ...]] = ("Td",)

    def linear(self) -> dict[str, float]:
        """``K0 e^{-Td s}/(m2 s^2 + m3 s + 1)`` in the common form (``K = 0``)."""
        return {"b1": 0.0, "b0": self.K0, "a2": self.m2, "a1": self.m3, "Td": self.Td, "K": 0.0}


@dataclass(frozen=True)
class Proposed(LowerLevelModel):
    """The paper's proposed model, Eqs. 2 and 5: ``G / (1 - K G)`` with
    ``G = (m1 s + K0) e^{-Td s} / (m2 s^2 + m3 s + 1)``."""

    m1: float
    m2: float
    m3: float
    K0: float
    Td: float
    K: float
    name: ClassVar[str] = "proposed"
    positive: ClassVar[tuple[str, ...]] = ("m2",)
    nonneg: ClassVar[tuple[str, ...]] = ("Td",)

    def linear(self) -> dict[str, float]:
        """The paper's parameters in the common form: ``b1 = m1, b0 = K0, a2 = m2,
        a1 = m3``."""
        return {"b1": self.m1, "b0": self.K0, "a2": self.m2, "a1": self.m3, "Td": self.Td,
                "K": self.K}


@dataclass(frozen=True)
class UpperLevel:
    """Constant-time-gap law, paper Eq. 3:
    ``a_cmd = kg (x_lead - x - Tg v - Gmin) + kv (v_lead - v)``."""

    kg: float
    kv: float = 0.0
    Tg: float = 2.0
    Gmin: float = GMIN

    def __post_init__(self) -> None:
        for f in fields(self):
            _check(f.name, getattr(self, f.name))

    def command(self, lead_x: Any, lead_v: Any, x: Any, v: Any) -> Any:
        """The command acceleration for the given states (arrays broadcast)."""
        return self.kg * (lead_x - x - self.Tg * v - self.Gmin) + self.kv * (lead_v - v)

    def to_array(self) -> np.ndarray:
        """``[kg, kv, Tg, Gmin]`` as float64."""
        return np.array([self.kg, self.kv, self.Tg, self.Gmin], dtype=np.float64)


def pade(td: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Padé approximation of ``e^{-td s}``: numerator ``Q(-s)`` and denominator ``Q(s)``
    (highest power first), ``Q(s) = sum_k c_k (td s)^k`` with
    ``c_k = (2n-k)! n! / ((2n)! k! (n-k)!)``. ``td = 0`` gives ``1/1``."""
    if not (isinstance(order, (int, np.integer)) and 0 <= order <= 10):
        raise ValueError(f"pade_order: must be an integer in 0..10, got {order!r}")
    _check("Td", td, nonneg=True)
    if td == 0 or order == 0:
        return np.array([1.0]), np.array([1.0])
    n = int(order)
    c = [
        math.factorial(2 * n - k) * math.factorial(n)
        / (math.factorial(2 * n) * math.factorial(k) * math.factorial(n - k))
        * td**k
        for k in range(n + 1)
    ]
    den = np.array(c[::-1])
    num = np.array([ck * (-1) ** k for k, ck in enumerate(c)][::-1])
    return num, den


def _registry() -> dict[str, type[LowerLevelModel]]:
    """The base models the Rust core registers (``_core.model_names()``, in its order),
    each with its Python class; a class whose parameters differ from the core's is an
    error at import, not a wrong result later."""
    from . import _core

    classes = {m.name: m for m in (FirstOrderLag, SecondOrder, Proposed)}
    out: dict[str, type[LowerLevelModel]] = {}
    for name in _core.model_names():
        cls = classes.get(name)
        if cls is None or tuple(_core.model_params(name)) != cls.param_names():
            raise ImportError(f"avll: the compiled core's model {name!r} does not match the "
                              "Python layer (rebuild the extension)")
        out[name] = cls
    return out


#: The registered base models by short name (the Rust core's registry).
MODELS: dict[str, type[LowerLevelModel]] = _registry()


def model_class(name: str | type[LowerLevelModel] | LowerLevelModel) -> type[LowerLevelModel]:
    """The model class for a short name (``"first"``, ``"second"``, ``"proposed"``)."""
    if isinstance(name, LowerLevelModel):
        return type(name)
    if isinstance(name, type) and issubclass(name, LowerLevelModel):
        return name
    try:
        return MODELS[str(name)]
    except KeyError:
        raise ValueError(f"model: unknown model {name!r}; known: {', '.join(MODELS)}") from None
