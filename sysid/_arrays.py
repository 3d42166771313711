"""Array helpers shared by sysid modules: read-only float copies (how frozen values hold
arrays) and runs of a boolean mask."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from sysid._typing import FloatArray


def readonly_array(values: Any) -> FloatArray:
    """A float64 copy of ``values`` that cannot be written (never a view of the caller's)."""
    arr = np.array(values, dtype=float, copy=True)
    arr.setflags(write=False)
    return arr


def true_runs(mask: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[False], mask, [False]]).astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


__all__ = ["readonly_array", "true_runs"]
