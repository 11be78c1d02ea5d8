"""The hand-written stubs of the extension match the runtime (mypy.stubtest)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


def test_core_stubs_match_runtime() -> None:
    pytest.importorskip("mypy")
    allow = Path(__file__).with_name("stubtest_allowlist.txt")
    res = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "avll._core", "--allowlist", str(allow)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stdout + res.stderr


def test_package_is_typed() -> None:
    import avll

    assert (Path(avll.__file__).parent / "py.typed").exists()
    assert (Path(avll.__file__).parent / "_core.pyi").exists()
