"""A package's names loaded from their modules on first use (PEP 562 ``__getattr__``).

A package that re-exports a heavy module's names with plain imports loads that module with the package: a
command that needs one light name pays for all of them (``drivecal fleet-report`` loaded JAX for the batch's
names). :func:`lazy_names` gives the package a module-level ``__getattr__`` and ``__dir__`` that import each
name's module when the name is first asked for. Base layer: the standard library only.
"""

from __future__ import annotations

import importlib
import sys
from typing import Callable


def lazy_names(package: str, modules: dict[str, tuple[str, ...]]) -> tuple[Callable[[str], object],
                                                                           Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package``, whose names ``modules`` lists by defining module.

    Args:
        package: the package's ``__name__``.
        modules: ``{module name in the package (e.g. "_batch"): the names it defines and the package offers}``.

    A name loaded once is set on the package, so the next access is an ordinary attribute. A name not listed is an
    ``AttributeError``, as for any module.
    """
    owner = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name: str) -> object:
        if name not in owner:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{owner[name]}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(owner))

    return __getattr__, __dir__
