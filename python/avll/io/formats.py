"""The measured-data formats, registered in ``avll.io.FORMATS`` for
``avll.io.read_runs(path, format=...)``.

Every entry takes ``(path, command_kind=None, *, dt=None, max_gap=None, **options)``:
``dt`` resamples the runs to that step (linear interpolation across gaps of at most
``max_gap`` seconds, default ``2.5*dt``; longer gaps split a run; see
:mod:`avll.io.resample`). The generic loader resamples itself, so it can also fix
non-uniform input. Every entry also takes ``strict=False``: ``True`` turns the
plausibility and sidecar warnings (:class:`avll.DataWarning`) into errors.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..data import Run
from ._common import with_strict
from .carma import load_carma
from .generic import load_generic
from .openacc import load_openacc_astazero
from .openacc_native import load_openacc_native
from .resample import resample_run

__all__ = ["LOADERS", "load_format"]


def _resampling(loader: Callable[..., list[Run]]) -> Callable[..., list[Run]]:
    @functools.wraps(loader)
    def wrapped(path: str | Path, command_kind: str | None = None, *,
                dt: float | None = None, max_gap: float | None = None, **kw: Any) -> list[Run]:
        runs = loader(path, command_kind=command_kind, **kw)
        if dt is None:
            return runs
        return [s for r in runs for s in resample_run(r, dt, max_gap=max_gap)]

    return with_strict(wrapped)


#: format name -> loader(path, command_kind=None, *, dt=None, max_gap=None, **options)
LOADERS: dict[str, Callable[..., list[Run]]] = {
    "carma": _resampling(load_carma),
    "openacc-astazero": _resampling(load_openacc_astazero),
    "openacc": _resampling(load_openacc_native),
    "generic": load_generic,
}


def load_format(path: str | Path, format: str, *, command_kind: str | None = None,
                **kw: Any) -> list[Run]:
    """Load ``path`` with the loader of ``format`` (``carma``, ``openacc-astazero``,
    ``openacc``, ``generic``); see the module doc for ``dt`` and ``max_gap``."""
    try:
        loader = LOADERS[format]
    except KeyError:
        raise ValueError(f"format: unknown {format!r}; one of "
                         f"{', '.join(['canonical', *LOADERS])}") from None
    return loader(path, command_kind=command_kind, **kw)
