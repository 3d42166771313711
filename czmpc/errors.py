"""Exceptions raised by `czmpc`."""

from __future__ import annotations


class CzmpcError(Exception):
    """Base class of every error `czmpc` raises on purpose."""


class SettingsError(CzmpcError, ValueError):
    """Controller settings that are out of range or inconsistent."""


class DesignError(CzmpcError, ValueError):
    """A model and settings from which no sound controller can be built (e.g. not detectable)."""


__all__ = ["CzmpcError", "DesignError", "SettingsError"]
