"""Shared fixtures. ``shared_data`` is ``../shared/data`` beside the repository;
tests that need it skip with a clear reason when it is absent (a user's machine)."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"field data folder {SHARED_DATA} is absent (only on the project's machines)")
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
