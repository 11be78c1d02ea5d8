"""Every public function, class and method of the package has a docstring."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import avll


def test_every_public_callable_is_documented() -> None:
    missing = []
    names = ["avll"] + [
        "avll." + m.name for m in pkgutil.walk_packages(avll.__path__) if not m.name.startswith("_")
    ]
    for mod_name in names:
        mod = importlib.import_module(mod_name)
        for name, obj in vars(mod).items():
            if name.startswith("_") or getattr(obj, "__module__", None) != mod_name:
                continue
            if not (inspect.isfunction(obj) or inspect.isclass(obj)):
                continue
            if not (obj.__doc__ or "").strip():
                missing.append(f"{mod_name}.{name}")
            if inspect.isclass(obj):
                for attr, val in vars(obj).items():
                    if inspect.isfunction(val) and not attr.startswith("_"):
                        if not (val.__doc__ or "").strip():
                            missing.append(f"{mod_name}.{name}.{attr}")
    assert missing == []
