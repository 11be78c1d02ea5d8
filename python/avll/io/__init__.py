"""Loaders of measured data into :class:`avll.Run` objects (minimal; the lead's
canonical reader/writer and ``read_runs`` dispatch land on main)."""

from .carma import carma_report, load_carma
from .formats import LOADERS, load_format
from .generic import load_generic
from .openacc import load_openacc_astazero
from .resample import resample_arrays, resample_run

__all__ = [
    "LOADERS",
    "load_format",
    "load_carma",
    "carma_report",
    "load_generic",
    "load_openacc_astazero",
    "resample_arrays",
    "resample_run",
]
