"""The shipped Monte-Carlo spec through the CLI, and its summary against the rows."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from czmpc.campaigns.campaign import load_spec
from czmpc.campaigns.runner import read_results
from czmpc.cli import main
from czmpc.reports.montecarlo_report import montecarlo_summary, rejection_summary, within_limits
from czmpc.shipped import shipped_path


def _row(controller: str, scenario: str, *, free: bool, limits: int = 0, iae: float = 1.0,
         status: str = "ok", plant: str = "sampled 0", rejected: int = 0) -> dict[str, Any]:
    return {"controller": controller, "scenario": scenario, "plant": plant, "status": status,
            "offset_free": free, "n_limit_violations": limits, "n_rate_violations": 0,
            "n_allowed_range_violations": 0, "iae_kw_s": iae, "n_rejected_draws": rejected,
            "plant_parameter_source": "covariance"}


def test_summary_counts_shares_per_controller_and_scenario() -> None:
    rows = [_row("a", "s", free=True, iae=1.0), _row("a", "s", free=False, iae=3.0),
            _row("a", "s", free=True, limits=2, iae=2.0), _row("a", "s", free=True, status="error"),
            _row("b", "s", free=True, iae=5.0), _row("a", "x", free=True, plant="model")]
    by = {(s["controller"], s["scenario"]): s for s in montecarlo_summary(rows)}
    assert set(by) == {("a", "s"), ("b", "s")}  # the model plant is no sampled plant
    a = by[("a", "s")]
    assert (a["n_runs"], a["n_errors"]) == (4, 1)
    assert a["offset_free"] == pytest.approx(2 / 3)
    assert a["within_limits"] == pytest.approx(2 / 3)
    assert a["both"] == pytest.approx(1 / 3)
    assert a["iae_median_kw_s"] == 2.0
    assert not within_limits(_row("a", "s", free=True, limits=1))


def test_rejections_are_counted_once_per_plant() -> None:
    rows = [_row("a", "s", free=True, plant="sampled 0", rejected=2),
            _row("b", "s", free=True, plant="sampled 0", rejected=2),
            _row("a", "s", free=True, plant="sampled 1", rejected=1)]
    assert rejection_summary(rows) == (2, 3, "covariance")


def test_shipped_spec_is_the_issue_s_study() -> None:
    spec = load_spec(shipped_path("campaign_montecarlo.toml"))
    assert [c.kind for c in spec.controllers] == ["mpc", "pi_gs", "linear_mpc"]
    assert [Path(s).stem for s in spec.scenarios] == ["staircase", "voltage_sag"]
    assert len(spec.expand()) == 3 * 200 * 2
    small = load_spec(shipped_path("campaign_montecarlo.toml"), samples=3, time_scale=0.1,
                      controllers=["mpc"])
    assert len(small.expand()) == 3 * 2 and small.time_scale == 0.1


def test_cli_runs_and_reports_a_small_montecarlo(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "mc"
    assert main(["campaign", "run", "campaign_montecarlo.toml", "--out", str(out),
                 "--samples", "2", "--time-scale", "0.02"]) == 0
    captured = capsys.readouterr()
    assert "12 runs (12 run now, 0 resumed), 0 crashed" in captured.out
    assert "standard errors" not in captured.err  # the shipped model carries its covariance
    rows = read_results(out)
    assert {r["plant"] for r in rows} == {"sampled 0", "sampled 1"}
    assert main(["campaign", "report", str(out)]) == 0
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "## Monte Carlo over the model's uncertainty" in report
    assert "**Warning:**" not in report
    assert (out / "montecarlo_iae.png").stat().st_size > 1000
    for s in montecarlo_summary(rows):
        mine = [r for r in rows if r["controller"] == s["controller"]
                and r["scenario"] == s["scenario"]]
        free = 100.0 * sum(bool(r["offset_free"]) for r in mine) / len(mine)
        line = re.search(rf"\| {re.escape(s['controller'])} \| {s['scenario']} \| 2 \| 0 \| "
                         r"([0-9.]+) \|", report)
        assert line is not None, s
        assert float(line.group(1)) == pytest.approx(free, abs=0.05)


@pytest.mark.parametrize("worst", ["0", "-1", "two"])
def test_worst_must_be_a_positive_count(worst: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["campaign", "run", "campaign_smoke.toml", "--out", str(tmp_path), "--worst", worst])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "czmpc: error:" in err and "--worst" in err and ">= 1" in err


def test_samples_on_a_spec_without_sampled_plants_exits_2(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["campaign", "run", "campaign_smoke.toml", "--out", str(tmp_path),
                 "--samples", "3"]) == 2
    assert "no [[plants]] kind = \"sampled\"" in capsys.readouterr().err
    assert main(["campaign", "run", "campaign_smoke.toml", "--out", str(tmp_path),
                 "--controllers", "lqr"]) == 2
    assert "no controller named ['lqr']" in capsys.readouterr().err
