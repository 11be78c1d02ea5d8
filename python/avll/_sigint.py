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

The command treats SIGTERM (``timeout``, schedulers, ``docker stop``) as a Ctrl-C
(:func:`term_handler`): the staged outputs are removed, the old ones stay, and it exits
with 143 instead of 130.

The library installs nothing by itself: in a notebook or a script Python's own handler
(or the user's) stays in place and :func:`check` never raises.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

_pending = False
_term = False


def handler(signum: int, frame: FrameType | None) -> None:
    """SIGINT handler: latches the signal, then raises ``KeyboardInterrupt`` as
    Python's default handler does."""
    global _pending
    _pending = True
    raise KeyboardInterrupt


def term_handler(signum: int, frame: FrameType | None) -> None:
    """The ``avll`` command's SIGTERM handler: records it (:func:`terminated`), then
    acts as :func:`handler`."""
    global _term
    _term = True
    handler(signum, frame)


def terminated() -> bool:
    """Whether the ``avll`` command received SIGTERM while it ran."""
    return _term


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
    afterwards. Under the ``avll`` command's own handler (:func:`command_starts`) it
    does neither: a Ctrl-C latched in the block stays latched, so the command still
    knows it was interrupted when another error carries the interrupt out."""
    installed = (threading.current_thread() is threading.main_thread()
                 and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
    if installed:
        signal.signal(signal.SIGINT, handler)
        clear()
    try:
        yield
    finally:
        if installed:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            clear()


# -- the ``avll`` command's start and end --------------------------------------------

#: Set when the ``avll`` command's process installed :func:`quiet_exit` at start-up.
console = False


def quiet_exit(signum: int, frame: FrameType | None) -> None:
    """SIGINT handler of the ``avll`` command's first and last moments (importing the
    package; after the outputs are committed), when nothing is half written: flushes
    stdout, prints one line and exits with 130 at once, without a traceback."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # a closed pipe: nothing left to say there
            stream.flush()
    with contextlib.suppress(OSError):
        os.write(2, b"avll: interrupted\n")
    os._exit(130)


def _is_console(argv: list[str], orig: list[str]) -> bool:
    """Whether this process is the ``avll`` command (console script or ``python -m``)."""
    if argv and os.path.basename(argv[0]).removesuffix(".exe") == "avll":
        return True
    pairs = zip(orig[:-1], orig[1:], strict=True)
    return any(a == "-m" and b in ("avll", "avll.cli") for a, b in pairs)


def at_startup() -> None:
    """Called first by ``import avll``: in the ``avll`` command's process (and only
    there) a Ctrl-C while the package imports ends the command with one line and exit
    code 130 (:func:`quiet_exit`) instead of a traceback; :func:`avll.cli.main` puts
    Python's handler back as soon as it runs."""
    global console
    if console or threading.current_thread() is not threading.main_thread():
        return
    if not _is_console(list(sys.argv), list(getattr(sys, "orig_argv", []))):
        return
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, quiet_exit)
        console = True


_previous_hook: Callable[[Any], object] | None = None


def _quiet_unraisable(u: Any) -> None:
    """``sys.unraisablehook`` while the command runs: a ``KeyboardInterrupt`` Python
    could not raise (in a weakref callback or a ``__del__``) is latched and delivered by
    :func:`check`, not printed as "Exception ignored"; anything else goes to the hook it
    replaced."""
    if u.exc_type is KeyboardInterrupt and _pending:
        return
    (_previous_hook or sys.__unraisablehook__)(u)


def command_starts() -> None:
    """The command runs: a Ctrl-C raises ``KeyboardInterrupt`` through :func:`handler`,
    which latches it, so a library that turns it into another error still leaves
    :func:`interrupted` true (the command reports the interruption, not that error); one
    Python had to ignore is not printed (:func:`_quiet_unraisable`)."""
    global _previous_hook
    if console and signal.getsignal(signal.SIGINT) is quiet_exit:
        clear()
        signal.signal(signal.SIGINT, handler)
        if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
            signal.signal(signal.SIGTERM, term_handler)
        if sys.unraisablehook is not _quiet_unraisable:
            _previous_hook = sys.unraisablehook
            sys.unraisablehook = _quiet_unraisable


def _restore_unraisable() -> None:
    global _previous_hook
    if sys.unraisablehook is _quiet_unraisable and _previous_hook is not None:
        sys.unraisablehook = _previous_hook
    _previous_hook = None


def interrupted() -> bool:
    """Whether a Ctrl-C was latched by :func:`handler` and not cleared since."""
    return _pending


def command_ends() -> None:
    """The command is done (outputs committed or removed): a Ctrl-C is now
    :func:`quiet_exit` (one line, exit 130), and ignored once the interpreter shuts down
    (``atexit``): CPython then restores the default action of a signal with a Python
    handler (not of an ignored one), which would end the process by the signal."""
    if console and threading.current_thread() is threading.main_thread():
        import atexit

        signal.signal(signal.SIGINT, quiet_exit)  # never raises: nothing left to latch
        if signal.getsignal(signal.SIGTERM) is term_handler:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
        _restore_unraisable()
        atexit.register(signal.signal, signal.SIGINT, signal.SIG_IGN)
