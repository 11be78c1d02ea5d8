"""Old names kept working: a module whose names moved defines
``__getattr__ = moved(__name__, {"old": "package.module:new"})``; using an old name
emits a ``DeprecationWarning`` naming the new place and returns the new object."""

from __future__ import annotations

import functools
import importlib
import warnings
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

_F = TypeVar("_F", bound=Callable[..., Any])

__all__ = ["moved", "renamed_kwargs"]


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


def renamed_kwargs(**old_to_new: str) -> Callable[[_F], _F]:
    """Decorator: keyword arguments renamed to one name per idea keep working under
    their old names (``old=new``), with a ``DeprecationWarning``; giving both is a
    ``TypeError``."""

    def wrap(fn: _F) -> _F:
        @functools.wraps(fn)
        def inner(*args: Any, **kwargs: Any) -> Any:
            for old, new in old_to_new.items():
                if old in kwargs:
                    if new in kwargs:
                        raise TypeError(f"{fn.__name__}: give {new!r} only ({old!r} is its "
                                        "deprecated name)")
                    warnings.warn(f"{fn.__name__}: {old!r} is deprecated; use {new!r}",
                                  DeprecationWarning, stacklevel=2)
                    kwargs[new] = kwargs.pop(old)
            return fn(*args, **kwargs)

        return inner  # type: ignore[return-value]

    return wrap
