"""``czmpc design-test``: the CSV it writes, its summary, the prior-model path and errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from czmpc.cli import main
from czmpc.shipped import shipped_path
from sysid.modelfile import load_model
from sysid.polynomials import roots_z


def test_design_test_writes_time_and_triac_columns(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "test.csv"
    code = main(["design-test", "--ts-s", "2", "--range-pct", "10", "50", "--tau-s", "100",
                 "--duration-s", "20000", "--max-step-pct", "5", "--seed", "3", "--out", str(out)])
    assert code == 0
    assert out.read_text().splitlines()[0] == "time_s,triac_pct"
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 0], np.arange(10001) * 2.0)
    assert np.abs(np.diff(table[:, 1])).max() <= 5.0 + 1e-9
    assert table[:, 1].min() == 10.0 and table[:, 1].max() == 50.0
    text = capsys.readouterr().out
    assert "staircase levels [%]: 10, 15, 20, 25, 30, 35, 40, 45, 50" in text
    assert "GBN mean switching time T_sw = 100 s" in text


def test_design_test_takes_tau_from_a_prior_model(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    model_path = shipped_path("cz_heater_model.json")
    model = load_model(model_path)
    tau = max(-model.ts_s / math.log(abs(z)) for z in roots_z(model.a) if 0 < abs(z) < 1)
    out = tmp_path / "test.csv"
    code = main(["design-test", "--ts-s", "2", "--range-pct", "20", "60", "--prior", str(model_path),
                 "--duration-s", str(60 * tau), "--out", str(out)])
    assert code == 0
    assert f"(tau = {tau:g} s)" in capsys.readouterr().out


def test_design_test_too_short_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["design-test", "--ts-s", "2", "--range-pct", "10", "50", "--tau-s", "100",
                 "--duration-s", "1000", "--out", str(tmp_path / "t.csv")])
    assert code == 2
    assert "czmpc: error: duration_s = 1000 s is too short" in capsys.readouterr().err


def test_design_test_plot_draws_signal_holds_and_spectrum(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    import re

    from czmpc.reports.design_figure import plot_test_signal
    from sysid.design import ExcitationSpec, design_test_signal

    png = tmp_path / "test.png"
    code = main(["design-test", "--ts-s", "2", "--range-pct", "10", "50", "--tau-s", "100",
                 "--duration-s", "20000", "--max-step-pct", "5", "--out",
                 str(tmp_path / "test.csv"), "--plot", str(png)])
    assert code == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"wrote {png}" in capsys.readouterr().out
    spec = ExcitationSpec(ts_s=2.0, lo_pct=10.0, hi_pct=50.0, tau_s=100.0, duration_s=20000.0,
                          max_step_pct=5.0)
    signal = design_test_signal(spec, np.random.default_rng(3))
    fig = plot_test_signal(signal, tmp_path / "again.png")
    axes = fig.get_axes()
    assert len(axes) == 3
    for ax in axes:
        assert re.search(r"\[.+\]", ax.get_xlabel()) and re.search(r"\[.+\]", ax.get_ylabel())
    bandwidth = [ln for ln in axes[2].get_lines() if ln.get_label().startswith("plant bandwidth")]
    assert bandwidth and bandwidth[0].get_xdata()[0] == pytest.approx(0.01, rel=1e-12)
    # the staircase levels hold 4 tau = 400 s each
    holds = axes[1].collections[0].get_offsets()[:, 1]
    assert np.count_nonzero(np.isclose(holds, 4.0, rtol=1e-12)) >= 9


def test_the_cli_offers_every_kind_the_design_builds() -> None:
    from czmpc.cli._argtypes import TEST_SIGNAL_KINDS
    from sysid.design import KINDS

    assert TEST_SIGNAL_KINDS == KINDS


def test_design_test_multilevel_prints_its_levels_and_switching(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "test.csv"
    code = main(["design-test", "--ts-s", "2", "--range-pct", "35", "60", "--tau-s", "600",
                 "--duration-s", "7200", "--max-step-pct", "5", "--kind", "multilevel",
                 "--out", str(out)])
    assert code == 0
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert table.shape == (3601, 2) and np.abs(np.diff(table[:, 1])).max() <= 5.0 + 1e-9
    text = capsys.readouterr().out
    assert "levels [%]: 35, 41.25, 47.5, 53.75, 60, visited in shuffled rounds" in text  # degree 3
    assert ("multilevel mean switching time T_sw = 720 s (1.20 tau; holds drawn in 0.5 .. 1.5 "
            "T_sw); 1 round(s) of the levels in each half of the test") in text
