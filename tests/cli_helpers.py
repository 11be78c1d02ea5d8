"""Helpers of the CLI tests."""

from __future__ import annotations

import pytest


def err_line(capsys: pytest.CaptureFixture[str], *words: str) -> str:
    """The command's stderr, checked to be one line without a traceback that holds
    every one of ``words``."""
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    return err
