"""record_from_fields: a frozen dataclass instance built from its fields at once (the step's records)."""

from __future__ import annotations

from typing import Any, TypeVar

_Record = TypeVar("_Record")


def record_from_fields(cls: type[_Record], fields: dict[str, Any]) -> _Record:
    """An instance of frozen dataclass ``cls`` whose ``__dict__`` is ``fields``, set at once.

    A frozen dataclass's ``__init__`` calls ``object.__setattr__`` per field, costing more
    than the rest of a step's record. Only for classes without ``__post_init__`` and
    ``slots``; ``fields`` must name every field, in order (the tests check).

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
