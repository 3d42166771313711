"""czmpc.pid.table and vendor: the CSV contract, exact round trips, spans never assumed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from czmpc.pid.design import DesignSpec
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.schedule import PIDSchedule, tune_schedule
from czmpc.pid.table import (
    COLUMNS,
    characterizer_error_pct,
    characterizer_points,
    read_pid_table,
    write_pid_table,
)
from czmpc.pid.vendor import (
    VENDOR_DISCRETIZATION,
    VENDOR_DISCRETIZATION_SOURCE,
    Spans,
    dependent_to_independent,
    gain_to_band_pct,
    seconds_to_minutes,
    vendor_csv_text,
    vendor_table,
)
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sysid.model import HammersteinModel
from sysid.modelfile import load_model
from tests.tolerances import CONVERSION_ROUND_TRIP_RTOL, IDENTITY_RTOL

VALUES = np.array([1e-3, 0.1234567891234, 0.5, 1.0, 3.0, 7.3, 60.0, 123.456, 1e4])
SPANS = Spans(pv_range_kw=(0.0, 120.0), out_range_pct=(0.0, 100.0))


@pytest.fixture(scope="module")
def model() -> HammersteinModel:
    return load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))


@pytest.fixture(scope="module")
def schedule(model: HammersteinModel) -> PIDSchedule:
    return tune_schedule(model, DesignSpec(ms=1.4), triac_range_pct=(28.0, 70.0))


def test_pid_table_has_the_issues_columns_and_reads_back_bit_for_bit(
    model: HammersteinModel, schedule: PIDSchedule, tmp_path: Path,
) -> None:
    path = write_pid_table(schedule, tmp_path / "pid_table.csv")
    lines = path.read_text().splitlines()
    comments = [line for line in lines if line.startswith("#")]
    assert lines[:len(comments)] == comments  # the header comments come first
    assert lines[len(comments)] == (
        "triac_pct,power_kw,gain_kw_per_pct,tau_s,dead_time_s,kc_pct_per_kw,ti_s,td_s,"
        "td_filter_s,setpoint_weight,ms,gain_margin,phase_margin_deg,crossover_rad_per_s,"
        "worst_ms_to_next")
    # they state the sampling time and the discretization of the integral and derivative filter
    assert "# ts_s: 2.0" in comments and "# discretization: worst" in comments
    text = "\n".join(comments)
    assert "sampling time 2 s" in text and "derivative filter" in text
    assert all(f"#   {f}:" in text for f in ("forward", "backward", "tustin"))
    assert "integral-dominant" in text  # the shipped heater's rule asks for Ti = Ts/2
    table = read_pid_table(path)
    assert table.schedule == schedule.table_schedule()
    assert table.ts_s == 2.0 and table.discretization == "worst"
    assert [v["worst_ms_to_next"] for v in table.values] == [
        r.worst_ms_to_next for r in schedule.rows]
    assert len(COLUMNS) == 15
    # stated for one form, the margins are that form's
    forward = read_pid_table(write_pid_table(schedule, tmp_path / "forward.csv", "forward"))
    assert forward.discretization == "forward"
    assert [v["ms"] for v in forward.values] == [
        r.margins_by_form["forward"].ms for r in schedule.rows]
    only_forward = tune_schedule(model, DesignSpec(ms=1.4, discretization="forward"),
                                 triac_range_pct=(28.0, 70.0), breakpoints_pct=(28.0, 70.0),
                                 add_breakpoints=False)
    with pytest.raises(PIDTuningError, match=r"designed for .*forward.*got 'worst'"):
        write_pid_table(only_forward, tmp_path / "x.csv", "worst")


@pytest.mark.parametrize("text, match", [
    ("triac_pct,kc\n", r"line 1: expected the pid_table.csv header"),
    (",".join(COLUMNS) + "\n", r"at least one row"),
    (",".join(COLUMNS) + "\n" + ",".join(["1"] * 5 + ["x"] + ["1"] * 9) + "\n",
     r"line 2, column 'kc_pct_per_kw': expected a number; got 'x'"),
    (",".join(COLUMNS) + "\n" + ",".join(["1"] * 5 + ["-1"] + ["1"] * 9) + "\n",
     r"line 2: PIDTuning.kc_pct_per_kw.*got -1.0"),
    ("# a comment\n# ts_s: 2\ntriac_pct,kc\n", r"line 3: expected the pid_table.csv header"),
    ("# discretization: euler\n" + ",".join(COLUMNS) + "\n",
     r"header comment 'discretization': discretization: expected one of .*got 'euler'"),
    ("# ts_s: -2\n" + ",".join(COLUMNS) + "\n", r"header comment 'ts_s': expected a time > 0"),
])
def test_a_bad_table_is_refused_with_file_line_and_column(tmp_path: Path, text: str,
                                                           match: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(PIDTuningError, match=match):
        read_pid_table(path)


def test_characterizer_inverts_f_to_a_tenth_of_a_percent(model: HammersteinModel) -> None:
    x, y = characterizer_points(model, (28.0, 70.0))
    coef = np.concatenate([[0.0], model.input_poly])
    s_nom = model.operating_point.triac_pct
    # x is the TRIAC value a linear f with the nominal slope would need for f(y - s_nom)
    np.testing.assert_allclose(
        x, s_nom + np.polynomial.polynomial.polyval(y - s_nom, coef) / model.input_poly[0],
        rtol=IDENTITY_RTOL, atol=0.0)
    assert np.all(np.diff(x) > 0)
    assert characterizer_error_pct(model, (28.0, 70.0)) < 0.1


def test_conversions_are_the_textbook_formulas() -> None:
    for x in VALUES:
        np.testing.assert_allclose(100.0 / gain_to_band_pct(x), x,
                                   rtol=CONVERSION_ROUND_TRIP_RTOL, atol=0.0)
        np.testing.assert_allclose(60.0 * seconds_to_minutes(x), x,
                                   rtol=CONVERSION_ROUND_TRIP_RTOL, atol=0.0)
        np.testing.assert_allclose(SPANS.dimensionless_gain(x) * 100.0 / 120.0, x,
                                   rtol=CONVERSION_ROUND_TRIP_RTOL, atol=0.0)
    assert gain_to_band_pct(2.0) == 50.0 and seconds_to_minutes(90.0) == 1.5
    for kc, ti, td in [(0.5, 2.0, 0.0), (1.7, 0.05, 0.01), (0.123, 12.5, 3.3)]:
        assert dependent_to_independent(kc, ti, td) == (kc, kc / ti, kc * td)


def test_vendor_forms_state_units_and_use_the_spans(schedule: PIDSchedule) -> None:
    row = schedule.rows[0].tuning
    deltav = vendor_table(schedule, "deltav", SPANS)
    assert deltav.header[1] == "GAIN [%/%]" and deltav.header[2] == "RESET [s/repeat]"
    assert deltav.rows[0][1] == pytest.approx(row.kc_pct_per_kw * 120.0 / 100.0, rel=IDENTITY_RTOL)
    honeywell = vendor_table(schedule, "honeywell", SPANS)
    assert honeywell.header[2] == "T1 [min]"
    assert honeywell.rows[0][2] == pytest.approx(row.ti_s / 60.0, rel=IDENTITY_RTOL)
    rockwell = vendor_table(schedule, "rockwell", SPANS)
    k = row.kc_pct_per_kw * 1.2
    assert rockwell.rows[0][1:7] == pytest.approx(
        (k, row.ti_s / 60, 0.0, k, k / (row.ti_s / 60), 0.0), rel=IDENTITY_RTOL)
    siemens = vendor_table(schedule, "siemens", SPANS)
    assert siemens.header[1] == "Gain [% output per kW]"
    assert any("CtrlParams" in n for n in siemens.notes)
    for table in (deltav, honeywell, rockwell, siemens):
        assert all("[" in h for h in table.header if h not in ("STRUCTURE", "CTLEQN"))
        assert table.header[-1] == "PB [%]"
        # each states its sampling time and discretization, in its file and in its notes
        assert table.discretization == VENDOR_DISCRETIZATION[table.form]
        text = vendor_csv_text(table)
        assert "# ts_s: 2.0\n" in text and f"# discretization: {table.discretization}\n" in text
        assert "Sampling time 2 s" in text and VENDOR_DISCRETIZATION_SOURCE[table.form] in text
        assert any("Discretization: " in n for n in table.notes)
        assert text.splitlines()[len(table.comments)].startswith('"from_triac_pct [%]"')


def test_a_vendor_form_needs_a_schedule_designed_for_its_discretization(
    model: HammersteinModel,
) -> None:
    forward = tune_schedule(model, DesignSpec(ms=1.4, discretization="forward"),
                            triac_range_pct=(28.0, 70.0), breakpoints_pct=(28.0, 70.0),
                            add_breakpoints=False)
    with pytest.raises(PIDTuningError, match=r"vendor form 'siemens'.*--discretization worst"):
        vendor_table(forward, "siemens", SPANS)


def test_vendor_forms_never_assume_spans(schedule: PIDSchedule) -> None:
    with pytest.raises(PIDTuningError, match=r"needs the spans .*\(--pv-range-kw LO HI"):
        vendor_table(schedule, "deltav", None)
    with pytest.raises(PIDTuningError, match=r"pv_range_kw: expected LO < HI.*got 50.0 50.0"):
        Spans(pv_range_kw=(50.0, 50.0), out_range_pct=(0.0, 100.0))
