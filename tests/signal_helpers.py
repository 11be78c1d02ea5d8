"""Ctrl-C in tests, whatever the test runner inherited.

A runner started with SIGINT ignored (``nohup pytest ... &``, a CI job without a
terminal) passes the ignored disposition on to everything it starts, and Python only
installs its ``KeyboardInterrupt`` handler when SIGINT is not ignored at start-up.
Tests that send SIGINT therefore install the handler themselves: in-process with the
``sigint_handler`` fixture (conftest), in a child process with ``SIGINT_DEFAULT``.
"""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest


def _restore_default_sigint() -> None:  # runs in the child, before exec
    signal.signal(signal.SIGINT, signal.SIG_DFL)


#: ``subprocess.Popen(..., **SIGINT_DEFAULT)``: the child starts with the default
#: SIGINT disposition, so Python installs its KeyboardInterrupt handler there.
SIGINT_DEFAULT: dict[str, Any] = {"preexec_fn": _restore_default_sigint}


def interrupt_once_staged(p: subprocess.Popen[str], out: Path, timeout: float = 120.0,
                          sig: int = signal.SIGINT) -> None:
    """Sends ``sig`` (SIGINT by default) to ``p``, an ``avll reproduce --out out``
    child, once the run has written its first figure into its staging folder (the
    stability maps, the diagnosis and the report are still to come). Not after a
    fixed delay: that lands after the end of the run on a fast enough machine, when
    the run is complete and the interpreter only shutting down (the process then ends
    by the signal). Skips the test if the run finishes first; fails it if nothing is
    staged in ``timeout``."""
    from avll import _atomic

    deadline = time.monotonic() + timeout
    while not any(out.glob(f"{_atomic.STAGING_PREFIX}*/fig3_*.png")):
        if p.poll() is not None or time.monotonic() > deadline:  # pragma: no cover
            p.kill()
            _, err = p.communicate()
            pytest.fail(f"no figure staged before the run ended or in {timeout:g} s: "
                        f"{err[-500:]}")
        time.sleep(0.01)
    if p.poll() is not None:  # pragma: no cover - a very fast machine
        p.communicate()  # close the pipes (an unclosed pipe warns, i.e. fails, later)
        pytest.skip("finished before the signal")
    p.send_signal(sig)
