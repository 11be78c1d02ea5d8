"""Progress of long work: one display per stage, used by every long stage of avll.

A :class:`Progress` is one stage (a GA over generations, a stability map over grid
points, a reproduction over its stages). Its display depends on ``mode``:

``"bar"``
    a tqdm bar on stderr;
``"log"``
    plain lines on stderr (``avll: <stage>: 40% (120/300 gen), 3.1 s``): one when the
    stage starts, at most one every :data:`LOG_INTERVAL` seconds while it runs, and
    one when it ends -- no escape codes, so a log file stays readable;
``"auto"``
    ``"bar"`` when stderr is a terminal, ``"log"`` otherwise;
``"none"``
    nothing.

``True`` means ``"auto"`` and ``False``/``None`` ``"none"``. The count never runs past
the total (an update beyond it is clamped), and :meth:`Progress.close` with
``complete=True`` (the stage finished, e.g. the GA converged before its generation
budget) moves the display to 100 % before closing, so a finished stage never looks
aborted. An interrupted stage closes where it stopped.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

from . import _sigint

__all__ = ["MODES", "LOG_INTERVAL", "Progress", "resolve_mode", "messages"]

#: The display modes (see the module doc).
MODES: tuple[str, ...] = ("auto", "bar", "log", "none")

#: Seconds between two log lines of one stage (log mode).
LOG_INTERVAL: float = 10.0


def resolve_mode(progress: Any, file: TextIO | None = None) -> str:
    """The display of ``progress`` (``True``/``False``/``None`` or one of
    :data:`MODES`) on ``file`` (default stderr): ``"bar"``, ``"log"`` or ``"none"``."""
    if progress is None or progress is False:
        return "none"
    if progress is True:
        progress = "auto"
    if not isinstance(progress, str) or progress not in MODES:
        raise ValueError(f"progress: expected True, False or one of {', '.join(MODES)}, "
                         f"got {progress!r}")
    if progress != "auto":
        return progress
    f = sys.stderr if file is None else file
    try:
        tty = bool(f.isatty())
    except (AttributeError, ValueError):
        tty = False
    return "bar" if tty else "log"


def messages(prefix: str, progress: Any, file: TextIO | None = None) -> Callable[[str], None]:
    """A function printing a stage's messages for a progress mode: ``"<prefix>: msg"``
    lines on ``file`` (default stderr), written above any bar in ``bar`` mode,
    nothing in ``none`` mode (``-q``)."""
    mode = resolve_mode(progress, file)
    if mode == "none":
        return lambda msg: None
    return lambda msg: _emit(f"{prefix}: {msg}", mode == "bar", file)


def _emit(line: str, bar: bool, file: TextIO | None) -> None:
    out = sys.stderr if file is None else file
    if bar:
        from tqdm.auto import tqdm

        tqdm.write(line, file=out)
    else:
        print(line, file=out, flush=True)


class Progress:
    """One stage's progress (see the module doc): ``update``/``advance_to`` while the
    work runs, ``close(complete=...)`` at the end (or use it as a context manager,
    which closes complete unless an exception left the block)."""

    def __init__(self, total: float, desc: str, *, unit: str = "it", mode: Any = "auto",
                 file: TextIO | None = None, interval: float | None = None,
                 unit_scale: bool = False) -> None:
        _sigint.check()
        self.total = max(float(total), 0.0)
        self.desc = desc
        self.unit = unit
        self.file = file
        self.mode = resolve_mode(mode, file)
        self.n = 0.0
        self.postfix = ""
        self.closed = False
        self.lines = 0
        self._interval = LOG_INTERVAL if interval is None else float(interval)
        self._t0 = time.perf_counter()
        self._last = self._t0
        self._bar: Any = None
        if self.mode == "bar":
            from tqdm.auto import tqdm

            self._bar = tqdm(total=_num(self.total), desc=desc, unit=unit, leave=True,
                             file=self._out(), unit_scale=unit_scale)
        elif self.mode == "log":
            self._log("started")

    def _out(self) -> TextIO:
        return sys.stderr if self.file is None else self.file

    def _log(self, state: str) -> None:
        n, tot = self.n, self.total
        pct = f"{100.0 * n / tot:.0f}%" if tot > 0 else "-"
        el = time.perf_counter() - self._t0
        extra = f", {self.postfix}" if self.postfix else ""
        print(f"avll: {self.desc}: {state} {pct} ({_count(n)}/{_count(tot)} {self.unit}), "
              f"{el:.1f} s{extra}", file=self._out(), flush=True)
        self.lines += 1
        self._last = time.perf_counter()

    def advance_to(self, n: float) -> None:
        """Sets the count to ``n`` (clamped to ``[current, total]``: never backwards,
        never past the total)."""
        _sigint.check()
        if self.closed:
            return
        n = min(max(float(n), self.n), self.total)
        step = n - self.n
        self.n = n
        if self._bar is not None:
            if step > 0:
                self._bar.update(_num(step))
        elif (self.mode == "log" and step > 0 and n < self.total
              and time.perf_counter() - self._last >= self._interval):
            self._log("running")

    def update(self, step: float = 1) -> None:
        """Adds ``step`` to the count (clamped to the total)."""
        self.advance_to(self.n + float(step))

    def set_total(self, total: float) -> None:
        """Changes the total (e.g. once the number of stages is known); the count is
        clamped to it."""
        self.total = max(float(total), 0.0)
        self.n = min(self.n, self.total)
        if self._bar is not None:
            self._bar.total = _num(self.total)
            self._bar.refresh()

    def set_postfix(self, text: str) -> None:
        """A short status shown beside the count (e.g. the best cost so far)."""
        _sigint.check()
        self.postfix = text
        if self._bar is not None:
            self._bar.set_postfix_str(text, refresh=False)

    def set_description(self, desc: str) -> None:
        """Renames the stage (e.g. the current sub-step of a reproduction)."""
        _sigint.check()
        self.desc = desc
        if self._bar is not None:
            self._bar.set_description(desc)

    def write(self, msg: str) -> None:
        """Prints a message line without breaking the bar (nothing in ``none`` mode)."""
        if self.mode != "none":
            _emit(msg, self._bar is not None, self.file)

    def close(self, complete: bool = True) -> None:
        """Ends the stage: ``complete=True`` moves the count to the total first (the
        work is done, e.g. converged early); ``False`` leaves it where it stopped."""
        if self.closed:
            return
        if complete:
            self.advance_to(self.total)
        self.closed = True
        if self._bar is not None:
            self._bar.refresh()
            self._bar.close()
        elif self.mode == "log":
            self._log("done" if complete else "stopped at")

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        self.close(complete=exc_type is None)


def _num(x: float) -> float | int:
    """``x`` as an ``int`` when whole (tqdm shows ``7``, not ``7.0``)."""
    return int(x) if x.is_integer() else x


def _count(x: float) -> str:
    """A count as an integer (never ``7.3084e+06``), a fractional one to 4 digits."""
    v = float(x)
    return str(int(v)) if v.is_integer() else f"{v:.4g}"
