"""Exceptions raised by `czmpc`."""

from __future__ import annotations


class CzmpcError(Exception):
    """Base class of every error `czmpc` raises on purpose."""


class SettingsError(CzmpcError, ValueError):
    """Controller settings that are out of range or inconsistent."""


class DesignError(CzmpcError, ValueError):
    """A model and settings from which no sound controller can be built.

    For example an augmented pair that is not detectable, or an allowed input range
    that leaves the monotone branch of the input nonlinearity.
    """


__all__ = ["CzmpcError", "DesignError", "SettingsError"]
