"""Lazy import of ``asyncua`` with a message naming the extra when it is missing."""

from __future__ import annotations

from types import ModuleType

from czmpc.errors import CzmpcError


class MissingExtraError(CzmpcError, ImportError):
    """An optional dependency is not installed."""


def asyncua() -> ModuleType:
    """Return the ``asyncua`` module, or raise `MissingExtraError` naming ``czmpc[opcua]``."""
    try:
        import asyncua as module
    except ImportError as exc:
        raise MissingExtraError(
            "the OPC UA link needs the package asyncua: pip install 'czmpc[opcua]'"
        ) from exc
    return module
