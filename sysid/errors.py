"""Exceptions and warnings raised by `sysid`."""

from __future__ import annotations

from pathlib import Path


class SysidError(Exception):
    """Base class of every error `sysid` raises on purpose."""


class DataFileError(SysidError, ValueError):
    """A logged-data file (or an in-memory data set) that breaks the data contract.

    Attributes
    ----------
    path :
        The file, or None for an in-memory data set.
    line :
        1-based line number in the file, or None when the whole file is at fault.
    column :
        Column name at fault, or None.
    """

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        line: int | None = None,
        column: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.column = column
        where = []
        if self.path is not None:
            where.append(Path(self.path).name if len(self.path) > 60 else self.path)
        if line is not None:
            where.append(f"line {line}")
        if column is not None:
            where.append(f"column '{column}'")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class ModelFileError(SysidError, ValueError):
    """A model file or model value that breaks the ``czmpc-model/1`` contract."""


class UnstableModelError(ModelFileError):
    """A polynomial A(q) or C(q) with a root on or outside the unit circle."""


class SamplingTimeError(SysidError, ValueError):
    """Two discrete-time objects with different sampling times were combined."""


class IdentificationError(SysidError, ValueError):
    """Options or data that cannot support the requested identification."""


class IdentificationWarning(UserWarning):
    """An identification finished but did not converge (the best iterate is kept)."""


__all__ = [
    "DataFileError", "IdentificationError", "IdentificationWarning", "ModelFileError",
    "SamplingTimeError", "SysidError", "UnstableModelError"
]
