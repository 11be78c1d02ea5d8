"""A Ctrl-C that cannot get lost in a long command.

Python raises ``KeyboardInterrupt`` wherever the main thread happens to be when the
signal is handled; when that is a weakref callback or a ``__del__`` (the garbage
collector runs them at arbitrary points), the exception is printed as "ignored" and
the work goes on, so a Ctrl-C pressed at that moment is lost. The ``avll`` command
installs :func:`handler`, which also latches the signal; every progress update
(:mod:`avll.progress`) calls :func:`check`, which raises ``KeyboardInterrupt`` again
while the latch is set. A calibration that returns its best point after a Ctrl-C
(``interrupted=True``) has delivered the interrupt and clears the latch
(:func:`clear`), so the command can still write that result.

The library installs nothing by itself: in a notebook or a script Python's own handler
(or the user's) stays in place and :func:`check` never raises.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

_pending = False


def handler(signum: int, frame: FrameType | None) -> None:
    """SIGINT handler: latches the signal, then raises ``KeyboardInterrupt`` as
    Python's default handler does."""
    global _pending
    _pending = True
    raise KeyboardInterrupt


def check() -> None:
    """Raises ``KeyboardInterrupt`` if a Ctrl-C was latched and not yet delivered."""
    if _pending:
        raise KeyboardInterrupt


def clear() -> None:
    """Forgets a latched Ctrl-C (it was delivered and handled)."""
    global _pending
    _pending = False


@contextmanager
def latched() -> Iterator[None]:
    """Installs :func:`handler` for the block (main thread, and only in place of
    Python's default handler); restores the previous handler and clears the latch
    afterwards."""
    installed = False
    old: object = None
    if threading.current_thread() is threading.main_thread():
        old = signal.getsignal(signal.SIGINT)
        if old is signal.default_int_handler:
            signal.signal(signal.SIGINT, handler)
            installed = True
    clear()
    try:
        yield
    finally:
        if installed:
            signal.signal(signal.SIGINT, old)  # type: ignore[arg-type]
        clear()
