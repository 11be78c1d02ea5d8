"""Deprecated location: the field-data studies are :mod:`avll.studies.fielddata`
(the old names keep working here with a ``DeprecationWarning``)."""

from __future__ import annotations

from ._compat import moved as _moved

__all__: list[str] = []

__getattr__ = _moved(__name__, {n: f"avll.studies.fielddata:{n}" for n in (
    "Study",
    "HANDOVER_SPEED",
    "CARMA_OBJECTIVES",
    "ASTAZERO_OBJECTIVES",
    "CARMA_CAL_FILES",
    "CARMA_BOUNDS",
    "read_carma",
    "split_launch_cruise",
    "read_astazero_pairs",
    "carma_study",
    "astazero_study",
)})
