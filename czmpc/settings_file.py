"""The controller settings file: MPCSettings as TOML, read and written.

Top-level keys are the fields of `czmpc.settings.MPCSettings`, the tables
``[reliability]`` and ``[osqp]`` those of `czmpc.settings.ReliabilitySettings` and
`czmpc.settings.OSQPOptions`; ``preset`` names the base (``MPCSettings.preset``). A
``float | None`` setting is switched off with ``"off"``. Errors are
`czmpc.errors.SettingsError` naming the file, the table and the key (user's page:
docs/reference/settings_file.rst).
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import types
import typing
from collections.abc import Callable, Mapping
from functools import partial
from pathlib import Path
from typing import Any, TypeVar, get_args

from czmpc.config_text import unknown_key
from czmpc.errors import SettingsError
from czmpc.settings import MPCSettings, OSQPOptions, PresetName, ReliabilitySettings
from sysid.model import HammersteinModel

#: How a switched-off optional setting is written in the file.
OFF = "off"
#: The tables of the file and the dataclass each one fills.
TABLES: dict[str, type[Any]] = {"reliability": ReliabilitySettings, "osqp": OSQPOptions}
#: The key that names the preset the file starts from.
PRESET_KEY = "preset"

_T = TypeVar("_T")


def field_docs(cls: type[Any]) -> dict[str, str]:
    """First sentence of each parameter's description in ``cls``'s numpy docstring (shared by ``a, b :``)."""
    doc = cls.__doc__ or ""
    block = doc.split("Parameters\n    ----------\n", 1)[-1]
    block = re.split(r"\n    [A-Z][a-z]+\n    -+\n", block, maxsplit=1)[0]
    docs: dict[str, str] = {}
    names: list[str] = []
    lines: list[str] = []

    def flush() -> None:
        text = " ".join(" ".join(lines).split())
        first = re.split(r"(?<=[.;])\s", text, maxsplit=1)[0] if text else ""
        for name in names:
            docs[name] = first.rstrip(".;")

    for line in block.splitlines():
        head = re.fullmatch(r"    ([a-z_][a-z0-9_, ]*) :", line)
        if head:
            flush()
            names = [n.strip() for n in head.group(1).split(",")]
            lines = []
        elif line.startswith("        "):
            lines.append(line.strip())
    flush()
    return docs


def _field_kind(cls: type[Any], name: str) -> tuple[type[Any], bool, tuple[str, ...]]:
    """(base type, may be None, allowed strings for a Literal) of one field."""
    hint = typing.get_type_hints(cls)[name]
    optional = False
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        args = [a for a in get_args(hint) if a is not type(None)]
        optional = len(args) < len(get_args(hint))
        hint = args[0]
    if typing.get_origin(hint) is typing.Literal:
        return str, optional, tuple(str(a) for a in get_args(hint))
    return hint, optional, ()


def _convert(where: str, cls: type[Any], name: str, value: object) -> object:
    """A TOML value as the field's Python value, or SettingsError saying what to write."""
    base, optional, choices = _field_kind(cls, name)
    if optional and value == OFF:
        return None
    off = f', or "{OFF}"' if optional else ""
    if choices:
        if value not in choices:
            raise SettingsError(f"{where}{name} must be one of {list(choices)}; got {value!r}")
        return value
    number = isinstance(value, int | float) and not isinstance(value, bool)
    ok, expected = {bool: (isinstance(value, bool), "true or false"),
                    int: (number and isinstance(value, int), f"an integer{off}"),
                    float: (number, f"a number{off}")}.get(base, (False, ""))
    if not expected:
        raise SettingsError(f"{where}{name} cannot be set from a file")  # pragma: no cover
    if not ok:
        raise SettingsError(f"{where}{name} must be {expected}; got {value!r}")
    return float(value) if base is float else value  # type: ignore[arg-type]


def _table_changes(where: str, cls: type[Any], table: Mapping[str, object]) -> dict[str, object]:
    valid = [f.name for f in dataclasses.fields(cls) if f.name not in TABLES]
    changes: dict[str, object] = {}
    for key, value in table.items():
        if key not in valid:
            raise SettingsError(unknown_key(where, key, valid))
        changes[key] = _convert(where, cls, key, value)
    return changes


def settings_from_dict(doc: Mapping[str, object], model: HammersteinModel, *,
                       source: str = "settings") -> MPCSettings:
    """Settings from a parsed settings document (module docstring).

    Parameters
    ----------
    doc :
        The TOML document as a dict.
    model :
        The model the settings are for: the preset is built on it.
    source :
        What to call the document in error messages (usually its path).

    Raises
    ------
    SettingsError
        An unknown key or preset, a value of the wrong type, out of range or
        inconsistent with another (the message names the key).
    """
    doc = dict(doc)
    preset = doc.pop(PRESET_KEY, "default")
    if preset not in get_args(PresetName):
        raise SettingsError(f"{source}: {PRESET_KEY} must be one of "
                            f"{list(get_args(PresetName))}; got {preset!r}")
    base = MPCSettings.preset(typing.cast(PresetName, preset), model)
    tables: dict[str, object] = {}
    for name, cls in TABLES.items():
        table = doc.pop(name, {})
        if not isinstance(table, dict):
            raise SettingsError(f"{source}: [{name}] must be a table; got {table!r}")
        changes = _table_changes(f"{source}: [{name}] ", cls, table)
        tables[name] = _checked(source, partial(dataclasses.replace, getattr(base, name), **changes))
    changes = _table_changes(f"{source}: ", MPCSettings, doc)
    return _checked(source, partial(base.with_updates, **changes, **tables))


def _checked(source: str, build: Callable[[], _T]) -> _T:
    """``build()``, with the source named in a SettingsError raised by a validator."""
    try:
        return build()
    except SettingsError as exc:
        raise SettingsError(f"{source}: {exc}") from None


def load_settings_doc(path: str | Path) -> dict[str, Any]:
    """The parsed TOML of a settings file, not yet checked against a model.

    Raises
    ------
    SettingsError
        The file cannot be read or is not TOML.
    """
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise SettingsError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise SettingsError(f"{path}: cannot read the settings file: {exc.strerror}") from None


def load_settings(path: str | Path, model: HammersteinModel) -> MPCSettings:
    """Read and check a settings TOML file for ``model`` (module docstring).

    Raises
    ------
    SettingsError
        The file cannot be read, is not TOML, or holds an invalid setting.
    """
    return settings_from_dict(load_settings_doc(path), model, source=str(path))


def _toml_value(value: object) -> str:
    if value is None:
        return f'"{OFF}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else f'"{value}"'
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return str(value)


def _table_lines(obj: Any, comments: bool) -> list[str]:
    cls = type(obj)
    docs = field_docs(cls) if comments else {}
    rows = [(f.name, _toml_value(getattr(obj, f.name))) for f in dataclasses.fields(obj)
            if f.name not in TABLES]
    width = max(len(f"{k} = {v}") for k, v in rows)
    lines = []
    for key, text in rows:
        line = f"{key} = {text}"
        if docs.get(key):
            note = docs[key].replace("``", "").replace("None", f'"{OFF}"')
            line = f"{line:<{width}}  # {note}"
        lines.append(line)
    return lines


def settings_to_toml(settings: MPCSettings, *, comments: bool = True) -> str:
    """The settings as a settings file that `load_settings` reads back to the same value.

    Parameters
    ----------
    settings :
        The effective settings.
    comments :
        Follow every key with the first sentence of its documentation (units in brackets).
    """
    lines = _table_lines(settings, comments)
    for name in TABLES:
        lines += ["", f"[{name}]", *_table_lines(getattr(settings, name), comments)]
    return "\n".join(lines) + "\n"


__all__ = ["OFF", "PRESET_KEY", "TABLES", "field_docs", "load_settings", "load_settings_doc",
           "settings_from_dict", "settings_to_toml"]
