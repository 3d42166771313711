"""Lazy public names for a package's ``__init__`` (PEP 562), shared by sysid, sim and czmpc.

A package lists ``name -> defining module``; the module is imported on first access.
This keeps ``czmpc --help`` fast (scipy.signal alone takes 0.5 s to import) and lets
the CLI pin BLAS threads before numpy is first imported.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(
    package: str, exports: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Return ``(__getattr__, __dir__)`` for a package whose public names load lazily.

    Parameters
    ----------
    package :
        The package's ``__name__``.
    exports :
        Public name -> fully qualified module that defines it.
    """

    def get_attribute(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def list_names() -> list[str]:
        return sorted(set(exports) | set(vars(sys.modules[package])))

    return get_attribute, list_names


__all__ = ["lazy_exports"]
