"""Array helpers shared by sysid modules: read-only float copies (how frozen values hold
arrays), runs of a boolean mask, the output's clipped samples and the robust standard
deviation (MAD) that the outlier search, the step detector and the rest check share."""

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


#: Median absolute deviation to standard deviation for Gaussian data, ``1 / Phi^-1(3/4)``.
MAD_TO_STD = 1.482602218505602


def robust_std(x: FloatArray) -> float:
    """``MAD_TO_STD * median(|x - median(x)|)``: the standard deviation of Gaussian ``x``,
    unmoved by a few outliers."""
    return MAD_TO_STD * float(np.median(np.abs(x - np.median(x))))


#: Shortest exactly constant run at the output's record maximum or minimum taken as
#: clipping (a saturated sensor or process, e.g. the cascaded tanks at 10 V).
CLIP_MIN_RUN_SAMPLES = 10


def clipped_samples(y: FloatArray, min_run: int = CLIP_MIN_RUN_SAMPLES) -> tuple[int, ...]:
    """Samples in exactly constant runs of at least ``min_run`` at ``y``'s max or min.

    A run from the first sample is the level the record starts at, not a limit reached:
    a heating test starts cold, at its minimum, and a quantised or held sensor repeats
    that value exactly (TCLab's log held for three samples: 12 samples at 20.83 degC).
    """
    return tuple(sorted(k for extreme in {float(np.max(y)), float(np.min(y))}
                        for a, b in true_runs(y == extreme) if b - a >= min_run and a > 0
                        for k in range(a, b)))


__all__ = ["CLIP_MIN_RUN_SAMPLES", "MAD_TO_STD", "clipped_samples", "readonly_array",
           "robust_std", "true_runs"]
