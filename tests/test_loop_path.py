"""The path the effect loop's runs take into the Rust core, measured.

The measurement (:class:`PathTracer`, ``sys.setprofile``): a Python frame of an avll
module is *on the data path* when the runs are handed to it: one of its arguments is a
run, a run set, a list of runs or an object holding a run set (a method's ``self`` does
not count: the data's own methods, ``Run.__len__`` or ``RunSet.cost_kw``, are the data
answering, not a module it passes through). From the moment control is in
:func:`avll.diagnose.effect_loop`'s own frame, the modules of the on-path frames that
are entered (a call) or re-entered (a return to an on-path frame) are recorded in
order, up to a call of a Rust function that consumes the runs (``_core.calibrate``,
``_core.batch_cost``, ``_core.simulate_batch``). That sequence is the path of one
Rust call: a *stay* is a maximal stretch of consecutive entries in one module, a
*return* a stay in a module that already had one earlier on the same path. The loop's
own stay is the first. A plain :func:`avll.calibrate` on a run set is one stay in
``avll.calibration``; on a list of runs, five (the packing in ``avll.runs`` checks the
runs in ``avll.data``), two of them returns.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from types import FrameType
from typing import Any

from avll import FirstOrderLag, _core
from avll.data import Run
from avll.runs import RunSet
from avll.synth_effects import paper_experiment_effects

FIRST = FirstOrderLag(Td=0.6)
#: The Rust functions that take the runs (the packed run set's columns).
CONSUMERS = frozenset({"calibrate", "batch_cost", "simulate_batch"})


def _is_data(v: Any) -> bool:
    if isinstance(v, (Run, RunSet)):
        return True
    if isinstance(v, (list, tuple)) and v and isinstance(v[0], (Run, RunSet)):
        return True
    attrs = getattr(v, "__dict__", None)
    return isinstance(attrs, dict) and any(isinstance(x, RunSet) for x in attrs.values())


@dataclass(frozen=True)
class Path:
    """One Rust call's path: the Rust function and the modules of its stays."""

    rust: str
    stays: tuple[str, ...]

    @property
    def returns(self) -> int:
        return sum(m in self.stays[:i] for i, m in enumerate(self.stays))


class PathTracer:
    """Records the path of every Rust call under ``top`` (see the module doc)."""

    def __init__(self, top: tuple[str, str] = ("avll.diagnose.loop", "effect_loop")) -> None:
        self.top = top
        self.on_path: dict[int, str] = {}  # id(frame) -> module, for on-path frames
        self.seq: list[str] = []
        self.fresh = True  # a Rust call returned: the next path starts from the stack
        self.paths: list[Path] = []

    def _stack(self, frame: FrameType | None) -> list[str] | None:
        """The modules of the on-path frames from the top frame down to ``frame``."""
        out: list[str] = []
        while frame is not None:
            m = self.on_path.get(id(frame))
            if m is not None:
                out.append(m)
                if (m, frame.f_code.co_name) == self.top:
                    return [m for i, m in enumerate(out[::-1]) if i == 0 or out[::-1][i - 1] != m]
            frame = frame.f_back
        return None

    def _enter(self, module: str) -> None:
        if self.seq and self.seq[-1] != module:
            self.seq.append(module)

    def __call__(self, frame: FrameType, event: str, arg: Any) -> None:
        if event == "call":
            module = frame.f_globals.get("__name__", "")
            if not module.startswith("avll."):
                return
            code = frame.f_code
            n = code.co_argcount + code.co_kwonlyargcount
            loc = frame.f_locals
            names = code.co_varnames[:n]
            if names and names[0] in ("self", "cls"):
                names = names[1:]  # the data's own methods: not another module
            if not any(_is_data(loc.get(name)) for name in names):
                return
            self.on_path[id(frame)] = module
            if (module, code.co_name) == self.top:
                self.seq, self.fresh = [module], False
            elif self.fresh:
                stack = self._stack(frame.f_back)
                if stack is not None:
                    self.seq, self.fresh = stack, False
            self._enter(module)
        elif event == "return":
            was = self.on_path.pop(id(frame), None)
            back_frame = frame.f_back
            back = None if back_frame is None else self.on_path.get(id(back_frame))
            if back is None:
                return
            assert back_frame is not None
            if (back, back_frame.f_code.co_name) == self.top:
                self.seq, self.fresh = [back], False  # back at the top: a new path
            elif was is not None and not self.fresh:
                self._enter(back)
        elif event == "c_call":
            name = getattr(arg, "__name__", "")
            if name in CONSUMERS and getattr(arg, "__self__", None) is _core and not self.fresh:
                self.paths.append(Path(name, tuple(self.seq)))
                self.fresh = True


@contextmanager
def traced() -> Iterator[PathTracer]:
    tracer = PathTracer()
    old = sys.getprofile()
    sys.setprofile(tracer)
    try:
        yield tracer
    finally:
        sys.setprofile(old)


def test_the_tracer_measures_a_plain_calibrate() -> None:
    """Its baseline: ``avll.calibrate`` on a list of runs."""
    runs = paper_experiment_effects(FIRST, {}, seed=0, runs=(1, 3))
    import avll

    tracer = PathTracer(top=("avll.calibration", "calibrate"))
    old = sys.getprofile()
    sys.setprofile(tracer)
    try:
        avll.calibrate("first", runs, max_generations=2, starts=1)
    finally:
        sys.setprofile(old)
    (path,) = tracer.paths
    assert path.rust == "calibrate"
    # packing the list: the run set (avll.runs) checks the runs (avll.data)
    assert path.stays == ("avll.calibration", "avll.runs", "avll.data", "avll.runs",
                          "avll.calibration")
    assert path.returns == 2


def test_the_effect_loop_reaches_rust_in_few_stays_and_returns() -> None:
    """Every Rust call of the loop on its runs crosses at most 10 module stays with at
    most 5 returns (the loop called the calibration through four wrappers before: 26
    stays in 7 modules, 19 returns)."""
    runs = paper_experiment_effects(FIRST, {"delay": None}, seed=0, runs=(1, 3, 8, 12))
    from avll.diagnose import effect_loop

    with traced() as tracer:
        res = effect_loop("first", runs[:2], runs[2:3], test_runs=runs[3:], seed=1,
                          max_effects=1, tries=1, max_generations=8, starts=1,
                          n_boot=50)  # fmt: skip
    assert res.trials
    kinds = {p.rust for p in tracer.paths}
    assert {"calibrate", "batch_cost", "simulate_batch"} <= kinds, kinds
    worst = max(tracer.paths, key=lambda p: (len(p.stays), p.returns))
    most = max(tracer.paths, key=lambda p: (p.returns, len(p.stays)))
    assert len(worst.stays) <= 10, worst
    assert most.returns <= 5, most
    # the calibrations take the one entry, avll.calibrate, straight from the loop
    for p in tracer.paths:
        if p.rust == "calibrate":
            assert p.stays[:2] == ("avll.diagnose.loop", "avll.calibration"), p
