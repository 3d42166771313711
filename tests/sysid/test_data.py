"""sysid.data: every bad input refused with file/line/column, through the API and the CLI.

Each bad file is tried twice: `read_csv` must raise `DataFileError` whose message and
attributes name the file, the 1-based line and the column; and ``czmpc inspect`` must
print ``czmpc: error: <the same message>`` to stderr and exit with code 2, without a
traceback.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from czmpc.cli import main
from sysid.data import Dataset, format_csv, read_csv, write_csv
from sysid.errors import DataFileError

GOOD_ROWS = "0,20,10.5\n2,20,10.6\n4,25,17.1\n6,25,16.9\n"
HEADER = "time_s,triac_pct,power_kw\n"


@pytest.mark.parametrize(
    ("name", "text", "line", "column", "message"),
    [
        ("missing_header_field.csv", "time_s,triac_pct\n0,20\n2,20\n4,20\n",
         1, "power_kw", r"header must contain 'power_kw'; got fields \['time_s', 'triac_pct'\]"),
        ("extra_header_field.csv", "time_s,triac_pct,power_kw,voltage\n0,20,10,230\n",
         1, "voltage", r"header must be exactly 'time_s,triac_pct,power_kw'; got extra "
                       r"field\(s\) \['voltage'\]"),
        ("duplicate_header_field.csv", "time_s,triac_pct,power_kw,power_kw\n0,20,10,10\n",
         1, "power_kw", r"header field 'power_kw' appears twice"),
        ("non_numeric.csv", HEADER + "0,20,10.5\n2,20,n/a\n4,20,10.4\n",
         3, "power_kw", r"expected a number; got 'n/a'"),
        ("empty_cell.csv", HEADER + "0,20,10.5\n2,,10.5\n4,20,10.4\n",
         3, "triac_pct", r"expected a number; got ''"),
        ("nan.csv", HEADER + "0,20,10.5\n2,NaN,10.5\n4,20,10.4\n",
         3, "triac_pct", r"expected a finite number; got 'NaN'"),
        ("inf.csv", HEADER + "0,20,10.5\n2,20,10.5\n4,20,inf\n",
         4, "power_kw", r"expected a finite number; got 'inf'"),
        ("overflow.csv", HEADER + "0,20,10.5\n2,20,1e999\n4,20,10.4\n",
         3, "power_kw", r"expected a finite number; got '1e999'"),
        ("time_not_increasing.csv", HEADER + "0,20,10.5\n2,20,10.5\n2,20,10.4\n4,20,10.4\n",
         4, "time_s", r"time must be strictly increasing; got 2 s after 2 s"),
        ("time_decreasing.csv", HEADER + "0,20,10.5\n2,20,10.5\n4,20,10.4\n1,20,10.4\n",
         5, "time_s", r"time must be strictly increasing; got 1 s after 4 s"),
        ("non_uniform.csv", HEADER + "0,20,10.5\n2,20,10.5\n4,20,10.4\n8,20,10.4\n10,20,10\n",
         5, "time_s", r"sampling must be uniform \(interval 2 s within 1 %\); got an interval "
                      r"of 4 s from 4 s to 8 s"),
        ("short_row.csv", HEADER + "0,20,10.5\n2,20\n4,20,10.4\n",
         3, None, r"expected 3 cells like the header; got 2"),
        ("long_row.csv", HEADER + "0,20,10.5\n2,20,10.5,\n4,20,10.4\n",
         3, None, r"expected 3 cells like the header; got 4"),
        ("blank_line.csv", HEADER + "0,20,10.5\n\n4,20,10.4\n",
         3, None, r"blank line; expected a row of numbers"),
        ("too_few_samples.csv", HEADER + "0,20,10.5\n2,20,10.5\n",
         None, None, r"expected at least 3 samples; got 2"),
        ("header_only.csv", HEADER, None, None, r"expected at least 3 samples; got 0"),
        ("empty.csv", "", None, None, r"the file is empty; expected a header"),
        ("whitespace_only.csv", "\n  \n", None, None, r"the file is empty"),
    ],
    ids=lambda v: v if isinstance(v, str) and v.endswith(".csv") else "",
)
def test_bad_file_is_refused_by_api_and_cli_with_file_line_and_column(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, text: str,
    line: int | None, column: str | None, message: str,
) -> None:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    # The message names the file (its path, or its name when the path is long).
    where = name + (f", line {line}" if line else "") + (f", column '{column}'" if column else "")
    expected = rf"{_escape(where)}: {message}"

    with pytest.raises(DataFileError, match=expected) as caught:
        read_csv(path)
    assert (caught.value.path, caught.value.line, caught.value.column) == (str(path), line, column)

    assert main(["inspect", str(path)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.startswith("czmpc: error: ") and f"{where}: " in err
    assert len(err.splitlines()) == 1 and "Traceback" not in err


def _escape(text: str) -> str:
    import re

    return re.escape(text)


def test_fewer_samples_than_min_samples_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "short_record.csv"
    path.write_text(HEADER + GOOD_ROWS, encoding="utf-8")
    with pytest.raises(DataFileError, match=r"short_record.csv: expected at least 10 "
                                            r"samples; got 4$"):
        read_csv(path, min_samples=10)
    assert read_csv(path, min_samples=4).n_samples == 4


def test_sampling_tolerance_and_nominal_sampling_time_are_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    path = tmp_path / "jitter.csv"
    path.write_text(HEADER + "0,20,10\n2,20,10\n4.1,20,10\n6,20,10\n", encoding="utf-8")
    with pytest.raises(DataFileError, match=r"line 4, column 'time_s': sampling must be uniform"):
        read_csv(path)
    assert read_csv(path, sampling_rtol=0.1).ts_s == 2.0
    assert main(["inspect", str(path), "--sampling-rtol", "0.1"]) == 0
    capsys.readouterr()
    with pytest.raises(DataFileError, match=r"line 3, column 'time_s': sampling must be uniform "
                                            r"\(interval 1 s"):
        read_csv(path, ts_s=1.0, sampling_rtol=0.1)
    assert main(["inspect", str(path), "--ts-s", "1", "--sampling-rtol", "0.1"]) == 2
    assert "line 3, column 'time_s'" in capsys.readouterr().err


def test_missing_file_is_an_os_error_and_exit_code_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    path = tmp_path / "nowhere.csv"
    with pytest.raises(OSError):
        read_csv(path)
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("czmpc: error: ") and "nowhere.csv" in err and "Traceback" not in err


def test_undecodable_bytes_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "latin1.csv"
    path.write_bytes(HEADER.encode() + b"0,20,10\n2,20,10\xb0\n4,20,10\n")
    # a degree sign written by Windows-1252: its byte, line and the fix are named
    with pytest.raises(DataFileError, match=r"expected UTF-8 text; got the byte 0xb0 at offset "
                       r"41 \(line 3\).*save the export as UTF-8"):
        read_csv(path)
    assert main(["inspect", str(path)]) == 2
    assert "expected UTF-8 text" in capsys.readouterr().err


def test_write_then_read_round_trips_bit_for_bit(tmp_path: Path,
                                                 rng: np.random.Generator) -> None:
    n = 500
    data = Dataset(time_s=np.arange(n) * 2.0, triac_pct=rng.uniform(0.0, 100.0, n),
                   power_kw=rng.normal(45.0, 10.0, n) * np.exp(rng.uniform(-30, 30, n)),
                   ts_s=2.0)
    path = tmp_path / "round_trip.csv"
    write_csv(data, path)
    again = read_csv(path)
    for name in ("time_s", "triac_pct", "power_kw"):
        assert np.array_equal(getattr(again, name), getattr(data, name)), name
    assert again.ts_s == data.ts_s
    assert path.read_bytes() == format_csv(data).encode()
    assert path.read_text(encoding="utf-8").splitlines()[0] == "time_s,triac_pct,power_kw"


def test_crlf_line_endings_and_a_bom_are_read(tmp_path: Path) -> None:
    path = tmp_path / "windows.csv"
    path.write_bytes(b"\xef\xbb\xbf" + (HEADER + GOOD_ROWS).replace("\n", "\r\n").encode())
    data = read_csv(path)
    assert np.array_equal(data.power_kw, [10.5, 10.6, 17.1, 16.9])


OTHER_RIG = "Zeit,heater_V,Temp_degC,comment\n0,2.0,300,a\n1,2.0,301,b\n2,4.0,301,c\n3,4.0,340,d\n"
OTHER_MAPPING = {"time_s": "Zeit", "triac_pct": "heater_V", "power_kw": "Temp_degC"}


def test_column_mapping_reads_a_log_of_another_rig(tmp_path: Path) -> None:
    path = tmp_path / "other_rig.csv"
    path.write_text(OTHER_RIG, encoding="utf-8")
    data = read_csv(path, columns=OTHER_MAPPING, input_unit="V", output_unit="degC")
    assert np.array_equal(data.triac_pct, [2.0, 2.0, 4.0, 4.0])
    assert np.array_equal(data.power_kw, [300.0, 301.0, 301.0, 340.0])
    assert (data.ts_s, data.input_unit, data.output_unit) == (1.0, "V", "degC")
    with pytest.raises(DataFileError, match=r"line 1, column 'time_s': header must contain"):
        read_csv(path)


@pytest.mark.parametrize(
    ("mapping", "match"),
    [
        ({"time_s": "Zeit", "triac_pct": "heater_V"}, r"must map exactly"),
        ({**OTHER_MAPPING, "speed": "comment"}, r"must map exactly"),
        ({**OTHER_MAPPING, "power_kw": "Temp_K"},
         r"line 1, column 'Temp_K': header must contain 'Temp_K' \(mapped to power_kw\)"),
        ({**OTHER_MAPPING, "triac_pct": "Zeit"}, r"map each name to a different column"),
    ],
    ids=["missing", "unknown", "absent-column", "same-column-twice"],
)
def test_bad_column_mappings_are_refused(tmp_path: Path, mapping: dict[str, str],
                                         match: str) -> None:
    path = tmp_path / "other_rig.csv"
    path.write_text(OTHER_RIG, encoding="utf-8")
    with pytest.raises(DataFileError, match=match):
        read_csv(path, columns=mapping)


def test_cli_column_mapping_reads_another_rig_and_names_mapped_columns_in_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    path = tmp_path / "other_rig.csv"
    path.write_text(OTHER_RIG, encoding="utf-8")
    columns = "time_s=Zeit,triac_pct=heater_V,power_kw=Temp_degC"
    assert main(["inspect", str(path), "--columns", columns, "--input-unit", "V",
                 "--output-unit", "degC"]) == 0
    out = capsys.readouterr().out
    assert "input range:    2 to 4 V" in out and "output range:   300 to 340 degC" in out
    assert "r [degC/V]" in out
    bad = tmp_path / "other_rig_bad.csv"
    bad.write_text(OTHER_RIG.replace("3,4.0,340,d", "3,4.0,hot,d"), encoding="utf-8")
    assert main(["inspect", str(bad), "--columns", columns]) == 2
    err = capsys.readouterr().err
    assert err.startswith("czmpc: error: ") and err.endswith(
        "other_rig_bad.csv, line 5, column 'Temp_degC': expected a number; got 'hot'\n")


@pytest.mark.parametrize(
    "columns",
    ["time_s=Zeit,triac_pct=heater_V", "time_s=Zeit,triac_pct=heater_V,power=Temp",
     "time_s=Zeit,time_s=Zeit,power_kw=Temp", "time_s:Zeit"],
    ids=["incomplete", "unknown-name", "twice", "no-equals"],
)
def test_cli_refuses_a_malformed_column_option_with_exit_code_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], columns: str,
) -> None:
    with pytest.raises(SystemExit) as caught:
        main(["inspect", str(tmp_path / "any.csv"), "--columns", columns])
    assert caught.value.code == 2
    err = capsys.readouterr().err
    assert "czmpc: error: argument --columns:" in err and "Traceback" not in err
