"""`czmpc identify` on logs as historians export them, and reports in the data's own terms.

Made from the real DaISy heater log (data/real): lamp voltage [V] in, plate temperature
[degC] out, rewritten as a European historian export (``;``, decimal comma, ISO time
stamps, a NaN cell, other column names).
"""

from __future__ import annotations

import json
import re
import shlex
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from czmpc.cli import main
from sysid.data import Dataset
from sysid.modelfile import load_model
from tests.sysid.reallogs import read_daisy_heating

REPO = Path(__file__).resolve().parents[3]
DAISY = REPO / "data" / "real" / "daisy_heating_system.dat"
COLUMNS = "time_s=Zeitstempel,triac_pct=Lampe,power_kw=Platte"
UNITS = ["--input-unit", "V", "--output-unit", "degC"]


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


#: A German export's time stamps (25.10.2026 01:00:00), read with --time-format.
GERMAN_STAMPS = "%d.%m.%Y %H:%M:%S"


def _european_export(path: Path, *, nan_line: int | None = 102, jitter_s: float = 0.0,
                     stamp_format: str | None = None) -> Path:
    """DaISy as a historian exports it: ISO stamps (or in `stamp_format`), ';', decimal
    comma, one NaN cell."""
    d: Dataset = read_daisy_heating(DAISY)
    t0 = datetime(2024, 5, 1, 12, 0, 0)
    jitter = np.zeros(d.n_samples)
    jitter[1::2] = jitter_s
    lines = ["Zeitstempel;Lampe;Platte"]
    for i, (t, u, y) in enumerate(zip(d.time_s, d.triac_pct, d.power_kw, strict=True)):
        when = t0 + timedelta(seconds=float(t) + jitter[i])
        stamp = (when.isoformat(timespec="milliseconds") if stamp_format is None
                 else f"{when:{stamp_format}}")
        plate = "NaN" if i + 2 == nan_line else repr(float(y)).replace(".", ",")
        lines.append(f"{stamp};{repr(float(u)).replace('.', ',')};{plate}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


# --- refusals: exit 2 with file, line, column and the option that accepts the data -------

def test_a_nan_is_refused_with_line_column_and_the_gaps_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _european_export(tmp_path / "export.csv")
    rc, _, err = _run(["identify", str(log), "--out", str(tmp_path / "o"), "--columns",
                       COLUMNS, *UNITS], capsys)
    assert rc == 2
    line = err.strip().splitlines()[-1]
    assert line.startswith("czmpc: error: ")
    assert "export.csv, line 102, column 'Platte'" in line
    assert "--gaps split" in line and "--gaps fill" in line
    assert "Traceback" not in err


def test_large_jitter_is_refused_naming_resample(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _european_export(tmp_path / "export.csv", nan_line=None, jitter_s=0.7)  # 35 % of Ts
    rc, _, err = _run(["identify", str(log), "--out", str(tmp_path / "o"), "--columns",
                       COLUMNS, "--ts-s", "2", *UNITS], capsys)
    assert rc == 2
    assert "export.csv, line 3, column 'Zeitstempel'" in err and "--resample linear" in err


def test_other_column_names_without_a_mapping_name_columns(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _european_export(tmp_path / "export.csv", nan_line=None)
    rc, _, err = _run(["identify", str(log), "--out", str(tmp_path / "o")], capsys)
    assert rc == 2
    assert "line 1" in err and "--columns time_s=NAME,triac_pct=NAME,power_kw=NAME" in err


@pytest.mark.parametrize("option", [["--sep", "|"], ["--decimal", ";"], ["--gaps", "drop"],
                                    ["--fill-max", "0"], ["--resample", "cubic"],
                                    ["--reference", "book"]],
                         ids=["sep", "decimal", "gaps", "fill-max", "resample", "reference"])
def test_bad_loading_options_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: list[str]
) -> None:
    with pytest.raises(SystemExit) as info:
        main(["identify", "x.csv", "--out", str(tmp_path / "o"), *option])
    err = capsys.readouterr().err
    assert info.value.code == 2
    assert f"czmpc: error: argument {option[0]}" in err and "Traceback" not in err


# --- a full run on the export: units, names, the reproducing command ---------------------

@pytest.mark.slow
def test_an_export_identifies_and_the_report_speaks_its_units_and_reruns_exactly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _european_export(tmp_path / "export.csv", stamp_format=GERMAN_STAMPS)
    out = tmp_path / "o"
    rc, _, err = _run(["identify", str(log), "--out", str(out), "--columns", COLUMNS, *UNITS,
                       "--gaps", "fill", "--fill-max", "2", "--orders", "paper",
                       "--time-format", GERMAN_STAMPS], capsys)
    assert rc == 0, err
    # the terminal says how the log was read and what was changed
    assert "czmpc: note: read" in err and "1 sample(s) filled" in err
    assert "separator ';', decimal ','" in err
    report = (out / "report.md").read_text(encoding="utf-8")
    # the data's units and names, not the puller's
    assert "V [degC^2]" in report and "[kW" not in report and "kW^2" not in report
    assert "input Lampe" in report and "output Platte" in report
    assert "paper V" not in report and "TRIAC" not in report and "heater power" not in report
    assert "--reference paper" in report        # says how to get the paper's columns
    assert "policy `--gaps fill` (runs of at most 2 filled)" in report
    model = load_model(out / "model.json")
    record = next(s for s in model.provenance.preprocessing if s["what"] == "load_log")
    assert record["n_filled"] == 1 and record["decimal"] == ","
    assert (model.effective_units.input, model.effective_units.output) == ("V", "degC")
    rc, shown, _ = _run(["show-model", str(out / "model.json")], capsys)
    assert rc == 0
    assert "signals: input u = column 'Lampe' [V], output y = column 'Platte' [degC]" in shown
    assert "f'(du) [degC/V]" in shown and "kW" not in shown

    # the "Produced by" line reruns the same run: exit 0 and the same model
    match = re.search(r"Produced by [^:]+: `([^`]+)`", report)
    assert match is not None
    words = shlex.split(match.group(1))
    assert words[:2] == ["czmpc", "identify"]
    for needed in ("--columns", "--input-unit", "--output-unit", "--gaps", "--fill-max",
                   "--orders", "--initial-state", "--resample", "--time-format"):
        assert needed in words
    first = json.loads((out / "model.json").read_text(encoding="utf-8"))
    (out / "model.json").unlink()
    rc, _, err = _run(words[1:], capsys)
    assert rc == 0, err
    again = load_model(out / "model.json")
    np.testing.assert_array_equal(again.a, model.a)
    np.testing.assert_array_equal(again.b, model.b)
    np.testing.assert_array_equal(again.input_poly, model.input_poly)
    second = json.loads((out / "model.json").read_text(encoding="utf-8"))
    for run in (first, second):
        run["provenance"].pop("created_utc")     # the only field that may differ
    assert second == first


@pytest.mark.slow
def test_a_skipped_hammerstein_is_said_on_the_terminal_with_the_right_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # one step 40 -> 50 % about the operating point 40 %: ds takes one level other than
    # 0, so a quadratic f (no constant term, two unknowns) cannot be determined
    n = 400
    s = np.where(np.arange(n) < 100, 40.0, 50.0)
    rng = np.random.default_rng(3)
    p = 30.0 + lfilter([0.0, 0.1], [1.0, -0.9], s - 40.0) + rng.normal(0.0, 0.01, n)
    log = tmp_path / "step.csv"
    log.write_text("time_s,triac_pct,power_kw\n" + "\n".join(
        f"{2.0 * k!r},{float(a)!r},{float(b)!r}" for k, (a, b) in enumerate(zip(s, p,
                                                                              strict=True)))
        + "\n", encoding="utf-8")
    out = tmp_path / "o"
    rc, _, err = _run(["identify", str(log), "--out", str(out), "--operating-point", "40", "30",
                       "--orders", "paper"], capsys)
    assert rc == 0, err
    model = load_model(out / "model.json")
    assert model.kind == "linear"
    note = next(line for line in err.splitlines() if "model.json holds" in line)
    assert note.startswith("czmpc: note: model.json holds the linear model")
    assert ">= 2 distinct levels other than the operating point (ds != 0); got 1" in note
    assert "3 distinct levels" not in err
    assert "czmpc: note: skipped: Hammerstein route skipped" in err
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "**Note:** model.json holds the linear model" in report


@pytest.mark.slow
def test_a_split_log_is_identified_on_all_its_segments_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _european_export(tmp_path / "export.csv", nan_line=202)   # sample 200 missing
    out = tmp_path / "o"
    rc, _, err = _run(["identify", str(log), "--out", str(out), "--columns", COLUMNS, *UNITS,
                       "--gaps", "split", "--orders", "paper"], capsys)
    assert rc == 0, err
    assert "split into 2 segments" in err
    assert ("the log holds 2 segments; all are used, each with its own initial state "
            "(800 samples: 0..398 s (200 samples); 402..1600 s (600 samples))") in err
    assert "identifies the longest" not in err
    model = load_model(out / "model.json")
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "**Note:** the log holds 2 segments" in report
    assert "| segments | 2, all used, each with its own initial state (starting at samples 0, " \
        "200) |" in report
    steps = [s["what"] for s in model.provenance.preprocessing]
    assert steps[0] == "load_log" and "segment" not in steps
    # the model was fitted to, and scored on, all 800 samples of both segments
    assert model.provenance.extra["n_segments"] == 2
    assert model.provenance.extra["n_samples"] == 800
    assert model.provenance.extra["segment_starts"] == [0, 200]
