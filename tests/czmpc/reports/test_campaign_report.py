"""Campaign summary numbers against numpy on hand-made rows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from czmpc.reports.campaign_report import controller_summary, format_summary_markdown


def _row(controller: str, iae: float, sse: float, limits: int = 0, status: str = "ok") -> dict[str, object]:
    return {"run_id": f"{controller}|{iae}", "controller": controller, "status": status,
            "error": "" if status == "ok" else "RuntimeError: x", "iae_kw_s": iae,
            "max_abs_steady_state_error_kw": sse, "n_limit_violations": limits,
            "n_rate_violations": 0, "n_solver_failures": 1, "max_overshoot_kw": 0.1, "seed": 3}


def test_summary_statistics() -> None:
    iae = [1.0, 2.0, 3.0, 10.0]
    rows = [_row("a", x, 0.01 if x < 5 else 0.2, limits=int(x == 2.0)) for x in iae]
    rows.append(_row("a", math.nan, math.nan, status="error"))
    rows.append(_row("b", 4.0, 0.0))
    a, b = controller_summary(rows)
    assert (a["n_runs"], a["n_errors"], b["n_runs"]) == (5, 1, 1)
    assert a["iae_median_kw_s"] == pytest.approx(float(np.median(iae)))
    assert a["iae_p95_kw_s"] == pytest.approx(float(np.percentile(iae, 95)))
    assert (a["within_limits"], a["offset_free"]) == (0.75, 0.75)
    text = format_summary_markdown(rows, title="x")
    assert "## Failed runs" in text and "RuntimeError: x" in text


def _perturbed(gain: float, delay: int, iae: float, offset_free: bool = True) -> dict[str, object]:
    return {"controller": "mpc", "status": "ok", "scenario": "staircase", "seed": 1,
            "plant": f"perturbed g{gain:g} m1 d+{delay}", "gain_factor": gain,
            "time_constant_factor": 1.0, "extra_delay_steps": delay,
            "iae_changes_reachable_kw_s": iae, "offset_free": offset_free,
            "n_unreachable_changes": int(gain < 1.0)}


def test_the_heat_map_shows_the_iae_ratio_to_the_nominal_plant_per_delay() -> None:
    from czmpc.reports.campaign_report import plot_perturbation_heatmaps

    rows = [_perturbed(1.0, 0, 80.0), _perturbed(0.7, 0, 160.0), _perturbed(1.0, 1, 170.0),
            _perturbed(0.7, 1, 400.0, offset_free=False)]
    fig = plot_perturbation_heatmaps(rows)
    assert fig is not None
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert [ax.get_title() for ax in panels] == ["mpc, extra delay +0 samples",
                                                 "mpc, extra delay +1 sample"]
    texts = [[t.get_text() for t in ax.texts] for ax in panels]
    assert texts == [["2.00*", "1.00"], ["5.00*", "2.12"]]   # 160/80, 80/80; 400/80, 170/80
    crosses = [[ln for ln in ax.lines if ln.get_marker() == "x"] for ax in panels]
    assert [len(c) for c in crosses] == [0, 1]               # not offset-free: gain 0.7, +1
    assert plot_perturbation_heatmaps([{**rows[0], "plant": "model"}]) is None
