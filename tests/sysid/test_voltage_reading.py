"""Reading the optional grid_voltage_factor column (issue 40): strict reader, historian, Parquet."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sysid.data import Dataset, read_csv, write_csv
from sysid.errors import DataFileError
from sysid.historian import LoadPolicy, load_log, read_log_csv, write_parquet

HEADER = "time_s,triac_pct,power_kw,grid_voltage_factor\n"
ROWS = ["0,40,40.0,1.0", "2,40,40.1,0.99", "4,45,46.0,1.01", "6,45,45.9,1.0",
        "8,50,51.0,0.98", "10,50,50.8,1.0"]


def _write(path: Path, rows: list[str], header: str = HEADER) -> Path:
    path.write_text(header + "\n".join(rows) + "\n")
    return path


def test_both_readers_read_the_column_and_a_log_without_it_has_none(tmp_path: Path) -> None:
    path = _write(tmp_path / "v.csv", ROWS)
    expected = [1.0, 0.99, 1.01, 1.0, 0.98, 1.0]
    np.testing.assert_array_equal(read_csv(path).grid_voltage_factor, expected)
    np.testing.assert_array_equal(load_log(path).data.grid_voltage_factor, expected)
    plain = _write(tmp_path / "p.csv", [r.rsplit(",", 1)[0] for r in ROWS],
                   "time_s,triac_pct,power_kw\n")
    assert read_csv(plain).grid_voltage_factor is None
    assert load_log(plain).data.grid_voltage_factor is None
    assert load_log(plain).data.preprocessing == ()   # the plain contract, as before


def test_write_csv_round_trips_the_column_bit_for_bit(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    v = 1.0 + 0.01 * rng.standard_normal(20)
    data = Dataset(time_s=2.0 * np.arange(20), triac_pct=np.repeat([40.0, 50.0], 10),
                   power_kw=45.0 + rng.standard_normal(20), ts_s=2.0, grid_voltage_factor=v)
    write_csv(data, tmp_path / "d.csv")
    np.testing.assert_array_equal(read_csv(tmp_path / "d.csv").grid_voltage_factor, v)


@pytest.mark.parametrize("cell, message", [("1.7", "0.5..1.5; got '1.7'"),
                                           ("0.2", "0.5..1.5; got '0.2'"),
                                           ("inf", "finite number; got 'inf'")])
def test_out_of_range_values_name_file_line_and_column(tmp_path: Path, cell: str,
                                                       message: str) -> None:
    rows = list(ROWS)
    rows[3] = rows[3].rsplit(",", 1)[0] + "," + cell
    path = _write(tmp_path / "bad.csv", rows)
    for read in (read_csv, load_log):
        with pytest.raises(DataFileError, match=message) as info:
            read(path)
        assert info.value.line == 5 and info.value.column == "grid_voltage_factor"
        assert path.name in str(info.value)


def test_the_column_through_a_mapping_and_the_strict_header_rule(tmp_path: Path) -> None:
    path = _write(tmp_path / "m.csv", ROWS, "t,u,P,U_rel\n")
    mapping = {"time_s": "t", "triac_pct": "u", "power_kw": "P", "grid_voltage_factor": "U_rel"}
    np.testing.assert_array_equal(read_csv(path, columns=mapping).grid_voltage_factor[:2],
                                  [1.0, 0.99])
    np.testing.assert_array_equal(
        load_log(path, columns=mapping).data.grid_voltage_factor[:2], [1.0, 0.99])
    del mapping["grid_voltage_factor"]
    assert read_csv(path, columns=mapping).grid_voltage_factor is None
    # the strict reader's header: the contract, optionally followed by the voltage only
    wrong = _write(tmp_path / "w.csv", ROWS, "grid_voltage_factor,time_s,triac_pct,power_kw\n")
    with pytest.raises(DataFileError, match="header must be exactly"):
        read_csv(wrong)


def test_gap_policies_treat_a_missing_voltage_as_the_other_columns(tmp_path: Path) -> None:
    rows = list(ROWS)
    rows[2] = rows[2].rsplit(",", 1)[0] + ",NaN"
    path = _write(tmp_path / "gap.csv", rows)
    with pytest.raises(DataFileError, match="missing value") as info:
        load_log(path)
    assert info.value.line == 4 and info.value.column == "grid_voltage_factor"
    filled = read_log_csv(path, policy=LoadPolicy(gaps="fill"))
    # linear interpolation between 0.99 and 1.0
    assert filled.data.grid_voltage_factor[2] == pytest.approx(0.995, abs=1e-15)
    assert filled.report.n_filled == 1 and filled.report.n_missing_cells == 1


def test_linear_resampling_interpolates_the_voltage(tmp_path: Path) -> None:
    rows = ["0,40,40.0,1.0", "2.6,40,40.1,0.98", "4,45,46.0,1.0", "6,45,45.9,1.0",
            "8,50,51.0,1.0"]
    loaded = read_log_csv(_write(tmp_path / "j.csv", rows),
                          policy=LoadPolicy(resample="linear", ts_s=2.0))
    # t = 2 lies 2/2.6 of the way from 1.0 to 0.98
    assert loaded.data.grid_voltage_factor[1] == pytest.approx(1.0 - 0.02 * 2 / 2.6, rel=1e-12)


def test_parquet_round_trips_the_column(tmp_path: Path) -> None:
    pytest.importorskip("pyarrow")
    data = read_csv(_write(tmp_path / "v.csv", ROWS))
    write_parquet(data, tmp_path / "v.parquet")
    back = load_log(tmp_path / "v.parquet").data
    np.testing.assert_array_equal(back.grid_voltage_factor, data.grid_voltage_factor)
