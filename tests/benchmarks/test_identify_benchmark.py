"""The identification benchmark (`python -m benchmarks.identify`): section, report, SIPPY peer."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from benchmarks.identify import (
    RealLogRow,
    _nb_nf_nk,
    format_real_logs,
    main,
    run_sippy_comparison,
    write_benchmarks_section,
)
from sysid.data import Dataset, write_csv


def _synthetic_log(path: Path) -> Path:
    """A short Hammerstein log of the paper's eq. 27 shape: seven input steps, 3000 samples."""
    rng = np.random.default_rng(11)
    s = np.repeat([45.0, 50.0, 55.0, 60.0, 50.0, 40.0, 35.0, 45.0], 375)
    ds = s - 45.0
    w = 1.35 * ds - 0.0065 * ds**2
    dp = lfilter([0.0, 1.0, -0.991], [1.0, -0.99], w) + rng.normal(0.0, 0.01, s.size)
    write_csv(Dataset(time_s=2.0 * np.arange(s.size), triac_pct=s, power_kw=45.0 + dp, ts_s=2.0), path)
    return path


def test_benchmarks_section_is_replaced_in_place_and_other_sections_are_kept(tmp_path: Path) -> None:
    md = tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\n## Controller\n\nfast\n")
    write_benchmarks_section(md, "first numbers")
    write_benchmarks_section(md, "second numbers")
    text = md.read_text()
    assert text.count("## Identification pipeline") == 1
    assert "second numbers" in text and "first numbers" not in text
    assert "## Controller\n\nfast" in text
    md.write_text(text.replace("# Benchmarks\n", "# Benchmarks\n\n## Later section\n\nkept\n")
                  .replace("second numbers", "second numbers\n\n## After\n\nalso kept"))
    write_benchmarks_section(md, "third")
    text = md.read_text()
    assert "kept" in text and "also kept" in text and "third" in text and "second" not in text


def test_identify_benchmark_prints_stage_medians_and_records_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = _synthetic_log(tmp_path / "log.csv")
    md = tmp_path / "B.md"
    rc = main(["--data", str(data), "--repeats", "1", "--out", str(tmp_path / "bench"),
               "--benchmarks-md", str(md)])
    out, err = capsys.readouterr()
    assert rc == 0
    for needle in ("| Hammerstein route |", "**whole pipeline**", "Goal: whole pipeline under 2 s",
                   "cores (", "numpy", "scipy", "casadi", "Command: `python -m benchmarks.identify --data"):
        assert needle in out, needle
    assert "run 1 of 1" in err
    assert md.read_text().startswith("# Benchmarks\n\n## Identification pipeline\n\nCommand:")
    numbers = json.loads((tmp_path / "bench" / "bench_identify.json").read_text())
    assert numbers["repeats"] == 1 and numbers["total"]["median_s"] > 0
    stages = [s["name"] for s in numbers["stages"]]
    assert stages[0] == "operating point" and "Hammerstein route" in stages


def test_identify_benchmark_refuses_zero_repeats_with_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--repeats", "0"])
    assert exc.value.code == 2
    assert "expected an integer >= 1" in capsys.readouterr().err


def test_sippy_comparison_says_why_when_sippy_is_not_installed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    from sysid.data import read_csv
    from sysid.model import OperatingPoint

    monkeypatch.setitem(sys.modules, "sippy_unipi", None)  # makes the import raise ImportError
    data = read_csv(_synthetic_log(tmp_path / "log.csv"))
    result = run_sippy_comparison(data, operating_point=OperatingPoint(triac_pct=45.0, power_kw=45.0),
                                  ours={})
    assert not result.available and result.rows == ()
    assert "not installed" in result.reason


def test_sippy_arx_scores_like_our_least_squares_arx_on_the_same_data(tmp_path: Path) -> None:
    pytest.importorskip("sippy_unipi")
    from sysid.data import read_csv
    from sysid.linear import fit_arx
    from sysid.model import OperatingPoint

    op = OperatingPoint(triac_pct=45.0, power_kw=45.0)
    data = read_csv(_synthetic_log(tmp_path / "log.csv"))
    ours = fit_arx(data, operating_point=op, na=1, nb=2, nk=1).model.criteria
    result = run_sippy_comparison(data, operating_point=op, ours={})
    arx = next(r for r in result.rows if r.model == "ARX(1,2)")
    assert arx.sippy_v_kw2 is not None and arx.sippy_w_kw2 is not None
    # Both solve the same least-squares problem; they differ only in which first rows
    # enter the regression (SIPPY drops max(na, nb) rows), which moves V and W by < 0.1 %.
    np.testing.assert_allclose(arx.sippy_v_kw2, ours.ballistic_mse_kw2, rtol=1e-3, atol=0)
    np.testing.assert_allclose(arx.sippy_w_kw2, ours.one_step_mse_kw2, rtol=1e-3, atol=0)


def test_the_real_log_table_shows_each_models_structure_and_how_many_structures_are_near(
) -> None:
    rows = (RealLogRow(log="a.dat", n_samples=599, pipeline_s=4.2, final_name="oe_rest",
                       converged=True, v_model_json=0.11, v_reference=0.10, output_unit="degC",
                       structure=_nb_nf_nk(np.array([0.0, 0.0, 0.0, 1.0, 0.5, 0.2, 0.1]),
                                           np.array([1.0, -1.5, 0.7, -0.1])), n_near=6),)
    table = format_real_logs(rows)
    assert "| `a.dat` | 599 | 4.20 | oe_rest | 4, 3, 3 | 6 | yes | 0.11 degC^2 | 0.1 | 1.100 |" \
        in table
    assert "**met**" in table
