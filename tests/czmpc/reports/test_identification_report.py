"""The identification report in the data's own terms; the paper's values only when asked."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import pytest

from czmpc.reports.identification import render_report
from sysid.data import Dataset
from sysid.pipeline import PipelineResult, run_paper_pipeline
from tests.sysid.reallogs import read_daisy_heating

REPO = Path(__file__).resolve().parents[3]
DAISY = REPO / "data" / "real" / "daisy_heating_system.dat"


@pytest.fixture(scope="module")
def daisy_result() -> PipelineResult:
    data = read_daisy_heating(DAISY)   # lamp voltage [V] -> plate temperature [degC]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # a search may stop at its limit; not the point here
        return run_paper_pipeline(data, orders="paper", from_zeros=False)


def test_data_in_v_and_degc_get_their_units_and_no_paper_columns(
    daisy_result: PipelineResult,
) -> None:
    text = render_report(daisy_result, [])
    assert "[kW" not in text and "kW^2" not in text and "paper V" not in text
    assert "V [degC^2]" in text and "r [degC/V]" in text and "f(du) = " in text
    assert "TRIAC" not in text and "heater power" not in text
    assert "pass --reference paper to show them" in text


def test_reference_paper_adds_the_papers_columns(daisy_result: PipelineResult) -> None:
    text = render_report(daisy_result, [], reference=True)
    assert "paper V [kW^2]" in text and "paper iterations" in text
    assert "V [degC^2]" in text            # ours stay in the data's units


def test_data_in_percent_and_kw_show_the_paper_by_default(daisy_result: PipelineResult) -> None:
    raw = daisy_result.raw_data
    puller = Dataset(time_s=raw.time_s, triac_pct=raw.triac_pct, power_kw=raw.power_kw,
                     ts_s=raw.ts_s)       # units % and kW: a puller's log
    text = render_report(dataclasses.replace(daisy_result, raw_data=puller), [])
    assert "paper V [kW^2]" in text and "TRIAC input s" in text and "heater power P" in text
    off = render_report(dataclasses.replace(daisy_result, raw_data=puller), [], reference=False)
    assert "paper V" not in off


def test_notes_stand_under_the_header(daisy_result: PipelineResult) -> None:
    text = render_report(daisy_result, [], command="czmpc identify x", notes=["a change"])
    head, _, _ = text.partition("## ")
    assert "Produced by" in head and "**Note:** a change." in head
