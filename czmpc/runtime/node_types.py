"""What a PLC's OPC UA variable can carry, and the value czmpc writes into it.

A PLC serves an S7 ``REAL`` as ``Float`` (float32), a ``WORD`` as ``UInt16``, an ``INT``
as ``Int16``, a ``BOOL`` as ``Boolean``, and refuses a write of another type
(``BadTypeMismatch``). So czmpc reads each node's ``DataType`` once per session
(`NodeType`) and writes a Variant of that type (`encode`): floats range-checked, integers
rounded half away from zero and range-checked, never silently clipped. A node may carry
a scaled value (`LinearScale`, e.g. raw 0..27648 for 0..100 %), applied both ways; the
run config's two forms of a node (`parse_node_spec`): docs/reference/run_config.rst.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from czmpc.errors import CzmpcError

#: Inclusive ranges of the OPC UA integer types (Part 6, 5.2.2).
INTEGER_RANGES: dict[str, tuple[int, int]] = {
    "SByte": (-(2**7), 2**7 - 1), "Byte": (0, 2**8 - 1),
    "Int16": (-(2**15), 2**15 - 1), "UInt16": (0, 2**16 - 1),
    "Int32": (-(2**31), 2**31 - 1), "UInt32": (0, 2**32 - 1),
    "Int64": (-(2**63), 2**63 - 1), "UInt64": (0, 2**64 - 1),
}
#: Largest finite float32 (an S7 REAL).
FLOAT32_MAX = 3.4028234663852886e38
#: Types whose values are numbers (reads accept every one of them).
NUMERIC_TYPES = frozenset({*INTEGER_RANGES, "Float", "Double"})
#: The built-in data types by their numeric node id in namespace 0 (Part 6, 5.1.2), and
#: the standard subtypes a PLC uses for plain numbers (Duration is a Double).
_BUILTIN_BY_ID: dict[int, str] = {
    1: "Boolean", 2: "SByte", 3: "Byte", 4: "Int16", 5: "UInt16", 6: "Int32", 7: "UInt32",
    8: "Int64", 9: "UInt64", 10: "Float", 11: "Double", 12: "String", 13: "DateTime",
    290: "Double",
}
#: Heartbeat counters of a float type wrap where the type still holds every integer.
_FLOAT_COUNTER_TOP = {"Float": 2**24, "Double": 2**53}


class NodeValueError(CzmpcError, ValueError):
    """A value the node's type cannot carry (out of its range, or not of its kind)."""


@dataclass(frozen=True, slots=True)
class LinearScale:
    """Linear map between a node's raw value and czmpc's value (both ways).

    ``raw_lo`` carries ``value_lo`` and ``raw_hi`` carries ``value_hi``; values outside
    the span are extrapolated (and then range-checked by the node's type).
    """

    raw_lo: float
    raw_hi: float
    value_lo: float
    value_hi: float

    def __post_init__(self) -> None:
        numbers = (self.raw_lo, self.raw_hi, self.value_lo, self.value_hi)
        if not all(math.isfinite(v) for v in numbers):
            raise NodeValueError(f"scaling needs finite numbers; got raw {self.raw_lo, self.raw_hi}, "
                                 f"value {self.value_lo, self.value_hi}")
        if self.raw_lo == self.raw_hi or self.value_lo == self.value_hi:
            raise NodeValueError(f"scaling needs two distinct raw and value ends; got raw "
                                 f"[{self.raw_lo:g}, {self.raw_hi:g}], value "
                                 f"[{self.value_lo:g}, {self.value_hi:g}]")

    def to_raw(self, value: float) -> float:
        """The raw number that carries ``value``."""
        span = (value - self.value_lo) / (self.value_hi - self.value_lo)
        return self.raw_lo + span * (self.raw_hi - self.raw_lo)

    def from_raw(self, raw: float) -> float:
        """The value a raw number carries."""
        span = (raw - self.raw_lo) / (self.raw_hi - self.raw_lo)
        return self.value_lo + span * (self.value_hi - self.value_lo)

    def describe(self) -> str:
        """``raw 0..27648 = 0..100`` for messages and the check table."""
        return (f"raw {self.raw_lo:g}..{self.raw_hi:g} = {self.value_lo:g}..{self.value_hi:g}")


@dataclass(frozen=True, slots=True)
class NodeSpec:
    """A configured node: its id (as the server spells it) and an optional scaling."""

    node_id: str
    scale: LinearScale | None = None

    def describe(self) -> str:
        """The id, and the scaling when there is one."""
        return self.node_id if self.scale is None else f"{self.node_id} ({self.scale.describe()})"


@dataclass(frozen=True, slots=True)
class NodeType:
    """A variable's type and this user's access, read once per session.

    Parameters
    ----------
    type_name :
        The built-in type of its ``DataType`` (``"Float"``, ``"UInt16"``, ...), or the
        data type's node id in words when it is none of them.
    value_rank :
        ``ValueRank``: -1 scalar, -2 any, -3 scalar or one-dimensional, >= 0 an array.
    user_readable, user_writable :
        ``UserAccessLevel`` bits ``CurrentRead`` and ``CurrentWrite``.
    """

    type_name: str
    value_rank: int
    user_readable: bool
    user_writable: bool

    @property
    def scalar(self) -> bool:
        """True when the variable may hold a single value."""
        return self.value_rank in (-1, -2, -3)

    @property
    def numeric(self) -> bool:
        """True for the integer types, Float and Double."""
        return self.type_name in NUMERIC_TYPES


def builtin_type_name(namespace: int, identifier: object) -> str | None:
    """The built-in type name of a ``DataType`` node id, or None for another type."""
    if namespace == 0 and isinstance(identifier, int):
        return _BUILTIN_BY_ID.get(identifier)
    return None


def parse_node_spec(value: Any, where: str) -> NodeSpec:
    """A `NodeSpec` from a run config's ``[nodes]`` value (module docstring).

    Raises
    ------
    NodeValueError
        Neither a non-empty string nor a table ``{id, raw = [lo, hi], value = [lo, hi]}``;
        ``where`` (e.g. ``nodes.triac_pct``) names it in the message.
    """
    if isinstance(value, str) and value.strip():
        return NodeSpec(value)
    if not isinstance(value, dict):
        raise NodeValueError(f"{where}: expected a node id string or a table {{ id = ..., raw = "
                             f"[LO, HI], value = [LO, HI] }}; got {value!r}")
    unknown = set(value) - {"id", "raw", "value"}
    if unknown:
        raise NodeValueError(f"{where}.{sorted(unknown)[0]}: unknown key; expected id, raw, value")
    node_id = value.get("id")
    if not isinstance(node_id, str) or not node_id.strip():
        raise NodeValueError(f"{where}.id: expected a non-empty node id string; got {node_id!r}")
    if ("raw" in value) != ("value" in value):
        raise NodeValueError(f"{where}: give both raw = [LO, HI] and value = [LO, HI], or neither")
    if "raw" not in value:
        return NodeSpec(node_id)
    ends: list[float] = []
    for key in ("raw", "value"):
        pair = value[key]
        if (not isinstance(pair, list) or len(pair) != 2
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in pair)):
            raise NodeValueError(f"{where}.{key}: expected [LO, HI] (two numbers); got {pair!r}")
        ends.extend(float(v) for v in pair)
    try:
        return NodeSpec(node_id, LinearScale(*ends))
    except NodeValueError as exc:
        raise NodeValueError(f"{where}: {exc}") from None


def _round_half_away(x: float) -> int:
    return int(math.floor(abs(x) + 0.5)) * (1 if x >= 0 else -1)


def encode(value: float | bool | str, type_name: str, scale: LinearScale | None = None
           ) -> float | int | bool | str:
    """The Python value of a Variant of ``type_name`` that carries ``value``.

    Numbers are scaled to raw first (`LinearScale.to_raw`). Integer types round half
    away from zero; every type checks its range. ``Boolean`` carries only 0/1 (or a
    bool), ``String`` any value as text.

    Raises
    ------
    NodeValueError
        A value outside the type's range, not finite, or a type that cannot carry it.
    """
    if type_name == "String":
        return value if isinstance(value, str) else f"{value:g}"
    if isinstance(value, str):
        raise NodeValueError(f"a {type_name} node cannot carry the text {value!r}")
    x = float(value)
    if scale is not None:
        x = scale.to_raw(x)
    if type_name == "Boolean":
        if x not in (0.0, 1.0):
            raise NodeValueError(f"a Boolean node carries only 0 or 1; got {x:g}")
        return bool(x)
    if not math.isfinite(x):
        raise NodeValueError(f"a {type_name} node cannot carry {x}")
    if type_name == "Double":
        return x
    if type_name == "Float":
        if abs(x) > FLOAT32_MAX:
            raise NodeValueError(f"{x:g} is outside the Float (float32) range +-{FLOAT32_MAX:.4g}")
        return x
    if type_name in INTEGER_RANGES:
        lo, hi = INTEGER_RANGES[type_name]
        n = _round_half_away(x)
        if not lo <= n <= hi:
            raise NodeValueError(f"{x:g} rounds to {n}, outside the {type_name} range {lo}..{hi}")
        return n
    raise NodeValueError(f"a node of type {type_name} cannot carry a number")


def decode(raw: Any, scale: LinearScale | None = None) -> float:
    """The value [czmpc's units] a read Variant carries: any numeric type, or a bool.

    Raises
    ------
    NodeValueError
        Text, None or another non-number.
    """
    if not isinstance(raw, int | float):   # a bool is an int
        raise NodeValueError(f"expected a number; the node holds {raw!r}")
    return float(raw) if scale is None else scale.from_raw(float(raw))


def next_heartbeat(current: Any, type_name: str) -> int | float | bool:
    """The heartbeat after ``current``: +1, wrapping to 0 past the type's top.

    A Boolean heartbeat toggles (a PLC's ``BOOL`` life bit). Float counters wrap at
    2^24, Double ones at 2^53, where every integer is still exact.

    Raises
    ------
    NodeValueError
        A type a watchdog counter cannot be (String, DateTime, ...).
    """
    if type_name == "Boolean":
        return not bool(current)
    if type_name in INTEGER_RANGES:
        if not isinstance(current, int | float) or not math.isfinite(current):
            return 0
        n = int(current)
        return 0 if n >= INTEGER_RANGES[type_name][1] else n + 1
    if type_name in _FLOAT_COUNTER_TOP:
        if not isinstance(current, int | float) or not math.isfinite(current):
            return 0.0
        x = float(math.floor(current))
        return 0.0 if abs(x) + 1 >= _FLOAT_COUNTER_TOP[type_name] else x + 1
    raise NodeValueError(f"a heartbeat counter must be an integer, Float, Double or Boolean "
                         f"node; this one is {type_name}")


__all__ = ["FLOAT32_MAX", "INTEGER_RANGES", "NUMERIC_TYPES", "LinearScale", "NodeSpec",
           "NodeType", "NodeValueError", "builtin_type_name", "decode", "encode",
           "next_heartbeat", "parse_node_spec"]
