"""How a configuration error shows what it got, and what it expected, in the user's words.

Every validator of a user's file says what it got as the user wrote it, never as a
Python repr: ``true``, ``[30, 60]``, a table as ``{ id = '...' }``, a path as its text.
An unknown key gets a did-you-mean hint.
"""

from __future__ import annotations

import difflib
import math
import os
from collections.abc import Iterable, Mapping
from typing import Any


def shown(value: Any) -> str:
    """``value`` as the user would have written it in a TOML file or on the command line."""
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return "'" + value.replace("'", "\\'") + "'"
    if isinstance(value, os.PathLike):
        return shown(os.fspath(value))
    if isinstance(value, float):
        return repr(value) if not math.isfinite(value) else f"{value:g}"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{k} = {shown(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list | tuple | set | frozenset):
        return "[" + ", ".join(shown(v) for v in value) + "]"
    return str(value)


def choices(values: Iterable[Any]) -> str:
    """``'a', 'b' or 'c'``: the allowed values, each as `shown`."""
    items = [shown(v) for v in values]
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} or {items[-1]}"


def did_you_mean(word: str, valid: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest valid word, or ``""``."""
    close = difflib.get_close_matches(word, list(valid), n=1)
    return f" (did you mean {shown(close[0])}?)" if close else ""


def unknown_key(where: str, key: str, valid: Iterable[str]) -> str:
    """The message of an unknown key: ``where`` names the table (or is empty)."""
    valid = list(valid)
    return (f"{where}unknown key {shown(key)}{did_you_mean(key, valid)}; valid keys: "
            f"{', '.join(valid)}")


__all__ = ["choices", "did_you_mean", "shown", "unknown_key"]
