"""Exceptions raised by `sim`."""

from __future__ import annotations


class SimError(Exception):
    """Base class of every error `sim` raises on purpose."""


class ScenarioError(SimError, ValueError):
    """A scenario (TOML file or value) that is malformed or inconsistent."""


class PlantError(SimError, ValueError):
    """A plant configured with invalid parameters."""


__all__ = ["PlantError", "ScenarioError", "SimError"]
