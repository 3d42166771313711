"""Spans identification cannot represent are refused before any fit (`sysid.scale`)."""

from __future__ import annotations

import numpy as np
import pytest

from sysid.data import Dataset
from sysid.errors import IdentificationError
from sysid.pipeline import run_paper_pipeline
from sysid.scale import MAX_SPAN, MIN_SPAN, check_representable


def _log(input_scale: float, output_scale: float) -> Dataset:
    k = np.arange(200)
    u = np.where((k // 25) % 2 == 0, 4.0, 6.0)
    return Dataset(time_s=2.0 * k, triac_pct=input_scale * u,
                   power_kw=output_scale * (100.0 + np.cumsum(u - 5.0) * 0.1),
                   ts_s=2.0, input_unit="V", output_unit="degC")


@pytest.mark.parametrize(("input_scale", "output_scale", "pattern"), [
    (1.0, 1e200, r"the output spans 2.5e\+200 degC"),
    (1.0, 1e-200, r"the output spans 2.5e-200 degC"),
    (1e200, 1.0, r"the input spans 2e\+200 V"),
    (1e-200, 1.0, r"the input spans 2e-200 V"),
], ids=["output-1e200", "output-1e-200", "input-1e200", "input-1e-200"])
def test_spans_beyond_the_representable_range_are_refused_by_name(
    input_scale: float, output_scale: float, pattern: str,
) -> None:
    with pytest.raises(IdentificationError, match="run_paper_pipeline: " + pattern):
        run_paper_pipeline(_log(input_scale, output_scale))


def test_the_range_holds_at_its_ends_and_leaves_a_constant_signal_to_other_checks() -> None:
    check_representable(_log(1.0, MAX_SPAN / 2.5), where="t")      # 2.5 x that: MAX_SPAN
    check_representable(_log(MIN_SPAN / 2.0, 1.0), where="t")      # 2 x that: MIN_SPAN
    with pytest.raises(IdentificationError, match="t: the output spans"):
        check_representable(_log(1.0, 1.01 * MAX_SPAN / 2.5), where="t")
    flat = Dataset(time_s=np.arange(10.0), triac_pct=np.ones(10), power_kw=np.ones(10),
                   ts_s=1.0)
    check_representable(flat, where="t")
