"""Errors of PID tuning: a model, option or table the tuning cannot use as given."""

from __future__ import annotations

from czmpc.errors import CzmpcError


class PIDTuningError(CzmpcError, ValueError):
    """A model, tuning option, span or table that PID tuning cannot use (the message says why)."""


__all__ = ["PIDTuningError"]
