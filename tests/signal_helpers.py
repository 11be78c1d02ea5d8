"""Ctrl-C in tests, whatever the test runner inherited.

A runner started with SIGINT ignored (``nohup pytest ... &``, a CI job without a
terminal) passes the ignored disposition on to everything it starts, and Python only
installs its ``KeyboardInterrupt`` handler when SIGINT is not ignored at start-up.
Tests that send SIGINT therefore install the handler themselves: in-process with the
``sigint_handler`` fixture (conftest), in a child process with ``SIGINT_DEFAULT``.
"""

from __future__ import annotations

import signal
from typing import Any


def _restore_default_sigint() -> None:  # runs in the child, before exec
    signal.signal(signal.SIGINT, signal.SIG_DFL)


#: ``subprocess.Popen(..., **SIGINT_DEFAULT)``: the child starts with the default
#: SIGINT disposition, so Python installs its KeyboardInterrupt handler there.
SIGINT_DEFAULT: dict[str, Any] = {"preexec_fn": _restore_default_sigint}
