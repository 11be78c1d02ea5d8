"""Shared fixtures. ``shared_data`` is ``../shared/data`` beside the repository;
tests that need it skip when it is absent, with the one reason
(``loader_helpers.NO_DATA``) that says how to get it (``avll data fetch``)."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path

import pytest
from loader_helpers import NO_DATA

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(NO_DATA)
    return SHARED_DATA


@pytest.fixture
def sigint_handler() -> Iterator[None]:
    """Python's KeyboardInterrupt handler for SIGINT during the test, whatever the
    runner inherited (SIGINT is ignored under ``nohup ... &``); restored afterwards."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
