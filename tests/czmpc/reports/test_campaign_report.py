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
