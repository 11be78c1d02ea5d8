"""Reading and writing runs.

``read_runs(path, format=...)`` dispatches on the format name; every loader returns
a list of :class:`avll.Run` and raises :class:`avll.DataError` (a ``ValueError``)
naming the file, the column and the row of any bad input. Input files are never
modified.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..data import DataError, Run
from .canonical import load_canonical, write_runs

__all__ = ["read_runs", "write_runs", "load_canonical", "FORMATS"]

#: Loader by format name: ``loader(path, command_kind=..., **options) -> list[Run]``.
FORMATS: dict[str, Callable[..., list[Run]]] = {
    "canonical": load_canonical,
}


def read_runs(
    path: str | Path, command_kind: str | None = None, format: str = "canonical", **options: Any
) -> list[Run]:
    """Reads the runs in ``path`` with the loader of ``format``.

    ``command_kind`` (``"acceleration"`` or ``"speed"``) overrides what the file or
    its sidecar says; loaders whose format fixes the kind check it instead.
    """
    try:
        loader = FORMATS[format]
    except KeyError:
        raise ValueError(
            f"format: unknown format {format!r}; known: {', '.join(sorted(FORMATS))}"
        ) from None
    p = Path(path)
    if not p.exists():
        raise DataError(f"{p}: no such file or folder")
    return loader(p, command_kind=command_kind, **options)
