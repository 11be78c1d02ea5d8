"""A moved name kept working: ``__getattr__ = moved(__name__, {"old": "package.module:new"})``;
using an old name emits a ``DeprecationWarning`` naming the new place and returns the
new object. Its last user is ``avll.studies.openacc.register_cli``; with that shim gone
this module goes too."""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["moved"]


def moved(module: str, names: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` resolving the moved ``names`` (``old -> "mod:attr"``)
    with a ``DeprecationWarning``; other names raise ``AttributeError``."""
    table = dict(names)

    def __getattr__(name: str) -> Any:
        target = table.get(name)
        if target is None:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        mod, attr = target.split(":")
        warnings.warn(f"{module}.{name} is deprecated; use {mod}.{attr}",
                      DeprecationWarning, stacklevel=2)
        return getattr(importlib.import_module(mod), attr)

    return __getattr__
