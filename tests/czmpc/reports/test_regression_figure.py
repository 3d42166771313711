"""The regression-case figure drawn from plain arrays."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from czmpc.reports.regression_figure import plot_regression_case


def test_the_figure_draws_golden_new_their_difference_and_the_divergence(tmp_path: Path) -> None:
    t = 2.0 * np.arange(50)
    golden = {"time_s": t, "setpoint_kw": np.full(50, 45.0), "power_true_kw": np.full(50, 45.0),
              "triac_pct": np.full(50, 45.0)}
    new = {**golden, "power_true_kw": 45.0 + 0.01 * np.arange(50)}
    fig = plot_regression_case(golden, {"power_true_kw": 0.1, "triac_pct": 0.05}, new,
                               title="mpc/model/staircase/s7", path=tmp_path / "f.png",
                               divergence_time_s=22.0)
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    power, triac, diff = fig.axes
    assert power.get_title() == "mpc/model/staircase/s7"
    assert [ln.get_label() for ln in power.lines][:3] == ["setpoint", "golden", "new"]
    drawn = next(ln for ln in diff.lines if ln.get_label() == "new - golden")
    np.testing.assert_allclose(drawn.get_ydata(), 0.01 * np.arange(50), rtol=0, atol=1e-12)
    marks = [ln for ln in triac.lines if ln.get_label().startswith("first divergence")]
    assert len(marks) == 1 and list(marks[0].get_xdata()) == [22.0, 22.0]
