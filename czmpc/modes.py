"""Controller modes, step statuses and the pure mode-transition function.

Modes (what the operator asked for):

``OFF``
    Nothing runs; `OffsetFreeMPC.step` hands back the input the caller applies.
``PREDICT``
    Shadow operation: estimator, target and plan run on the caller's applied input,
    nothing is applied. The estimator warms up here before ``ON``.
``ON``
    The controller computes and returns the input to apply.

Statuses (what one step did; `czmpc.controller.StepDiagnostics.status`), in order of
precedence: ``SHED`` (``ON`` but given up: a safe input is held), ``HELD`` (the input
was not moved by this step's plan: ``OFF``/``PREDICT``, or a solver fallback),
``PREDICTED`` (``ON`` on the model alone: the measurement was rejected), ``CLAMPED``
(``ON``, the input sits on a limit or the rate limit, the setpoint is unreachable, or
the applied input differed from the command) and ``GOOD``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Mode(enum.Enum):
    """Operating mode requested for the controller."""

    OFF = "off"
    PREDICT = "predict"
    ON = "on"


class Status(enum.Enum):
    """What one controller step did (module notes)."""

    GOOD = "good"
    PREDICTED = "predicted"
    CLAMPED = "clamped"
    HELD = "held"
    SHED = "shed"


@dataclass(frozen=True, slots=True, kw_only=True)
class ModeTransition:
    """One mode request and its outcome.

    Parameters
    ----------
    k :
        Sample index of the next step the new mode applies to.
    from_mode, to_mode :
        Mode before and after (equal when the request was refused).
    requested :
        The mode asked for.
    accepted :
        False if the request was refused (``to_mode == from_mode``).
    reason :
        Why, in words.
    """

    k: int
    from_mode: Mode
    to_mode: Mode
    requested: Mode
    accepted: bool
    reason: str


def transition(current: Mode, requested: Mode, *, estimator_ready: bool) -> tuple[Mode, str]:
    """Return ``(new_mode, reason)`` for a mode request; pure.

    ``OFF`` and ``PREDICT`` may always be entered, ``ON`` only with a warm estimator; a
    request for the current mode, or a refused one, leaves the mode as it is.

    Parameters
    ----------
    current :
        The mode now.
    requested :
        The mode asked for.
    estimator_ready :
        True if the estimator has seen its warm-up samples since its last (re)start.
    """
    if not isinstance(requested, Mode):
        return current, f"refused: {requested!r} is not a Mode"
    if requested is current:
        return current, "unchanged: already in this mode"
    if requested is Mode.ON and not estimator_ready:
        return current, "refused: the estimator is not warm (run PREDICT first)"
    return requested, "accepted"


__all__ = ["Mode", "ModeTransition", "Status", "transition"]
