"""Lazy public names for a package's ``__init__`` (PEP 562), shared by sysid, sim and czmpc.

A package lists ``name -> defining module``; the module is imported on first access.
This keeps ``czmpc --help`` fast (scipy.signal alone takes 0.5 s to import) and lets
the CLI pin BLAS threads before numpy is first imported.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from types import ModuleType
from typing import Any

_EXPORTS: dict[str, Mapping[str, str]] = {}


class _LazyPackage(ModuleType):
    """A package whose public names win over its submodules of the same name.

    Importing ``sysid.simulate`` (the module) binds it to the attribute ``simulate`` of
    ``sysid``, which would hide the public function ``sysid.simulate`` whenever another
    module imported the submodule first. The binding is refused for such names.
    """

    def __setattr__(self, name: str, value: Any) -> None:
        if (isinstance(value, ModuleType) and value.__name__ == f"{self.__name__}.{name}"
                and name in _EXPORTS.get(self.__name__, {})):
            return
        super().__setattr__(name, value)


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

    _EXPORTS[package] = exports
    sys.modules[package].__class__ = _LazyPackage

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
