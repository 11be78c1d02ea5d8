"""Reading and writing runs.

``read_runs(path, format=...)`` dispatches on the format name; every loader returns
a list of :class:`avll.Run` and raises :class:`avll.DataError` (a ``ValueError``)
naming the file, the column and the row of any bad input. Input files are never
modified.

Formats: ``canonical`` (the library's own long CSV/Parquet), ``generic`` (any
CSV/Parquet with a column mapping), ``carma`` (FHWA CARMA platoon CSVs: engaged
stretches, speed command), ``openacc-astazero`` (JRC OpenACC AstaZero: platoon pairs
and free-flow segments, road grade), ``openacc`` (the OpenACC database's native
layout, any campaign file or folder as distributed: one closed-loop run per usable
stretch of each follower, with car model, ACC state, gap setting and its rank in
``meta``). The measured-data loaders accept ``dt=`` (and
``max_gap=``) to resample.
"""

from __future__ import annotations

import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..data import DataError, Run
from ._common import (
    check_regular_file,
    check_runs_for_delay,
    natural_key,
    stat_path,
    strict_warnings,
    summarize,
    with_strict,
)
from .canonical import load_canonical, write_runs
from .carma import carma_report
from .carma import load_carma as _load_carma
from .formats import LOADERS, load_format
from .generic import load_generic
from .openacc import load_openacc_astazero as _load_openacc_astazero
from .openacc_native import load_openacc_native as _load_openacc_native
from .openacc_native import openacc_native_report, read_openacc_native
from .resample import resample_arrays, resample_run

#: :func:`avll.io.carma.load_carma` with the ``strict=False`` option.
load_carma = with_strict(_load_carma)
#: :func:`avll.io.openacc.load_openacc_astazero` with the ``strict=False`` option.
load_openacc_astazero = with_strict(_load_openacc_astazero)
#: :func:`avll.io.openacc_native.load_openacc_native` with the ``strict=False`` option.
load_openacc_native = with_strict(_load_openacc_native)

__all__ = [
    "read_runs",
    "write_runs",
    "load_canonical",
    "FORMATS",
    "LOADERS",
    "load_format",
    "load_carma",
    "carma_report",
    "load_generic",
    "load_openacc_astazero",
    "load_openacc_native",
    "openacc_native_report",
    "read_openacc_native",
    "resample_arrays",
    "resample_run",
    "check_runs_for_delay",
    "summarize",
]

#: Loader by format name: ``loader(path, command_kind=..., **options) -> list[Run]``.
FORMATS: dict[str, Callable[..., list[Run]]] = {
    "canonical": load_canonical,
    **LOADERS,
}


def read_runs(
    path: str | Path, command_kind: str | None = None, format: str = "canonical", *,
    strict: bool = False, **options: Any
) -> list[Run]:
    """Reads the runs in ``path`` with the loader of ``format``.

    ``path`` is a file or, for the per-file formats (``canonical``, ``carma``,
    ``generic``), a folder: then every ``*.csv`` / ``*.parquet`` in it is read, in
    natural order of the names (data5, data6, data9, data10). ``openacc-astazero``
    reads its own folder layout; ``openacc`` every ``*.csv`` below a folder,
    recursively (options ``setting``, ``car``, ``track`` filter the followers).
    ``command_kind`` (``"acceleration"`` or ``"speed"``) overrides what the file or
    its sidecar says; loaders whose format fixes the kind check it instead.
    ``strict=True`` turns every :class:`avll.DataWarning` (implausible values,
    sidecar entries for runs not in the data) into a :class:`avll.DataError`.
    """
    with strict_warnings(strict):
        return _read_runs(path, command_kind, format, **options)


def _read_runs(path: str | Path, command_kind: str | None, format: str,
               **options: Any) -> list[Run]:
    try:
        loader = FORMATS[format]
    except KeyError:
        raise ValueError(
            f"format: unknown format {format!r}; known: {', '.join(sorted(FORMATS))}"
        ) from None
    p = Path(path)
    st = stat_path(p)  # FileNotFoundError for a missing path, DataError for a link loop
    if stat.S_ISDIR(st.st_mode) and format in _PER_FILE:
        files = sorted(
            (f for f in p.iterdir() if f.suffix.lower() in (".csv", ".parquet", ".pq")),
            key=natural_key,
        )
        if not files:
            raise DataError(f"{p}: no CSV or Parquet files in this folder")
        for f in files:  # all checked before any is read: a FIFO would block the read
            check_regular_file(f)
        runs: list[Run] = []
        for f in files:
            runs += loader(f, command_kind=command_kind, **options)
        return runs
    if not stat.S_ISDIR(st.st_mode):
        check_regular_file(p)  # every format: a FIFO or a device is never opened
    return loader(p, command_kind=command_kind, **options)


#: Formats whose loader reads one file; ``read_runs`` reads a folder of them.
_PER_FILE = ("canonical", "carma", "generic")
