"""Typed values for PLC nodes, refusal kinds and the per-node check (no server needed).

References are computed here independently: `decimal` rounding half away from zero,
numpy's float32 and integer limits, asyncua's own table of status codes.
"""

from __future__ import annotations

import datetime as dt
import math
from decimal import ROUND_HALF_UP, Decimal

import numpy as np
import pytest

asyncua = pytest.importorskip("asyncua")
ua = asyncua.ua

from czmpc.runtime import refusals  # noqa: E402
from czmpc.runtime.link import check_node  # noqa: E402
from czmpc.runtime.node_types import (  # noqa: E402
    INTEGER_RANGES,
    LinearScale,
    NodeSpec,
    NodeValueError,
    decode,
    encode,
    next_heartbeat,
    parse_node_spec,
)

S7_ANALOG = LinearScale(0.0, 27648.0, 0.0, 100.0)   # an S7 analog value: 27648 counts = 100 %


def _half_away(x: float) -> int:
    return int(Decimal(repr(x)).quantize(Decimal(1), rounding=ROUND_HALF_UP))


@pytest.mark.parametrize("name,dtype", [("SByte", np.int8), ("Byte", np.uint8),
                                        ("Int16", np.int16), ("UInt16", np.uint16),
                                        ("Int32", np.int32), ("UInt32", np.uint32),
                                        ("Int64", np.int64), ("UInt64", np.uint64)])
def test_integer_ranges_are_those_of_the_machine_types(name: str, dtype: type) -> None:
    info = np.iinfo(dtype)
    assert INTEGER_RANGES[name] == (int(info.min), int(info.max))
    top = min(int(info.max), 2**53)      # the largest top a float carries exactly
    assert encode(float(top), name) == top
    beyond = float(info.max) + 1.0 if info.max < 2**53 else float(info.max) * 2.0
    with pytest.raises(NodeValueError, match=f"outside the {name} range"):
        encode(beyond, name)


@pytest.mark.parametrize("x", [-2.5, -0.5, 0.49999, 0.5, 1.5, 2.5, 12815.5, 46.352 * 276.48])
def test_integers_round_half_away_from_zero(x: float) -> None:
    assert encode(x, "Int32") == _half_away(x)


def test_a_scaled_command_is_carried_by_a_raw_int16_both_ways() -> None:
    raw = encode(46.352, "Int16", S7_ANALOG)
    assert raw == _half_away(46.352 * 276.48) == 12815
    # read back, the raw count carries the value to within half a count (0.0018 %)
    assert abs(decode(raw, S7_ANALOG) - 46.352) <= 0.5 * 100.0 / 27648.0
    assert encode(100.0, "Int16", S7_ANALOG) == 27648
    with pytest.raises(NodeValueError, match="outside the Byte range 0..255"):
        encode(50.0, "Byte", S7_ANALOG)


def test_scaling_round_trips_to_float_precision() -> None:
    scale = LinearScale(-5000.0, 5000.0, 20.0, 80.0)
    for x in np.linspace(-10.0, 110.0, 25):
        assert scale.from_raw(scale.to_raw(float(x))) == pytest.approx(float(x), rel=1e-14, abs=1e-12)


def test_float_is_range_checked_as_float32_and_other_kinds_refused() -> None:
    top = float(np.finfo(np.float32).max)
    assert encode(top, "Float") == top
    with pytest.raises(NodeValueError, match="float32"):
        encode(np.nextafter(top, math.inf) * 1.0001, "Float")
    with pytest.raises(NodeValueError):
        encode(math.nan, "Double")
    assert encode(1.0, "Boolean") is True
    with pytest.raises(NodeValueError, match="only 0 or 1"):
        encode(45.0, "Boolean")
    assert encode(45.0, "String") == "45"
    with pytest.raises(NodeValueError, match="cannot carry a number"):
        encode(45.0, "DateTime")


def test_reads_accept_every_numeric_type() -> None:
    assert decode(13824, S7_ANALOG) == 50.0
    assert decode(np.float32(41.5).item()) == 41.5
    assert decode(True) == 1.0
    with pytest.raises(NodeValueError, match="expected a number"):
        decode("41.5")


def test_the_heartbeat_continues_and_wraps_within_its_type() -> None:
    assert next_heartbeat(65534, "UInt16") == 65535
    assert next_heartbeat(65535, "UInt16") == 0
    assert next_heartbeat(32767, "Int16") == 0
    assert next_heartbeat(-7, "Int16") == -6
    assert next_heartbeat(None, "UInt32") == 0          # nothing readable: start at 0
    assert next_heartbeat(True, "Boolean") is False     # a BOOL life bit toggles
    assert next_heartbeat(2.0**24 - 1, "Float") == 0.0  # float32 still counts exactly below 2^24
    with pytest.raises(NodeValueError, match="heartbeat"):
        next_heartbeat(3, "String")


def test_a_node_is_a_string_or_a_table_with_its_scaling() -> None:
    assert parse_node_spec('ns=3;s="DB_Heater"."TriacCmd"', "nodes.triac_pct") == NodeSpec(
        'ns=3;s="DB_Heater"."TriacCmd"')
    spec = parse_node_spec({"id": "ns=3;i=7", "raw": [0, 27648], "value": [0.0, 100.0]},
                           "nodes.triac_pct")
    assert spec.scale == S7_ANALOG
    with pytest.raises(NodeValueError, match="nodes.triac_pct: give both"):
        parse_node_spec({"id": "ns=3;i=7", "raw": [0, 27648]}, "nodes.triac_pct")
    with pytest.raises(NodeValueError, match="nodes.triac_pct.raw"):
        parse_node_spec({"id": "ns=3;i=7", "raw": [0], "value": [0, 100]}, "nodes.triac_pct")
    with pytest.raises(NodeValueError, match="two distinct"):
        parse_node_spec({"id": "ns=3;i=7", "raw": [5, 5], "value": [0, 100]}, "nodes.triac_pct")


def test_refusal_codes_are_real_status_codes_and_sorted_by_kind() -> None:
    for name in refusals.CONFIGURATION_CODES | refusals.LINK_CODES:
        assert hasattr(ua.StatusCodes, name), name
    assert not refusals.CONFIGURATION_CODES & refusals.LINK_CODES
    assert refusals.kind_of("BadTypeMismatch") == "configuration"
    assert refusals.kind_of("BadSessionIdInvalid") == "link"
    assert refusals.kind_of("BadResourceUnavailable") == "transient"


def _attributes(type_id: int, *, access: int = 3, user_access: int | None = None, rank: int = -1,
                value: object = 45.0, vtype: object = None, source: bool = True) -> dict[str, object]:
    stamp = dt.datetime.now(dt.UTC)

    def dv(v: object, t: object) -> object:
        return ua.DataValue(ua.Variant(v, t))

    return {
        "Value": ua.DataValue(ua.Variant(value, vtype or ua.VariantType.Float),
                              SourceTimestamp=stamp if source else None, ServerTimestamp=stamp),
        "DataType": dv(ua.NodeId(type_id, 0), ua.VariantType.NodeId),
        "ValueRank": dv(rank, ua.VariantType.Int32),
        "AccessLevel": dv(access, ua.VariantType.Byte),
        "UserAccessLevel": dv(access if user_access is None else user_access, ua.VariantType.Byte),
    }


def test_the_check_passes_a_float_command_and_says_what_is_wrong_otherwise() -> None:
    spec = NodeSpec('ns=3;s="DB_Heater"."TriacCmd"')
    ok, info = check_node("triac_pct", spec, _attributes(10), user=None)
    assert ok.problem is None and info is not None and info.type_name == "Float"
    boolean, _ = check_node("triac_pct", spec, _attributes(1, value=False,
                                                         vtype=ua.VariantType.Boolean), user=None)
    assert boolean.code == "BadTypeMismatch" and "Boolean" in (boolean.problem or "")
    read_only, _ = check_node("triac_pct", spec, _attributes(10, access=1), user=None)
    assert read_only.code == "BadNotWritable"
    denied, _ = check_node("triac_pct", spec, _attributes(10, user_access=1), user="viewer")
    assert denied.code == "BadUserAccessDenied" and "'viewer'" in (denied.problem or "")
    array, _ = check_node("triac_pct", spec, _attributes(10, rank=1), user=None)
    assert array.problem is not None and "array" in array.problem
    byte_scaled = NodeSpec("ns=3;i=9", S7_ANALOG)
    too_small, _ = check_node("triac_pct", byte_scaled, _attributes(3, value=0,
                                                                  vtype=ua.VariantType.Byte),
                              user=None)
    assert too_small.code == "BadTypeMismatch" and "Byte range" in (too_small.problem or "")
    whole_percent, _ = check_node("triac_pct", NodeSpec("ns=3;i=9"),
                                  _attributes(4, value=45, vtype=ua.VariantType.Int16), user=None)
    assert whole_percent.problem is None and "whole units" in whole_percent.note
    no_source, _ = check_node("power_kw", NodeSpec("ns=3;i=1"), _attributes(10, access=1,
                                                                          source=False), user=None)
    assert no_source.problem is None and "server timestamp" in no_source.note
