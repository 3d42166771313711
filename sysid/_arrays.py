"""Read-only float copies: how frozen values hold arrays."""

from __future__ import annotations

from typing import Any

import numpy as np

from sysid._typing import FloatArray


def readonly_array(values: Any) -> FloatArray:
    """A float64 copy of ``values`` that cannot be written (never a view of the caller's)."""
    arr = np.array(values, dtype=float, copy=True)
    arr.setflags(write=False)
    return arr


__all__ = ["readonly_array"]
