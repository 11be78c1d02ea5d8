"""The non-canonical formats, for ``avll.io.read_runs(path, format=...)``.

``LOADERS`` maps a format name to its loader; :func:`load_format` calls it and, when
``dt`` is given, resamples every run to that step (splitting at gaps longer than
``max_gap``; see :mod:`avll.io.resample`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..data import Run
from .carma import load_carma
from .generic import load_generic
from .openacc import load_openacc_astazero
from .resample import resample_run

__all__ = ["LOADERS", "load_format"]

#: format name -> loader(path, command_kind=..., **options) -> list[Run]
LOADERS: dict[str, Callable[..., list[Run]]] = {
    "carma": load_carma,
    "openacc-astazero": load_openacc_astazero,
    "generic": load_generic,
}


def load_format(path: str | Path, format: str, *, command_kind: str | None = None,
                dt: float | None = None, max_gap: float | None = None,
                **kw: Any) -> list[Run]:
    """Load ``path`` with the loader of ``format`` (``carma``, ``openacc-astazero``,
    ``generic``); ``dt`` resamples the runs (the generic loader resamples itself, so
    it can also fix non-uniform input)."""
    try:
        loader = LOADERS[format]
    except KeyError:
        raise ValueError(f"format: unknown {format!r}; one of "
                         f"{', '.join(['canonical', *LOADERS])}") from None
    if format == "generic":
        return loader(path, command_kind=command_kind, dt=dt, max_gap=max_gap, **kw)
    runs = loader(path, command_kind=command_kind, **kw)
    if dt is None:
        return runs
    out: list[Run] = []
    for r in runs:
        out += resample_run(r, dt, max_gap=max_gap)
    return out
