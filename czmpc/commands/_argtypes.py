"""argparse ``type=`` converters shared by the sub-commands (not a sub-command itself).

Each converter raises `argparse.ArgumentTypeError` with what was expected and what was
given, which the parser turns into ``czmpc: error: ...`` and exit code 2.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

_REPO = Path(__file__).resolve().parents[2]


def integer(minimum: int, what: str = "an integer") -> Callable[[str], int]:
    """Converter to an int >= ``minimum``."""

    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what} >= {minimum}; got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {what} >= {minimum}; got {text!r}")
        return value

    return convert


def number(
    *, above: float | None = None, at_least: float | None = None, at_most: float | None = None,
    unit: str = "",
) -> Callable[[str], float]:
    """Converter to a finite float with optional bounds (``above`` is exclusive)."""
    parts = ["a finite number"]
    if above is not None:
        parts.append(f"> {above:g}")
    if at_least is not None:
        parts.append(f">= {at_least:g}")
    if at_most is not None:
        parts.append(f"<= {at_most:g}")
    expected = " ".join(parts) + (f" [{unit}]" if unit else "")

    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}; got {text!r}") from None
        if not (math.isfinite(value)
                and (above is None or value > above)
                and (at_least is None or value >= at_least)
                and (at_most is None or value <= at_most)):
            raise argparse.ArgumentTypeError(f"expected {expected}; got {text!r}")
        return value

    return convert


#: A seed for the random number generators (any int >= 0).
seed = integer(0, "an integer seed")
positive_int = integer(1)
non_negative_int = integer(0)
finite_float = number()
positive_float = number(above=0.0)
non_negative_float = number(at_least=0.0)
#: A shortening factor for scenarios: times x FACTOR, 0 < FACTOR <= 1.
shortening_factor = number(above=0.0, at_most=1.0)


def default_benchmarks_md() -> Path:
    """BENCHMARKS.md at the project root of a source checkout, else in the working directory."""
    return _REPO / "BENCHMARKS.md" if (_REPO / "pyproject.toml").is_file() else Path("BENCHMARKS.md")
