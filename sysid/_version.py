"""The installed version of the ``czmpc`` distribution (which ships sysid, sim and czmpc).

The one source of truth is ``version`` in pyproject.toml; the installed metadata
carries it, and this module reads it back. ``czmpc.__version__``, ``czmpc --version``,
the reports' "Produced by" lines and the ``software`` entry of model-file provenance
all come from here. sysid is the ground floor, so the reading lives here, not in czmpc.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version


def distribution_version() -> str:
    """The version of the installed ``czmpc`` distribution (``"0+unknown"`` when not installed)."""
    try:
        return version("czmpc")
    except PackageNotFoundError:   # run from a source tree that was never installed
        return "0+unknown"


__version__ = distribution_version()
"""The version of the installed ``czmpc`` distribution."""

SOFTWARE = f"czmpc {__version__}"
"""Name and version of the software, as written in reports and model-file provenance."""

__all__ = ["SOFTWARE", "__version__", "distribution_version"]
