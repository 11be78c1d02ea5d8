"""The run set: measured runs packed once into Rust and passed to every batched call.

:class:`RunSet` wraps the Rust handle (``avll._core.RunSet``), each method a thin
delegation. It is built once from :class:`avll.Run` objects with every column that
all runs have (command, leader, speed, position, upper-level law, exogenous
signals), not only what one cost needs; which columns a call needs is checked when
the call is made (:meth:`RunSet.cost_kw`). Folds, resamples and candidate subsets
are :meth:`RunSet.subset` views sharing the packed arrays: nothing is copied again.
Functions that take a run set also take a plain list of runs, packed once at the
door (:func:`as_runset`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any, overload

import numpy as np

from . import _core
from ._limits import check_choice
from .data import INITS, Run, check_runs
from .defaults import objective_weights, upper_index

__all__ = ["RunSet", "as_runset"]

_SERIES = ("command", "lead_x", "lead_v", "v", "x")


def _concat(runs: Sequence[Run], attr: str) -> np.ndarray | None:
    """The column concatenated over runs, or None unless every run has it."""
    parts = [getattr(r, attr) for r in runs]
    if any(p is None for p in parts):
        return None
    return np.ascontiguousarray(np.concatenate(parts), dtype=np.float64)


class RunSet(Sequence[Run]):
    """Runs packed once into Rust (a view on some of them: see :meth:`subset`); a
    sequence of its :class:`avll.Run` objects, so that code written for a list of
    runs takes it as it is.

    ``RunSet(runs)`` packs every column that all ``runs`` have; ``len()`` is the
    number of runs, :attr:`run_ids` their ids, :attr:`runs` the :class:`avll.Run`
    objects themselves (kept for labels and error messages)."""

    __slots__ = ("_handle", "_runs", "_all_runs", "_cols", "_has_upper", "_upper")

    def __init__(self, runs: Iterable[Run]) -> None:
        runs = tuple(check_runs(runs))
        offsets = [0, *np.cumsum([len(r) for r in runs]).tolist()]
        has_upper = tuple(r.upper is not None for r in runs)
        upper = None
        if any(has_upper):
            upper = np.ascontiguousarray(np.vstack(
                [np.zeros(4) if r.upper is None else r.upper.to_array() for r in runs]))
        exo = {n: np.ascontiguousarray(np.concatenate([r.exo[n] for r in runs]),
                                       dtype=np.float64)
               for n in sorted(set.intersection(*(set(r.exo) for r in runs)))}  # fmt: skip
        cols = {c: _concat(runs, c) for c in _SERIES}
        self._handle = _core.RunSet(
            [int(o) for o in offsets], np.array([r.dt for r in runs], dtype=np.float64),
            np.ascontiguousarray(np.concatenate([r.a for r in runs]), dtype=np.float64),
            upper=upper, exo=exo, **cols,
        )  # fmt: skip
        self._all_runs = runs
        self._runs = runs
        self._cols = frozenset(c for c, v in cols.items() if v is not None)
        self._has_upper = has_upper
        self._upper: Any = None

    @classmethod
    def _view(cls, parent: RunSet, handle: Any, upper: Any = None) -> RunSet:
        new = cls.__new__(cls)
        new._upper = upper
        new._handle = handle
        new._all_runs = parent._all_runs
        new._runs = tuple(parent._all_runs[i] for i in handle.index)
        new._cols = parent._cols
        new._has_upper = parent._has_upper
        return new

    # --- the handle's own answers -------------------------------------------------

    def __len__(self) -> int:
        return len(self._handle)

    def __iter__(self) -> Iterator[Run]:
        return iter(self._runs)

    @overload
    def __getitem__(self, i: int) -> Run: ...
    @overload
    def __getitem__(self, i: slice) -> RunSet: ...
    def __getitem__(self, i: int | slice) -> Run | RunSet:
        """Run ``i``, or a view on the runs of a slice."""
        if isinstance(i, slice):
            return self.subset(range(len(self))[i])
        return self._runs[i]

    @property
    def handle(self) -> Any:
        """The Rust run set (``avll._core.RunSet``) the batched calls take."""
        return self._handle

    @property
    def offsets(self) -> list[int]:
        """Run ``r`` is ``offsets[r]:offsets[r+1]`` of the runs laid end to end."""
        return list(self._handle.offsets)

    @property
    def total(self) -> int:
        """Samples over all runs."""
        return int(self._handle.total)

    def shares(self, other: RunSet) -> bool:
        """Whether ``other`` is a view of the same packed arrays (no copy between them)."""
        return bool(self._handle.shares(other._handle))

    # --- what Python keeps beside the handle -------------------------------------

    @property
    def runs(self) -> tuple[Run, ...]:
        """The runs of this set, in order."""
        return self._runs

    @property
    def run_ids(self) -> tuple[str, ...]:
        """The ids of the runs, in order."""
        return tuple(r.run_id for r in self._runs)

    @property
    def command_kind(self) -> str:
        return self._runs[0].command_kind

    @property
    def columns(self) -> frozenset[str]:
        """The packed optional series (of ``command, lead_x, lead_v, v, x``)."""
        return self._cols

    @property
    def exo_names(self) -> list[str]:
        return list(self._handle.exo_names)

    def has(self, column: str) -> bool:
        """Whether every run of the set has ``column`` (packed)."""
        return column in self._cols

    def indices(self, subset: Iterable[Any], name: str = "subset") -> list[int]:
        """Run positions of ``subset`` (positions or run ids; repeats allowed)."""
        return positions(self.run_ids, subset, name)

    def subset(self, subset: Iterable[Any]) -> RunSet:
        """A view on some runs (positions or run ids, repeats allowed) sharing the
        packed arrays."""
        return RunSet._view(self, self._handle.take(self.indices(subset)), self._upper)

    @property
    def upper(self) -> Any:
        """The upper-level law that replaces every run's own in the simulations and
        errors of the diagnosis (:meth:`with_upper`), or None."""
        return self._upper

    def with_upper(self, upper: Any) -> RunSet:
        """The same runs (the same packed arrays) with ``upper`` (an
        :class:`avll.UpperLevel`) replacing each run's upper-level law wherever the
        set is simulated or scored by :func:`avll.diagnose.fitting.simulate_runs` and
        :func:`avll.diagnose.fitting.run_mse` (the gains enter the parameter row as
        free gains: nothing is packed again)."""
        return RunSet._view(self, self._handle, upper)

    def cost_kw(
        self,
        *,
        weights: Sequence[float] | None = None,
        init: str = "rest",
        closed_loop: bool = False,
        upper_free: Sequence[int] = (),
        exo: Mapping[str, str] | None = None,
    ) -> dict[str, Any]:
        """The run set and cost options of the Rust batched calls, after checking that
        every run has what this objective needs (the command in open loop, the leader,
        speed, position and upper-level law in closed loop, ``v``/``x`` when weighted,
        the exogenous signal each effect of ``exo`` (effect name -> signal name,
        :func:`avll.effects.exo_needs`) reads). ``weights=None``: the default of the loop
        (:func:`avll.defaults.objective_weights`)."""
        wa, wv, wx = objective_weights(weights, closed_loop)
        init = check_choice(init, "init", INITS)
        need = ["lead_x", "lead_v", "v", "x"] if closed_loop else ["command"]
        need += [c for c, w in (("v", wv), ("x", wx)) if w > 0 and c not in need]
        for c in need:
            self._require(c)
        free = [upper_index(u) for u in upper_free]
        if closed_loop and len(set(free)) < 4:
            for i in self._handle.index:
                if not self._has_upper[i]:
                    raise ValueError(f"run {self._all_runs[i].run_id!r}: closed loop needs its "
                                     "upper-level law")  # fmt: skip
        for n, sig in (exo or {}).items():
            if sig not in self.exo_names:
                bad = next(r for r in self._all_runs if sig not in r.exo)
                raise ValueError(f"run {bad.run_id!r}: effect {n!r} needs the column 'exo_{sig}'")
        return dict(runs=self._handle, upper_free=free, command_kind=self.command_kind,
                    weights=(wa, wv, wx), init=init, closed_loop=bool(closed_loop))  # fmt: skip

    def _require(self, column: str) -> None:
        if column in self._cols:
            return
        missing = [r for r in self._all_runs if getattr(r, column) is None]
        if len(missing) == len(self._all_runs):
            raise ValueError(f"runs: column {column!r} is needed here but no run has it")
        raise ValueError(f"run {missing[0].run_id!r}: column {column!r} is missing")

    def __repr__(self) -> str:
        return f"avll.RunSet({len(self)} runs, {self.total} samples)"


def positions(run_ids: Sequence[str], subset: Iterable[Any], name: str) -> list[int]:
    """Positions in ``run_ids`` of ``subset`` (positions or run ids; repeats allowed),
    a ValueError naming ``name`` for an unknown run or an empty subset."""
    ids = {rid: i for i, rid in enumerate(run_ids)}
    out = []
    for s in subset:
        if isinstance(s, (int, np.integer)) and not isinstance(s, bool):
            if not 0 <= int(s) < len(run_ids):
                raise ValueError(f"{name}: run index {s} is out of range 0..{len(run_ids) - 1}")
            out.append(int(s))
        elif str(s) in ids:
            out.append(ids[str(s)])
        else:
            raise ValueError(f"{name}: unknown run {s!r}")
    if not out:
        raise ValueError(f"{name}: is empty")
    return out


def as_runset(runs: RunSet | Iterable[Run]) -> RunSet:
    """``runs`` itself if it is a :class:`RunSet`, else the runs packed once."""
    return runs if isinstance(runs, RunSet) else RunSet(runs)
