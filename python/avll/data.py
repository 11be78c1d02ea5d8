"""The canonical run: the library's own data model.

A run has a uniform time base, a command of a declared kind (``"acceleration"`` or
``"speed"``), the measured response (acceleration always; speed and position where
known), optionally the leader's trajectory, exogenous signals (``exo_<name>``) and
metadata. Loaders (CSV/Parquet, CARMA, OpenACC) produce runs; the calibration and
diagnosis code consume them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ._limits import check_range
from .models import UpperLevel

__all__ = ["Run", "DataError", "DataWarning", "PlausibilityWarning", "COMMAND_KINDS"]

COMMAND_KINDS = ("acceleration", "speed")
#: The initial states of a rollout (:mod:`avll.rollout`).
INITS = ("rest", "steady")


class DataError(ValueError):
    """Bad input data. The message names the file, the column and the row."""


class DataWarning(UserWarning):
    """Suspicious but usable input data (e.g. a sidecar entry for a run that is not
    in the data). The message names the file, the column and the line. A loader's
    ``strict=True`` (the CLI's ``--strict``) turns it into a :class:`DataError`."""


class PlausibilityWarning(DataWarning):
    """A value outside the physical range of road vehicles (speed, acceleration,
    time step, grade; see ``avll._limits.RANGES``) that is not so far out that
    the unit must be wrong. Names the file, the column and the line; ``strict=True``
    turns it into a :class:`DataError`."""


def _series(run_id: str, name: str, x: Any, n: int | None) -> np.ndarray:
    if isinstance(x, (str, bytes)):
        raise DataError(f"run {run_id!r}: column {name!r} must be numbers, got {x!r:.40}")
    try:
        arr = np.ascontiguousarray(np.asarray(x, dtype=np.float64))
    except (TypeError, ValueError, OverflowError) as e:
        raise DataError(f"run {run_id!r}: column {name!r} must be numbers ({e})") from None
    if arr.ndim != 1:
        raise DataError(f"run {run_id!r}: column {name!r} must be 1-D, got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise DataError(f"run {run_id!r}: column {name!r} has {arr.shape[0]} samples, expected {n}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise DataError(
            f"run {run_id!r}: column {name!r} row {int(bad[0])} is not finite ({arr[bad[0]]})"
        )
    return arr


@dataclass(frozen=True, eq=False)
class Run:
    """One measured (or synthetic) run on a uniform time base.

    ``a`` is the measured acceleration; ``command`` is what the lower level was
    told (``command_kind`` says whether it is an acceleration or a speed); ``v``
    and ``x`` are the measured speed and position; ``lead_*`` the predecessor's
    trajectory; ``upper`` the known upper-level law of the run (e.g. Table I's kg
    and Tg); ``exo`` exogenous signals such as ``grade``.
    """

    run_id: str
    t: np.ndarray
    a: np.ndarray
    command_kind: str = "acceleration"
    command: np.ndarray | None = None
    v: np.ndarray | None = None
    x: np.ndarray | None = None
    lead_x: np.ndarray | None = None
    lead_v: np.ndarray | None = None
    lead_a: np.ndarray | None = None
    exo: Mapping[str, np.ndarray] = field(default_factory=dict)
    upper: UpperLevel | None = None
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        rid = str(self.run_id)
        object.__setattr__(self, "run_id", rid)
        if self.command_kind not in COMMAND_KINDS:
            raise DataError(
                f"run {rid!r}: command_kind must be one of {COMMAND_KINDS}, "
                f"got {self.command_kind!r}"
            )
        t = _series(rid, "t", self.t, None)
        n = t.shape[0]
        if n < 2:
            raise DataError(f"run {rid!r}: needs at least 2 samples, got {n}")
        dts = np.diff(t)
        bad = np.flatnonzero(dts <= 0)
        if bad.size:
            raise DataError(
                f"run {rid!r}: column 't' is not increasing at row {int(bad[0]) + 1} "
                f"({t[bad[0]]} then {t[bad[0] + 1]})"
            )
        dt = float(np.median(dts))
        off = np.flatnonzero(np.abs(dts - dt) > 1e-3 * dt + 1e-9)
        if off.size:
            raise DataError(
                f"run {rid!r}: column 't' is not uniformly sampled at row {int(off[0]) + 1} "
                f"(step {dts[off[0]]:.6g} s, expected {dt:.6g} s); resample first"
            )
        object.__setattr__(self, "t", t)
        for name in ("a", "command", "v", "x", "lead_x", "lead_v", "lead_a"):
            val = getattr(self, name)
            if val is not None:
                object.__setattr__(self, name, _series(rid, name, val, n))
        for name, ok, what in (("exo", isinstance(self.exo, Mapping), "a mapping"),
                               ("meta", isinstance(self.meta, Mapping), "a mapping"),
                               ("upper", self.upper is None or isinstance(self.upper, UpperLevel),
                                "an avll.UpperLevel or None")):  # fmt: skip
            if not ok:
                raise DataError(f"run {rid!r}: {name} must be {what}, got "
                                f"{getattr(self, name)!r:.40}")
        exo = {k: _series(rid, f"exo_{k}", v, n) for k, v in self.exo.items()}
        for k, v in exo.items():  # a loader checks a file's grade against its own range
            check_range(v, "other", f"run {rid!r}: column 'exo_{k}'", DataError)
        object.__setattr__(self, "exo", exo)
        object.__setattr__(self, "meta", dict(self.meta))

    @property
    def dt(self) -> float:
        """The sample time (s)."""
        return float((self.t[-1] - self.t[0]) / (self.t.shape[0] - 1))

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def cut(self, start: int, stop: int, suffix: str, note: str | None = None) -> Run:
        """Samples ``start:stop`` of every series as the run ``<run_id><suffix>`` (the
        cut recorded in ``meta["cleaning"]`` when ``note`` is given)."""
        sl = slice(start, stop)
        series: dict[str, Any] = {
            k: None if getattr(self, k) is None else getattr(self, k)[sl]
            for k in ("command", "v", "x", "lead_x", "lead_v", "lead_a")}  # fmt: skip
        meta = dict(self.meta)
        if note is not None:
            meta["cleaning"] = [*meta.get("cleaning", []), note]
        return replace(self, run_id=f"{self.run_id}{suffix}", t=self.t[sl], a=self.a[sl],
                       exo={k: v[sl] for k, v in self.exo.items()}, meta=meta,
                       **series)  # fmt: skip


def check_runs(runs: Any) -> list[Run]:
    """``runs`` as a list of :class:`Run` of one command kind, or a ``TypeError`` /
    ``ValueError`` naming the argument (a single run, a string, an empty sequence,
    a non-run element, mixed command kinds)."""
    if isinstance(runs, (str, bytes, Run)) or not hasattr(runs, "__iter__"):
        raise TypeError(f"runs: expected a sequence of avll.Run, got {type(runs).__name__}")
    runs = list(runs)
    if not runs:
        raise ValueError("runs: no runs given")
    for r in runs:
        if not isinstance(r, Run):
            raise ValueError(f"runs: expected avll.Run objects, got {type(r).__name__}")
    kinds = {r.command_kind for r in runs}
    if len(kinds) != 1:
        raise ValueError(f"runs: mixed command kinds {sorted(kinds)}")
    return runs
