"""Argument checks shared by sysid modules: one rule and one message form each."""

from __future__ import annotations

import numpy as np

from sysid.errors import IdentificationError


def checked_int(value: object, minimum: int, what: str,
                error: type[Exception] = IdentificationError) -> int:
    """``value`` as an ``int``: a whole number, Python's or numpy's (not a bool), >= ``minimum``.

    ``what`` names it in the message, with its function where that helps
    (``"detect_steps: delay_steps"``); ``error`` is raised as
    ``"{what} must be an int >= {minimum}; got {value!r}"``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise error(f"{what} must be an int >= {minimum}; got {value!r}")
    return int(value)


__all__ = ["checked_int"]
