"""Real logs from other rigs (data/real): readers, preprocessing and an ARX fit on them."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from sysid.data import Dataset
from sysid.errors import DataFileError, IdentificationError
from sysid.linear import arx_least_squares, fit_arx
from sysid.model import OperatingPoint
from sysid.preprocess import find_operating_point, find_outlier_candidates, to_deviation
from sysid.residuals import autocorrelation
from sysid.simulate import simulate
from tests.sysid.reallogs import (
    read_cascaded_tanks,
    read_daisy_exchanger,
    read_daisy_heating,
    read_tclab,
)

REPO = Path(__file__).resolve().parents[2]
REAL = REPO / "data" / "real"
DAISY = REAL / "daisy_heating_system.dat"
TCLAB = REAL / "tclab_mimo_steps_data.txt"
TANKS = REAL / "cascaded_tanks_dataBenchmark.csv"
EXCHANGER = REAL / "daisy_exchanger.dat"
#: data/real/README.md: the first 16 hex digits of each file's SHA-256.
SHA256_PREFIX = {DAISY: "928866ebcfadf998", TCLAB: "10278caee2b095cc",
                 EXCHANGER: "cfb5a447fb573f87",
                 TANKS: "7416cb2aeb97c077"}
#: DaISy's description: the steady input before the experiment; y0 = y[0].
DAISY_U0_V, DAISY_Y0_DEGC = 6.0, 129.32
#: A fit % well above 50 (the brief); ARX(2,2,1) measures 82.8 % on this record.
MIN_FIT_PCT = 75.0


def _fit_pct(measured: np.ndarray, simulated: np.ndarray) -> float:
    """NRMSE fit [%]: ``100 (1 - |y - yhat| / |y - mean y|)`` (MATLAB ``compare``)."""
    return float(100.0 * (1.0 - np.linalg.norm(measured - simulated)
                          / np.linalg.norm(measured - measured.mean())))


@pytest.fixture(scope="module")
def daisy() -> Dataset:
    return read_daisy_heating(DAISY)


@pytest.fixture(scope="module")
def tclab() -> Dataset:
    return read_tclab(TCLAB)


@pytest.fixture(scope="module")
def tanks() -> Dataset:
    return read_cascaded_tanks(TANKS)


# --------------------------------------------------------------------------- readers


def test_files_are_the_published_bytes() -> None:
    for path, prefix in SHA256_PREFIX.items():
        assert hashlib.sha256(path.read_bytes()).hexdigest().startswith(prefix), path.name


def test_daisy_loads_801_samples_at_2_s_in_volts_and_degc(daisy: Dataset) -> None:
    assert daisy.n_samples == 801
    assert daisy.ts_s == 2.0
    assert (daisy.input_unit, daisy.output_unit) == ("V", "degC")
    np.testing.assert_array_equal(daisy.time_s, 2.0 * np.arange(801))
    assert daisy.power_kw[0] == DAISY_Y0_DEGC
    assert daisy.sha256 is not None and daisy.sha256.startswith(SHA256_PREFIX[DAISY])
    assert daisy.source == str(DAISY)
    # the README's staircase: k=0..199 u=9, 200..399 u=4, 400..499 u=8, 500..599 u=3, ...
    for start, stop, volts in ((0, 200, 9.0), (200, 400, 4.0), (400, 500, 8.0),
                               (500, 600, 3.0), (600, 700, 7.0), (700, 801, 6.0)):
        assert np.all(daisy.triac_pct[start:stop] == volts)
    steps = np.diff(np.unique(daisy.power_kw))
    assert np.min(steps) == pytest.approx(0.244, abs=0.001)  # reason: 3-decimal quantization


def test_tclab_loads_599_jittered_samples_at_nominal_1_s(tclab: Dataset) -> None:
    assert tclab.n_samples == 599
    assert tclab.ts_s == 1.0
    assert (tclab.input_unit, tclab.output_unit) == ("%", "degC")
    intervals = np.diff(tclab.time_s)
    assert 0.98 < intervals.min() < 1.0 < intervals.max() < 1.03  # real jitter, kept as logged
    assert tclab.time_s[-1] == pytest.approx(598.9, abs=0.05)  # reason: README's 598.9 s
    assert tclab.triac_pct[9] == 0.0 and tclab.triac_pct[10] == 100.0  # Q1 0 -> 100 % at k=10
    assert 20.0 < tclab.power_kw.min() and tclab.power_kw.max() < 56.0


def test_tclab_heater_2_reads_the_other_pair() -> None:
    data = read_tclab(TCLAB, heater=2)
    assert data.triac_pct[99] == 0.0 and data.triac_pct[100] == 50.0  # Q2 0 -> 50 % at k=100
    assert data.power_kw.max() == pytest.approx(42.5, abs=0.1)  # reason: README's T2 range


def test_tclab_jitter_is_refused_at_the_strict_default_tolerance() -> None:
    with pytest.raises(DataFileError, match=r"line \d+, column 'Time \(sec\)'.*interval"):
        read_tclab(TCLAB, sampling_rtol=0.01)


def test_cascaded_tanks_load_1024_samples_each_at_4_s(tanks: Dataset) -> None:
    val = read_cascaded_tanks(TANKS, record="validation")
    for data in (tanks, val):
        assert data.n_samples == 1024
        assert data.ts_s == 4.0
        assert (data.input_unit, data.output_unit) == ("V", "V")
        np.testing.assert_array_equal(data.time_s, 4.0 * np.arange(1024))
    assert (tanks.triac_pct[0], tanks.power_kw[0]) == (3.2567, 5.205)
    assert (val.triac_pct[0], val.power_kw[0]) == (0.97619, 4.9728)
    assert (tanks.triac_pct[-1], tanks.power_kw[-1]) == (3.2615, 3.6831)
    assert int(np.count_nonzero(tanks.power_kw == 10.0)) == 47  # README: overflow samples
    assert int(np.count_nonzero(val.power_kw == 10.0)) == 37


# --------------------------------------------------------------------------- preprocessing


def test_daisy_given_operating_point_and_no_settled_stair(daisy: Dataset) -> None:
    given = OperatingPoint(triac_pct=DAISY_U0_V, power_kw=float(daisy.power_kw[0]))
    choice = find_operating_point(daisy, method="given", given=given)
    assert choice.operating_point == OperatingPoint(triac_pct=6.0, power_kw=129.32)
    assert choice.method == "given"
    # every stair (200-400 s) ends with the plate still drifting by more than the
    # band, even a 2 degC one: the finder says so instead of inventing a steady state
    for atol in (0.0, 2.0):
        with pytest.raises(IdentificationError, match=r"degC\); got none"):
            find_operating_point(daisy, method="steady", output_atol_kw=atol)
    last_stair = daisy.power_kw[700:]
    assert abs(last_stair[-20:].mean() - last_stair[-45:-25].mean()) > 2.0  # still moving


def test_daisy_outlier_detector_flags_nothing_on_a_clean_lab_record(daisy: Dataset) -> None:
    op = OperatingPoint(triac_pct=DAISY_U0_V, power_kw=DAISY_Y0_DEGC)
    report = find_outlier_candidates(daisy, operating_point=op)
    assert report.input_step_samples == (200, 400, 500, 600, 700)
    assert report.candidates == ()
    assert report.clipped_samples == ()
    # ARX(10,10) residual scale (measured 0.233 degC) is of the order of the 0.244 degC
    # quantization step; the largest residual (0.85 degC) stays under 5 scales
    assert 0.05 < report.scale_kw < 0.5
    assert np.nanmax(np.abs(report.residuals_kw)) < report.threshold_kw


def test_tclab_steady_window_is_the_ambient_start(tclab: Dataset) -> None:
    # Before Q1 switches on at k=10 the rig sits at ambient; the later stairs are too
    # short for the ~3-minute thermal time constant to settle.
    with pytest.raises(IdentificationError, match="got none"):
        find_operating_point(tclab, method="steady")
    choice = find_operating_point(tclab, method="steady", min_window_samples=8)
    window = choice.window
    assert window is not None and (window.start_sample, window.stop_sample) == (0, 10)
    assert choice.operating_point.triac_pct == 0.0
    assert choice.operating_point.power_kw == pytest.approx(20.8, abs=0.1)  # reason: README T1
    report = find_outlier_candidates(tclab, operating_point=choice.operating_point)
    assert report.input_step_samples == (10, 200, 400)
    assert report.candidates == ()


def test_tanks_have_no_steady_window_and_report_their_overflow(tanks: Dataset) -> None:
    with pytest.raises(IdentificationError, match=r"input constant within 0 .* got none"):
        find_operating_point(tanks, method="steady")  # the input moves every sample
    op = find_operating_point(tanks, method="means").operating_point
    report = find_outlier_candidates(tanks, operating_point=op)
    assert report.input_step_samples == ()  # a smooth multisine-like input has no steps
    clipped = np.array(report.clipped_samples)
    assert clipped.size == 47
    assert np.all(tanks.power_kw[clipped] == 10.0)
    # the linear ARX misses the rise into the first overflow (samples 150..176): a
    # candidate is flagged within 10 samples before it
    assert any(140 <= c.sample < 150 for c in report.candidates)


# --------------------------------------------------------------------------- identification


def test_daisy_arx_221_fits_its_own_data_well(daisy: Dataset) -> None:
    op = OperatingPoint(triac_pct=DAISY_U0_V, power_kw=DAISY_Y0_DEGC)
    result = fit_arx(daisy, operating_point=op, na=2, nb=2, nk=1)
    assert result.model.ts_s == 2.0
    fit_pct = _fit_pct(daisy.power_kw, simulate(result.model, daisy))
    assert fit_pct > MIN_FIT_PCT
    # independent check: the same least-squares ARX simulated by lfilter from rest at
    # the operating point (the steady state before the experiment)
    ds, dp = to_deviation(daisy, op)
    fit = arx_least_squares(dp, ds, na=2, nb=2, nk=1)
    reference_pct = _fit_pct(dp, lfilter(fit.b, fit.a, ds))
    assert reference_pct > MIN_FIT_PCT
    assert fit_pct == pytest.approx(reference_pct, abs=1.0)  # reason: initial conditions differ
    # a low-order ARX on real data leaves coloured residuals (the description's
    # "discrepancies"): the whiteness test must say so
    assert not autocorrelation(fit.residuals).is_white


# --------------------------------------------------------------------------- reader errors


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode())
    return path


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", r"the file is empty"),
        ("0 9 129\n2 9 129\n4 9\n", r"line 3: expected 3 whitespace-separated fields.*got 2"),
        ("0 9 129\n2 x 129\n4 9 129\n", r"line 2, column 'lamp_voltage_v': expected a number; "
                                        r"got 'x'"),
        ("0 9 129\n2 9 nan\n4 9 129\n", r"line 2, column 'plate_temperature_degc': expected a "
                                        r"finite number"),
        ("0 9 129\n\n4 9 129\n", r"line 2: blank line"),
        ("0 9 129\n2 9 129\n5 9 129\n", r"line 3, column 'time_s': sampling must be uniform"),
        ("0 9 129\n2 9 129\n2 9 129\n", r"line 3, column 'time_s': time must be strictly"),
        ("0 9 129\n2 9 129\n", r"expected at least 3 samples; got 2"),
        ("0 9 129\n2 9 129\n4 9 129\n\n\n", None),
    ],
    ids=["empty", "fields", "text", "nan", "blank", "uniform", "increasing", "short",
         "trailing-blank-ok"],
)
def test_read_daisy_heating_names_line_and_column(tmp_path: Path, text: str,
                                                  match: str | None) -> None:
    path = _write(tmp_path, "heat.dat", text)
    if match is None:
        assert read_daisy_heating(path).n_samples == 3
        return
    with pytest.raises(DataFileError, match=match):
        read_daisy_heating(path)


def test_read_daisy_heating_refuses_non_utf8(tmp_path: Path) -> None:
    path = tmp_path / "heat.dat"
    path.write_bytes(b"0 9 129\n\xff\n")
    with pytest.raises(DataFileError, match=r"expected UTF-8 text"):
        read_daisy_heating(path)


TCLAB_HEADER = ("Time (sec), Heater 1 (%), Heater 2 (%), Temperature 1 (degC), "
                "Temperature 2 (degC)\n")


@pytest.mark.parametrize(
    ("text", "kwargs", "match"),
    [
        (TCLAB_HEADER + "0,0,0,20,20\n1,0,0,20,20\n2,0,0,20,20\n", {"heater": 3},
         r"heater must be 1 or 2; got 3"),
        ("Time (sec), Heater 1 (%)\n0,0\n1,0\n2,0\n", {},
         r"line 1, column 'Temperature 1 \(degC\)': header must contain"),
        (TCLAB_HEADER + "0,0,0,20,20\n1,0,0,x,20\n2,0,0,20,20\n", {},
         r"line 3, column 'Temperature 1 \(degC\)': expected a number; got 'x'"),
        (TCLAB_HEADER + "0,0,0,20,20\n1.5,0,0,20,20\n2.5,0,0,20,20\n", {},
         r"line 3, column 'Time \(sec\)': sampling must be uniform"),
    ],
    ids=["heater", "header", "cell", "gap"],
)
def test_read_tclab_names_line_and_column(tmp_path: Path, text: str, kwargs: dict[str, object],
                                          match: str) -> None:
    path = _write(tmp_path, "data.txt", text)
    with pytest.raises(DataFileError, match=match):
        read_tclab(path, **kwargs)  # type: ignore[arg-type]


TANKS_HEADER_LINE = '"uEst","uVal","yEst","yVal","Ts",\r\n'


@pytest.mark.parametrize(
    ("text", "kwargs", "match"),
    [
        (TANKS_HEADER_LINE + "1,2,3,4,4,\r\n1,2,3,4,,\r\n1,2,3,4,,\r\n", {"record": "test"},
         r"record must be 'estimation' or 'validation'; got 'test'"),
        ('"u","y"\r\n1,2\r\n1,2\r\n1,2\r\n', {}, r"line 1: header must be"),
        (TANKS_HEADER_LINE + "1,2,3,4,,\r\n1,2,3,4,,\r\n1,2,3,4,,\r\n", {},
         r"line 2, column 'Ts': expected a number; got ''"),
        (TANKS_HEADER_LINE + "1,2,3,4,-4,\r\n1,2,3,4,,\r\n1,2,3,4,,\r\n", {},
         r"line 2, column 'Ts': expected a sampling time > 0; got '-4'"),
        (TANKS_HEADER_LINE + "1,2,3,4,4,\r\n1,2,3,4,5,\r\n1,2,3,4,,\r\n", {},
         r"line 3, column 'Ts': expected Ts empty or equal to the first row's 4; got '5'"),
        (TANKS_HEADER_LINE + "1,2,3,4,4,\r\n1,2,3,4\r\n1,2,3,4,,\r\n", {},
         r"line 3: expected 6 cells like the header; got 4"),
        (TANKS_HEADER_LINE + "1,2,3,4,4,\r\n1,2,,4,,\r\n1,2,3,4,,\r\n", {},
         r"line 3, column 'yEst': expected a number; got ''"),
        (TANKS_HEADER_LINE + "1,2,3,4,4,\r\n1,x,3,4,,\r\n1,2,3,4,,\r\n", {"record": "validation"},
         r"line 3, column 'uVal': expected a number; got 'x'"),
        (TANKS_HEADER_LINE + "1,2,3,4,4,\r\n\r\n1,2,3,4,,\r\n", {}, r"line 3: blank line"),
        (TANKS_HEADER_LINE + "1,2,3,4,4,\r\n", {}, r"expected at least 3 samples; got 1"),
    ],
    ids=["record", "header", "ts-missing", "ts-negative", "ts-differs", "cells", "y-empty",
         "u-text", "blank", "short"],
)
def test_read_cascaded_tanks_names_line_and_column(tmp_path: Path, text: str,
                                                   kwargs: dict[str, object], match: str) -> None:
    path = _write(tmp_path, "tanks.csv", text)
    with pytest.raises(DataFileError, match=match):
        read_cascaded_tanks(path, **kwargs)  # type: ignore[arg-type]


def test_read_cascaded_tanks_accepts_a_repeated_ts_and_trailing_blank_lines(
    tmp_path: Path,
) -> None:
    path = _write(tmp_path, "tanks.csv",
                  TANKS_HEADER_LINE + "1,2,3,4,4,\r\n5,6,7,8,4,\r\n9,10,11,12,,\r\n\r\n")
    data = read_cascaded_tanks(path, record="validation")
    np.testing.assert_array_equal(data.triac_pct, [2.0, 6.0, 10.0])
    np.testing.assert_array_equal(data.power_kw, [4.0, 8.0, 12.0])
    np.testing.assert_array_equal(data.time_s, [0.0, 4.0, 8.0])


def test_exchanger_loads_4000_samples_at_1_s_starting_held_at_flow_0_3() -> None:
    data = read_daisy_exchanger(EXCHANGER)
    assert data.n_samples == 4000 and data.ts_s == 1.0
    np.testing.assert_array_equal(data.time_s, np.arange(4000.0))
    assert (data.input_unit, data.output_unit) == ("-", "degC")
    # data/real/README.md: flow 0.10 .. 0.70, held at 0.3 at first; temperature 92.8 .. 101.4
    # (rounded: 92.8154 .. 101.441)
    assert data.triac_pct[0] == 0.3 and data.power_kw[0] == 98.6281
    assert 0.10 <= data.triac_pct.min() < 0.11 and 0.69 < data.triac_pct.max() <= 0.70
    assert (data.power_kw.min(), data.power_kw.max()) == (92.8154, 101.441)
    assert data.sha256 is not None and data.sha256.startswith(SHA256_PREFIX[EXCHANGER])


@pytest.mark.parametrize(("text", "pattern"), [
    ("1 0.3 98.6\n2 0.3\n3 0.3 98.6\n", r"line 2: expected 3 whitespace-separated fields"),
    ("1 0.3 98.6\n2 0.3 98.6\n4 0.3 98.6\n", r"line 3, column 'sample'"),
    ("1 0.3 98.6\n2 x 98.6\n3 0.3 98.6\n", r"line 2, column 'liquid_flow'"),
], ids=["fields", "skipped-index", "number"])
def test_read_daisy_exchanger_names_line_and_column(tmp_path: Path, text: str,
                                                    pattern: str) -> None:
    path = tmp_path / "exchanger.dat"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(DataFileError, match=pattern):
        read_daisy_exchanger(path)
