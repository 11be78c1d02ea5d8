"""Kept for :mod:`avll.diagnose`, whose ``avll diagnose`` registration still imports
the AstaZero options from here: the options now live in :mod:`avll.cli._common` and
``avll load`` in :mod:`avll.cli.load`. Import them from :mod:`avll.cli._common`."""

from __future__ import annotations

from ..cli._common import add_astazero_options, astazero_options

__all__ = ["add_astazero_options", "astazero_options"]
