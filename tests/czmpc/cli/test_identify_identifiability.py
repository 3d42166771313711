"""`czmpc identify` refuses logs that carry no information about the input (exit 1, nothing
written), warns about unusual models (exit 0), and still identifies every real log."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from czmpc.cli import main
from czmpc.shipped import EXPERIMENT_CSV, shipped_path
from sysid.data import Dataset, read_csv, write_csv
from sysid.identifiability import (
    INFORMATION_P_VALUE,
    INPUT_STD_RTOL,
    SAMPLES_PER_PARAMETER,
    assess_data,
    assess_model,
    structure_before_fit,
)
from sysid.model import OperatingPoint
from sysid.modelfile import load_model
from sysid.pipeline import run_paper_pipeline
from tests.sysid.reallogs import read_cascaded_tanks, read_daisy_heating, read_tclab

REAL = Path(__file__).resolve().parents[3] / "data" / "real"


def _write(path: Path, s: np.ndarray, p: np.ndarray) -> Path:
    write_csv(Dataset(time_s=2.0 * np.arange(s.size), triac_pct=s, power_kw=p, ts_s=2.0), path)
    return path


def _steps(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return 45.0 + np.repeat(rng.uniform(-10.0, 10.0, n // 50 + 1), 50)[:n]


def _identify(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    rc = main(["identify", *argv])
    return rc, capsys.readouterr().err


def _refused(rc: int, err: str, out: Path, check_words: str) -> None:
    assert rc == 1, err
    assert "czmpc: error:" in err and "the data cannot support a model" in err
    assert check_words in err
    assert "czmpc design-test" in err or "--orders" in err
    assert "Traceback" not in err
    assert not (out / "model.json").exists()


def test_power_unrelated_to_the_input_exits_1_with_the_f_test_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(21)
    s = _steps(800, 21)
    p = 45.0 + lfilter([1.0], [1.0, -0.8], 0.2 * rng.standard_normal(s.size))
    out = tmp_path / "o"
    rc, err = _identify([str(_write(tmp_path / "noise.csv", s, p)), "--out", str(out),
                         "--orders", "paper"], capsys)
    _refused(rc, err, out, "information about the input: F-test")
    assert not out.exists()


def test_twenty_samples_exit_1_before_any_fit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = _steps(20, 22)[:20]
    s[::5] += 3.0
    p = 45.0 + 1.3 * (s - 45.0)
    out = tmp_path / "o"
    rc, err = _identify([str(_write(tmp_path / "short.csv", s, p)), "--out", str(out)], capsys)
    _refused(rc, err, out, "samples: 20 usable samples for the 3 parameters")
    assert f"at least {SAMPLES_PER_PARAMETER * 3} needed" in err


def test_a_log_too_short_for_the_given_orders_exits_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = _steps(100, 23)
    p = 45.0 + lfilter([0.0, 1.0], [1.0, -0.9], 1.3 * (s - 45.0))
    out = tmp_path / "o"
    rc, err = _identify([str(_write(tmp_path / "log.csv", s, p)), "--out", str(out),
                         "--orders", "4,3,2"], capsys)
    _refused(rc, err, out, "samples: 100 usable samples for the 11 parameters")


def test_a_constant_input_exits_1_with_every_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(24)
    s = np.full(600, 45.0)
    p = 45.0 + 0.1 * rng.standard_normal(600)
    out = tmp_path / "o"
    rc, err = _identify([str(_write(tmp_path / "flat.csv", s, p)), "--out", str(out)], capsys)
    _refused(rc, err, out, "input excitation: std(s)/max|s| = 0")
    assert "input levels: 1 distinct input value(s)" in err
    assert "persistent excitation" in err


def test_accept_unidentifiable_writes_the_model_and_records_the_override(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(21)
    s = _steps(800, 21)
    p = 45.0 + lfilter([1.0], [1.0, -0.8], 0.2 * rng.standard_normal(s.size))
    out = tmp_path / "o"
    rc, err = _identify([str(_write(tmp_path / "noise.csv", s, p)), "--out", str(out),
                         "--orders", "paper", "--accept-unidentifiable", "--allow-unconverged"],
                        capsys)
    assert rc == 0, err
    assert "czmpc: WARNING: refusal overridden (--accept-unidentifiable): information" in err
    extra = load_model(out / "model.json").provenance.extra
    assert extra["accepted_unidentifiable"] is True
    refused = [c for c in extra["identifiability"] if not c["passed"] and c["severity"] == "refusal"]
    assert [c["check"] for c in refused] == ["input_information"]
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "## Identifiability" in report and "**refused**" in report
    assert "--accept-unidentifiable" in report                 # the Produced-by line


def test_a_plant_with_negative_gain_exits_0_with_a_loud_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(25)
    s = _steps(1500, 25)
    ds = s - 45.0
    p = 45.0 + lfilter([0.0, 1.0, -0.95], [1.0, -0.97], -(0.8 * ds + 0.005 * ds**2)) \
        + 0.02 * rng.standard_normal(s.size)
    out = tmp_path / "o"
    rc, err = _identify([str(_write(tmp_path / "cooling.csv", s, p)), "--out", str(out),
                         "--orders", "paper", "--operating-point", "45", "45"], capsys)
    assert rc == 0, err
    assert "czmpc: WARNING: gain sign: static gain g = -" in err
    assert "refuses a model whose static gain" in err
    model = load_model(out / "model.json")
    checks = {c["check"]: c for c in model.provenance.extra["identifiability"]}
    assert checks["gain_sign"]["passed"] is False and checks["gain_sign"]["measured"] < 0
    assert checks["gain_significance"]["passed"] is True
    # truth: K = (1 - 0.95) / (1 - 0.97) = 5/3 times -(0.8 + 0.005 (lo + hi)) [kW/%]
    lo, hi = model.input_range_pct
    true_gain = -(5.0 / 3.0) * (0.8 + 0.005 * (lo - 45.0 + hi - 45.0))
    assert checks["gain_sign"]["measured"] == pytest.approx(true_gain, rel=0.05)
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "**warnings**" in report and "| gain_sign | warning |" in report
    assert json.loads((out / "model.json").read_text())["provenance"]["identifiability"]


def _real(name: str) -> tuple[Dataset, tuple[float, float] | None]:
    if name == "daisy":                  # DaISy: u = 6 V before the test, y[0] = 129.32 degC
        return read_daisy_heating(REAL / "daisy_heating_system.dat"), (6.0, 129.32)
    if name == "tclab":
        return read_tclab(REAL / "tclab_mimo_steps_data.txt"), None
    if name == "tanks":
        return read_cascaded_tanks(REAL / "cascaded_tanks_dataBenchmark.csv"), None
    return read_csv(shipped_path(EXPERIMENT_CSV)), None


#: Smallest margin of every refusal check measured on the real logs and the shipped
#: experiment with ``--orders auto`` (the CLI default), as a factor beyond its threshold:
#: input excitation >= 150x, input_information p <= 1e-9 (1e6 below 1e-3), samples >= 5x.
REAL_LOGS = ["daisy", "tclab", "tanks", "shipped"]


@pytest.mark.slow
@pytest.mark.parametrize("name", REAL_LOGS)
def test_every_real_log_and_the_shipped_experiment_still_identify(
        name: str, request: pytest.FixtureRequest) -> None:
    """The judgement `identify_to_directory` makes, on the pipeline it runs (no figures)."""
    data, op = _real(name)
    degree, nb, n_par, what = structure_before_fit("auto")
    before = assess_data(data, degree=degree, nb=nb, n_parameters=n_par, what=what)
    assert before.is_identifiable
    if name == "shipped":     # the same run as tests/sysid/test_structure.py's, shared
        result = request.getfixturevalue("shipped_pipeline")
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # non-convergence is reported in the result
            result = run_paper_pipeline(
                data, operating_point=None if op is None else OperatingPoint(
                    triac_pct=op[0], power_kw=op[1]), orders="auto")
    assert result.final is not None
    judged = before + assess_model(result.final.model, result.data)
    assert judged.is_identifiable, [c.message for c in judged.refusals]
    assert judged.check("input_excitation").measured >= 150 * INPUT_STD_RTOL
    assert judged.check("input_information").measured <= 1e-6 * INFORMATION_P_VALUE
    samples = judged.check("samples_per_parameter")
    assert samples.measured >= 5 * samples.threshold
    levels, pe = judged.check("input_levels"), judged.check("persistent_excitation")
    assert levels.measured >= levels.threshold + 1 and pe.measured >= pe.threshold
