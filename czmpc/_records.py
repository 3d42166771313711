"""record_from_fields: a frozen dataclass instance built from its fields at once (the step's records)."""

from __future__ import annotations

from typing import Any, TypeVar

_Record = TypeVar("_Record")


def record_from_fields(cls: type[_Record], fields: dict[str, Any]) -> _Record:
    """An instance of frozen dataclass ``cls`` whose ``__dict__`` is ``fields``, set at once.

    The step's path for its records (`czmpc.diagnostics.StepDiagnostics`,
    `czmpc.qp.QPSolution`, `czmpc.target.Target`, `czmpc.mismatch.MismatchStats`): a
    frozen dataclass's ``__init__`` calls ``object.__setattr__`` once per field, which
    cost more than the rest of building the record (issue 30). For classes without
    ``__post_init__`` and ``slots`` only, so nothing is skipped but the calls; ``fields``
    must name every field, in order (the tests check the step's records).

    Parameters
    ----------
    cls :
        The class.
    fields :
        Every field's value by name; the instance keeps this dict.
    """
    record: _Record = object.__new__(cls)
    object.__setattr__(record, "__dict__", fields)
    return record


__all__ = ["record_from_fields"]
