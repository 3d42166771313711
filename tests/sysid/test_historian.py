"""Historian-shaped logs (sysid.historian): every policy and message, on real logs mutated.

Each test starts from a real log of data/real (DaISy 99-001 heater, TCLab), writes a
mutated copy as a historian would export it (NaN, dropped rows, ISO time, ``;`` with
decimal comma, Parquet, a DataFrame, jitter) and checks the loaded data against the
clean log with an independent reference (the clean arrays, ``np.interp``).
"""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy.signal import lfilter

from sysid.data import Dataset, read_csv, write_csv
from sysid.errors import DataFileError
from sysid.hammerstein import fit_hammerstein_oe
from sysid.historian import (
    DEFAULT_FILL_MAX_SAMPLES,
    SNAP_MAX_JITTER,
    LoadPolicy,
    load_log,
    read_frame,
    read_log_csv,
    to_frame,
    write_parquet,
)
from tests.sysid.reallogs import read_daisy_heating
from tests.tolerances import (
    IDENTITY_RTOL,
    POLICY_FIT_GAIN_RTOL,
    POLICY_FIT_POLE_RTOL,
    POLICY_FIT_V_RATIO,
)

REPO = Path(__file__).resolve().parents[2]
DAISY = REPO / "data" / "real" / "daisy_heating_system.dat"
TCLAB = REPO / "data" / "real" / "tclab_mimo_steps_data.txt"
TCLAB_COLUMNS = {"time_s": "Time (sec)", "triac_pct": "Heater 1 (%)",
                 "power_kw": "Temperature 1 (degC)"}
#: DaISy's description: the steady input before the experiment (6 V); y0 = y[0].
DAISY_U0_V = 6.0


@pytest.fixture(scope="module")
def daisy() -> Dataset:
    return read_daisy_heating(DAISY)


def _rows(d: Dataset) -> list[str]:
    return [f"{float(t)!r},{float(u)!r},{float(y)!r}"
            for t, u, y in zip(d.time_s, d.triac_pct, d.power_kw, strict=True)]


def _write(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    return path


def _contract(tmp_path: Path, d: Dataset) -> Path:
    path = tmp_path / "clean.csv"
    write_csv(d, path)
    return path


def _with_cell(rows: list[str], i: int, column: int, text: str) -> list[str]:
    out = list(rows)
    cells = out[i].split(",")
    cells[column] = text
    out[i] = ",".join(cells)
    return out


# --- the strict case is unchanged --------------------------------------------------------

def test_a_contract_csv_loads_exactly_as_the_strict_reader(tmp_path: Path, daisy: Dataset) -> None:
    path = _contract(tmp_path, daisy)
    strict = read_csv(path)
    loaded = load_log(path)
    for name in ("time_s", "triac_pct", "power_kw"):
        np.testing.assert_array_equal(getattr(loaded.data, name), getattr(strict, name))
    assert loaded.data.ts_s == strict.ts_s and loaded.data.sha256 == strict.sha256
    assert loaded.data.preprocessing == ()         # nothing done, nothing recorded
    assert loaded.report.is_plain_contract and not loaded.report.changed_data


def test_a_short_clean_log_keeps_the_strict_minimum_not_the_segment_minimum(
    tmp_path: Path,
) -> None:
    path = _write(tmp_path / "short.csv", "time_s,triac_pct,power_kw",
                  ["0,45,45", "2,45,45.01", "4,46,44.99"])   # 3 samples < MIN_SEGMENT_SAMPLES
    np.testing.assert_array_equal(load_log(path).data.power_kw, read_csv(path).power_kw)


# --- NaN and empty cells -----------------------------------------------------------------

def _nan_rows(daisy: Dataset) -> list[str]:
    rows = _rows(daisy)
    rows = _with_cell(rows, 100, 2, "nan")          # one NaN output (line 102)
    rows = _with_cell(rows, 101, 2, "")             # one empty output (line 103)
    rows = _with_cell(rows, 400, 1, "NA")           # one missing input (line 402)
    return rows


def test_nan_is_refused_by_default_with_line_column_and_both_options(
    tmp_path: Path, daisy: Dataset
) -> None:
    path = _write(tmp_path / "nan.csv", "time_s,triac_pct,power_kw", _nan_rows(daisy))
    with pytest.raises(DataFileError) as info:
        load_log(path)
    err = info.value
    assert (err.line, err.column) == (102, "power_kw")
    assert err.path == str(path) and path.name in str(err)
    assert "--gaps split" in str(err) and "--gaps fill" in str(err)


def test_fill_interpolates_each_missing_value_between_its_neighbours(
    tmp_path: Path, daisy: Dataset
) -> None:
    path = _write(tmp_path / "nan.csv", "time_s,triac_pct,power_kw", _nan_rows(daisy))
    loaded = load_log(path, policy=LoadPolicy(gaps="fill"))
    d = loaded.data
    assert d.n_samples == daisy.n_samples and d.segment_starts == (0,)
    y, u = np.array(daisy.power_kw), np.array(daisy.triac_pct)
    # reference: np.interp over the samples that were kept, per signal
    keep_y = np.ones(y.size, dtype=bool)
    keep_y[[100, 101]] = False
    ref_y = np.interp(daisy.time_s, daisy.time_s[keep_y], y[keep_y])
    keep_u = np.ones(u.size, dtype=bool)
    keep_u[400] = False
    ref_u = np.interp(daisy.time_s, daisy.time_s[keep_u], u[keep_u])
    np.testing.assert_allclose(d.power_kw, ref_y, rtol=IDENTITY_RTOL)
    np.testing.assert_allclose(d.triac_pct, ref_u, rtol=IDENTITY_RTOL)
    assert loaded.report.n_missing_cells == 3 and loaded.report.n_filled == 3
    record = d.preprocessing[-1]
    assert record["what"] == "load_log" and record["n_filled"] == 3
    json.dumps(record)                               # goes into a JSON model file as is


def test_split_cuts_at_missing_values_into_segments(tmp_path: Path, daisy: Dataset) -> None:
    path = _write(tmp_path / "nan.csv", "time_s,triac_pct,power_kw", _nan_rows(daisy))
    loaded = load_log(path, policy=LoadPolicy(gaps="split"))
    d = loaded.data
    # samples 100, 101 and 400 are dropped: segments 0..99, 102..399, 401..800
    assert d.segment_starts == (0, 100, 398)
    assert d.n_samples == daisy.n_samples - 3 and loaded.report.n_dropped == 3
    kept = np.setdiff1d(np.arange(daisy.n_samples), [100, 101, 400])
    np.testing.assert_array_equal(d.power_kw, daisy.power_kw[kept])
    np.testing.assert_array_equal(d.time_s, daisy.time_s[kept])


# --- gaps in time (rows dropped) ---------------------------------------------------------

def test_a_gap_in_time_is_refused_then_filled_or_split(tmp_path: Path, daisy: Dataset) -> None:
    rows = _rows(daisy)
    short = rows[:250] + rows[253:]                      # 3 samples missing: t = 500..504 s
    path = _write(tmp_path / "gap.csv", "time_s,triac_pct,power_kw", short)
    with pytest.raises(DataFileError, match=r"3 missing sample\(s\) between 498 s") as info:
        load_log(path)
    assert info.value.line == 252 and info.value.column == "time_s"
    assert "--gaps split" in str(info.value) and "--gaps fill" in str(info.value)

    filled = load_log(path, policy=LoadPolicy(gaps="fill")).data
    np.testing.assert_allclose(filled.time_s, daisy.time_s, rtol=IDENTITY_RTOL)
    kept = np.r_[0:250, 253:daisy.n_samples]
    ref = np.interp(daisy.time_s, daisy.time_s[kept], daisy.power_kw[kept])
    np.testing.assert_allclose(filled.power_kw, ref, rtol=IDENTITY_RTOL)

    split = load_log(path, policy=LoadPolicy(gaps="split")).data
    assert split.segment_starts == (0, 250) and split.n_samples == daisy.n_samples - 3


def test_fill_splits_at_gaps_longer_than_its_limit(tmp_path: Path, daisy: Dataset) -> None:
    rows = _rows(daisy)
    n_gap = DEFAULT_FILL_MAX_SAMPLES + 1
    path = _write(tmp_path / "gap.csv", "time_s,triac_pct,power_kw",
                  rows[:300] + rows[300 + n_gap:])
    loaded = load_log(path, policy=LoadPolicy(gaps="fill"))
    assert loaded.data.segment_starts == (0, 300) and loaded.report.n_filled == 0
    wider = load_log(path, policy=LoadPolicy(gaps="fill", fill_max_samples=n_gap))
    assert wider.data.segment_starts == (0,) and wider.report.n_filled == n_gap


def test_segments_shorter_than_the_minimum_are_dropped(tmp_path: Path, daisy: Dataset) -> None:
    rows = _rows(daisy)
    rows = _with_cell(rows, 5, 2, "nan")                 # leaves a 5-sample head segment
    path = _write(tmp_path / "head.csv", "time_s,triac_pct,power_kw", rows)
    loaded = load_log(path, policy=LoadPolicy(gaps="split"))
    assert loaded.data.segment_starts == (0,)
    assert loaded.data.time_s[0] == daisy.time_s[6] and loaded.report.n_dropped == 6


# --- ISO-8601 time stamps ----------------------------------------------------------------

@pytest.mark.parametrize("zone", ["+02:00", "Z", ""], ids=["offset", "utc", "naive"])
def test_iso_time_stamps_give_seconds_from_the_first(
    tmp_path: Path, daisy: Dataset, zone: str
) -> None:
    t0 = datetime(2024, 3, 31, 0, 30, 0)
    rows = [f"{(t0 + timedelta(seconds=float(t))).isoformat(sep=' ')}{zone},{float(u)!r},"
            f"{float(y)!r}" for t, u, y in zip(daisy.time_s, daisy.triac_pct, daisy.power_kw,
                                               strict=True)]
    path = _write(tmp_path / "iso.csv", "stamp,lamp,plate", rows)
    loaded = load_log(path, columns={"time_s": "stamp", "triac_pct": "lamp",
                                     "power_kw": "plate"}, input_unit="V", output_unit="degC")
    np.testing.assert_allclose(loaded.data.time_s, daisy.time_s, rtol=IDENTITY_RTOL)
    np.testing.assert_array_equal(loaded.data.power_kw, daisy.power_kw)
    origin = datetime.fromisoformat(str(loaded.report.time_origin))
    expected = t0 - timedelta(hours=2) if zone == "+02:00" else t0
    assert origin.replace(tzinfo=None) == expected
    assert (origin.tzinfo is not None) == bool(zone)
    assert loaded.data.preprocessing[-1]["time_format"] == "timestamp"


def test_mixed_zoned_and_naive_stamps_and_garbage_are_refused(
    tmp_path: Path, daisy: Dataset
) -> None:
    rows = [f"2024-05-01T12:00:{2 * i:02d}+00:00,1.0,2.0" for i in range(20)]
    rows[7] = "2024-05-01T12:00:14,1.0,2.0"
    path = _write(tmp_path / "mixed.csv", "time_s,triac_pct,power_kw", rows)
    with pytest.raises(DataFileError, match="mix zoned and zone-less") as info:
        load_log(path)
    assert (info.value.line, info.value.column) == (9, "time_s")
    rows[7] = "yesterday noon,1.0,2.0"
    _write(path, "time_s,triac_pct,power_kw", rows)
    with pytest.raises(DataFileError, match="ISO-8601") as info:
        load_log(path)
    assert info.value.line == 9


def test_stamps_in_a_local_form_load_with_their_format(tmp_path: Path, daisy: Dataset) -> None:
    # a German export: day.month.year, semicolons, decimal commas
    t0 = datetime(2024, 3, 31, 0, 30, 0)
    rows = [f"{t0 + timedelta(seconds=float(t)):%d.%m.%Y %H:%M:%S};"
            + ";".join(repr(float(v)).replace(".", ",") for v in (u, y))
            for t, u, y in zip(daisy.time_s, daisy.triac_pct, daisy.power_kw, strict=True)]
    path = _write(tmp_path / "de.csv", "Zeit;Stellgrad;Temperatur", rows)
    columns = {"time_s": "Zeit", "triac_pct": "Stellgrad", "power_kw": "Temperatur"}
    with pytest.raises(DataFileError, match=r"got '31.03.2024 00:30:00' \(for another form "
                       r"pass --time-format") as info:
        load_log(path, columns=columns)
    assert info.value.line == 2
    loaded = load_log(path, columns=columns, time_format="%d.%m.%Y %H:%M:%S")
    np.testing.assert_allclose(loaded.data.time_s, daisy.time_s, rtol=IDENTITY_RTOL)
    np.testing.assert_array_equal(loaded.data.power_kw, daisy.power_kw)
    assert loaded.report.time_origin == "2024-03-31T00:30:00"
    rows[4] = "2024-03-31 00:30:08" + rows[4][rows[4].index(";"):]
    _write(path, "Zeit;Stellgrad;Temperatur", rows)
    with pytest.raises(DataFileError, match=r"in the format '%d.%m.%Y %H:%M:%S' \(--time-format\)"
                       r"; got '2024-03-31 00:30:08'") as info:
        load_log(path, columns=columns, time_format="%d.%m.%Y %H:%M:%S")
    assert info.value.line == 6
    parquet = tmp_path / "log.parquet"
    write_parquet(daisy, parquet)
    with pytest.raises(DataFileError, match="--time-format apply to CSV files"):
        load_log(parquet, time_format="%d.%m.%Y %H:%M:%S")


def test_the_end_of_daylight_saving_time_is_named_not_a_sort(tmp_path: Path) -> None:
    # Europe, 2024-10-27: local clocks go from 03:00 CEST back to 02:00 CET
    utc = [datetime(2024, 10, 27, 0, 40, tzinfo=UTC) + timedelta(seconds=20.0 * k)
           for k in range(120)]
    local = [t.astimezone(timezone(timedelta(hours=2 if t.hour < 1 else 1))) for t in utc]
    rows = [f"{t.isoformat()},{10.0 + (k > 60)!r},{float(k % 7)!r}" for k, t in enumerate(local)]
    zoned = _write(tmp_path / "zoned.csv", "time_s,triac_pct,power_kw", rows)
    loaded = load_log(zoned)
    np.testing.assert_array_equal(loaded.data.time_s, 20.0 * np.arange(120))
    naive = _write(tmp_path / "naive.csv", "time_s,triac_pct,power_kw",
                   [r.split("+")[0] + r[r.index(","):] for r in rows])
    with pytest.raises(DataFileError, match="daylight-saving time ends") as info:
        load_log(naive)
    assert info.value.line == 2 + 60          # 03:00:00 CEST, written 02:00:00
    assert "sort" not in str(info.value).replace("sorting would", "")
    rows[9] = rows[8]                          # a duplicated row is still told to sort
    with pytest.raises(DataFileError, match="sort the export by time"):
        load_log(_write(tmp_path / "twice.csv", "time_s,triac_pct,power_kw", rows))


def test_lines_before_the_header_are_named(
    tmp_path: Path, daisy: Dataset
) -> None:
    titled = tmp_path / "titled.csv"
    titled.write_text("Export of CZ12 heater\n\n" + "\n".join(
        ["time_s,triac_pct,power_kw", *_rows(daisy)]) + "\n", encoding="utf-8")
    with pytest.raises(DataFileError, match="line 3 has one.*delete them") as info:
        load_log(titled)
    assert info.value.line == 1


# --- separators and decimal comma --------------------------------------------------------

@pytest.mark.parametrize("sep", [";", "\t"], ids=["semicolon", "tab"])
def test_other_separators_and_decimal_comma_are_detected(
    tmp_path: Path, daisy: Dataset, sep: str
) -> None:
    rows = [sep.join(c.replace(".", ",") for c in r.split(",")) for r in _rows(daisy)]
    path = _write(tmp_path / "eu.csv", sep.join(["time_s", "triac_pct", "power_kw"]), rows)
    loaded = load_log(path)
    assert (loaded.report.separator, loaded.report.decimal) == (sep, ",")
    for name in ("time_s", "triac_pct", "power_kw"):
        np.testing.assert_array_equal(getattr(loaded.data, name), getattr(daisy, name))
    explicit = read_log_csv(path, sep=sep, decimal=",")
    np.testing.assert_array_equal(explicit.data.power_kw, daisy.power_kw)


def test_a_wrong_decimal_or_separator_is_named(tmp_path: Path, daisy: Dataset) -> None:
    rows = [";".join(c.replace(".", ",") for c in r.split(",")) for r in _rows(daisy)]
    path = _write(tmp_path / "eu.csv", "time_s;triac_pct;power_kw", rows)
    with pytest.raises(DataFileError, match="--decimal ,") as info:
        load_log(path, decimal=".")
    assert info.value.line == 2
    with pytest.raises(DataFileError, match="pass --sep"):
        load_log(path, sep=",")
    one = _write(tmp_path / "one.csv", "time_s", ["1", "2", "3"])
    with pytest.raises(DataFileError, match="pass --sep"):
        load_log(one)


# --- jitter ------------------------------------------------------------------------------

def test_real_tclab_jitter_is_snapped_onto_the_grid() -> None:
    loaded = load_log(TCLAB, columns=TCLAB_COLUMNS, input_unit="%", output_unit="degC")
    raw = np.loadtxt(TCLAB, delimiter=",", skiprows=1)
    d, rep = loaded.data, loaded.report
    # the logged intervals run 0.990..1.021 s: 2.1 % jitter, above the 1 % kept as logged
    assert 0.01 < rep.max_jitter < SNAP_MAX_JITTER and rep.n_snapped > 0
    ts = (raw[-1, 0] - raw[0, 0]) / (raw.shape[0] - 1)   # the mean period
    np.testing.assert_allclose(d.ts_s, ts, rtol=IDENTITY_RTOL)
    np.testing.assert_allclose(d.time_s, raw[0, 0] + ts * np.arange(raw.shape[0]),
                               rtol=IDENTITY_RTOL)
    np.testing.assert_array_equal(d.power_kw, raw[:, 3])     # values untouched
    assert "snapped" in rep.summary()


def test_large_jitter_is_refused_naming_resample_linear_which_interpolates(
    tmp_path: Path, daisy: Dataset, rng: np.random.Generator
) -> None:
    t = daisy.time_s + rng.uniform(-0.3, 0.3, daisy.n_samples) * daisy.ts_s   # +-30 % of Ts
    t[0] = 0.0
    rows = [f"{float(a)!r},{float(u)!r},{float(y)!r}"
            for a, u, y in zip(t, daisy.triac_pct, daisy.power_kw, strict=True)]
    path = _write(tmp_path / "jitter.csv", "time_s,triac_pct,power_kw", rows)
    with pytest.raises(DataFileError, match="--resample linear") as info:
        load_log(path, policy=LoadPolicy(ts_s=2.0))
    assert info.value.column == "time_s" and info.value.line is not None
    loaded = load_log(path, policy=LoadPolicy(ts_s=2.0, resample="linear"))
    grid = 2.0 * np.arange(loaded.data.n_samples)
    np.testing.assert_allclose(loaded.data.time_s, grid, rtol=IDENTITY_RTOL)
    np.testing.assert_allclose(loaded.data.power_kw, np.interp(grid, t, daisy.power_kw),
                               rtol=IDENTITY_RTOL)
    assert loaded.report.resampled and loaded.data.preprocessing[-1]["resampled"] is True


# --- Parquet and DataFrames --------------------------------------------------------------

def test_parquet_written_by_pyarrow_with_timestamps_and_nulls(
    tmp_path: Path, daisy: Dataset
) -> None:
    t0 = datetime(2024, 5, 1, 8, 0, tzinfo=UTC)
    stamps = [t0 + timedelta(seconds=float(t)) for t in daisy.time_s]
    plate = [None if i in (10, 11) else float(y) for i, y in enumerate(daisy.power_kw)]
    table = pa.table({"ts": pa.array(stamps, pa.timestamp("ms", tz="UTC")),
                      "lamp": pa.array(daisy.triac_pct), "plate": pa.array(plate)})
    path = tmp_path / "log.parquet"
    pq.write_table(table, path)
    columns = {"time_s": "ts", "triac_pct": "lamp", "power_kw": "plate"}
    with pytest.raises(DataFileError, match="--gaps split") as info:
        load_log(path, columns=columns)
    assert "row 11" in str(info.value) and info.value.column == "plate"
    loaded = load_log(path, columns=columns, policy=LoadPolicy(gaps="fill"))
    np.testing.assert_allclose(loaded.data.time_s, daisy.time_s, rtol=IDENTITY_RTOL)
    ref = np.interp(daisy.time_s, np.delete(daisy.time_s, [10, 11]),
                    np.delete(daisy.power_kw, [10, 11]))
    np.testing.assert_allclose(loaded.data.power_kw, ref, rtol=IDENTITY_RTOL)
    assert loaded.report.source_format == "parquet"
    assert loaded.report.time_origin == "2024-05-01T08:00:00+00:00"


def test_parquet_round_trip_keeps_values_and_segments(tmp_path: Path, daisy: Dataset) -> None:
    two = Dataset(time_s=np.r_[daisy.time_s[:300], daisy.time_s[310:]],
                  triac_pct=np.r_[daisy.triac_pct[:300], daisy.triac_pct[310:]],
                  power_kw=np.r_[daisy.power_kw[:300], daisy.power_kw[310:]],
                  ts_s=2.0, segment_starts=(0, 300))
    path = tmp_path / "two.parquet"
    write_parquet(two, path)
    back = load_log(path, policy=LoadPolicy(gaps="split")).data
    assert back.segment_starts == (0, 300)
    np.testing.assert_array_equal(back.power_kw, two.power_kw)


def test_dataframe_with_a_zoned_datetime_index(daisy: Dataset) -> None:
    pd = pytest.importorskip("pandas")
    index = pd.date_range("2024-05-01 08:00", periods=daisy.n_samples, freq="2s",
                          tz="Europe/Oslo", name="time")
    frame = pd.DataFrame({"lamp": daisy.triac_pct, "plate": daisy.power_kw}, index=index)
    frame.iloc[50, 1] = np.nan
    columns = {"time_s": "time", "triac_pct": "lamp", "power_kw": "plate"}
    with pytest.raises(DataFileError, match="row 51: a missing value"):
        Dataset.from_frame(frame, columns=columns)
    d = Dataset.from_frame(frame, columns=columns, policy=LoadPolicy(gaps="fill"),
                           input_unit="V", output_unit="degC")
    np.testing.assert_allclose(d.time_s, daisy.time_s, rtol=IDENTITY_RTOL)
    assert d.power_kw[50] == pytest.approx(0.5 * (daisy.power_kw[49] + daisy.power_kw[51]),
                                           rel=IDENTITY_RTOL)
    assert d.preprocessing[-1]["time_origin"] == "2024-05-01T06:00:00+00:00"   # 08:00 CEST
    back = to_frame(d)
    np.testing.assert_array_equal(back["power_kw"].to_numpy(), d.power_kw)
    again = read_frame(back).data
    np.testing.assert_array_equal(again.time_s, d.time_s)


def test_a_frame_without_a_time_column_is_refused(daisy: Dataset) -> None:
    pd = pytest.importorskip("pandas")
    frame = pd.DataFrame({"lamp": daisy.triac_pct, "plate": daisy.power_kw})  # RangeIndex
    with pytest.raises(DataFileError, match="neither a DatetimeIndex nor named 'time_s'"):
        Dataset.from_frame(frame, columns={"time_s": "time_s", "triac_pct": "lamp",
                                           "power_kw": "plate"})
    seconds = frame.set_index(pd.Index(daisy.time_s, name="t"))
    d = Dataset.from_frame(seconds, columns={"time_s": "t", "triac_pct": "lamp",
                                             "power_kw": "plate"})
    np.testing.assert_array_equal(d.time_s, daisy.time_s)


def test_without_pandas_the_message_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    import builtins

    real_import = builtins.__import__

    def no_pandas(name: str, *args: object, **kwargs: object) -> object:
        if name == "pandas":
            raise ImportError("No module named 'pandas'")
        return real_import(name, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(builtins, "__import__", no_pandas)
    with pytest.raises(ImportError, match=r"pip install 'czmpc\[pandas\]'"):
        Dataset.from_frame(object())


# --- policies and their record -----------------------------------------------------------

def test_bad_policies_are_refused() -> None:
    with pytest.raises(DataFileError, match="gaps must be one of"):
        LoadPolicy(gaps="drop")  # type: ignore[arg-type]
    with pytest.raises(DataFileError, match="resample must be one of"):
        LoadPolicy(resample="cubic")  # type: ignore[arg-type]
    with pytest.raises(DataFileError, match="fill_max_samples must be an int >= 1"):
        LoadPolicy(fill_max_samples=0)
    with pytest.raises(DataFileError, match=r"sampling_rtol must be in \[0, 0.25\)"):
        LoadPolicy(sampling_rtol=0.3)


# --- the model fitted through each policy is the clean log's --------------------------

def _fit(d: Dataset) -> dict[str, float]:
    y0 = float(d.power_kw[0])   # DaISy's description: at rest at (6 V, y[0]) before the log
    fit = fit_hammerstein_oe(np.asarray(d.power_kw) - y0, np.asarray(d.triac_pct) - DAISY_U0_V,
                             degree=2, nb=2, nf=1, nk=1, segment_starts=d.segment_starts)
    return fit.values()


def _v_on_clean(v: dict[str, float], clean: Dataset) -> float:
    """V of a fitted model on the clean record, simulated by lfilter from rest (reference)."""
    du = np.asarray(clean.triac_pct) - DAISY_U0_V
    w = v["d1"] * du + v["d2"] * du**2
    sim = lfilter([0.0, 1.0, v["b2"]], [1.0, v["f1"]], w)
    return float(np.mean((np.asarray(clean.power_kw) - clean.power_kw[0] - sim) ** 2))


def _static_gain(v: dict[str, float]) -> float:
    return v["d1"] * (1.0 + v["b2"]) / (1.0 + v["f1"])


@pytest.mark.slow
def test_models_from_split_and_fill_variants_match_the_clean_log(
    tmp_path: Path, daisy: Dataset
) -> None:
    rows = _rows(daisy)
    rows = _with_cell(rows, 150, 2, "nan")
    rows = rows[:500] + rows[503:]                       # plus a 3-sample gap
    path = _write(tmp_path / "holes.csv", "time_s,triac_pct,power_kw", rows)
    clean = _fit(daisy)
    split = load_log(path, policy=LoadPolicy(gaps="split")).data
    filled = load_log(path, policy=LoadPolicy(gaps="fill")).data
    assert split.n_segments == 3 and filled.n_segments == 1
    assert split.n_samples == daisy.n_samples - 4
    v_clean = _v_on_clean(clean, daisy)
    for variant in (split, filled):
        fitted = _fit(variant)
        assert _v_on_clean(fitted, daisy) <= POLICY_FIT_V_RATIO * v_clean
        assert fitted["f1"] == pytest.approx(clean["f1"], rel=POLICY_FIT_POLE_RTOL)
        assert _static_gain(fitted) == pytest.approx(_static_gain(clean),
                                                     rel=POLICY_FIT_GAIN_RTOL)
