"""Array helpers shared by sysid modules: read-only float copies (how frozen values hold
arrays), runs of a boolean mask, and the output's clipped samples."""

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


#: Shortest exactly constant run at the output's record maximum or minimum taken as
#: clipping (a saturated sensor or process, e.g. the cascaded tanks at 10 V).
CLIP_MIN_RUN_SAMPLES = 10


def clipped_samples(y: FloatArray, min_run: int = CLIP_MIN_RUN_SAMPLES) -> tuple[int, ...]:
    """Samples in exactly constant runs of at least ``min_run`` at ``y``'s max or min."""
    return tuple(sorted(k for extreme in {float(np.max(y)), float(np.min(y))}
                        for a, b in true_runs(y == extreme) if b - a >= min_run
                        for k in range(a, b)))


__all__ = ["CLIP_MIN_RUN_SAMPLES", "clipped_samples", "readonly_array", "true_runs"]
