"""`czmpc tune-pid`'s margins against python-control, from the model file, for every discretization.

The loop is written here from the model file's JSON (``A``, ``B``, ``input_poly``, the
operating point, ``ts_s``; no czmpc or sysid object) and from the three velocity laws a
block may run, ``du_k = Kc [e_k - e_{k-1} + (Ts/Ti) i_k]`` with ``i_k = e_{k-1}`` (forward
Euler), ``e_k`` (backward Euler) or ``(e_k + e_{k-1})/2`` (trapezoidal). python-control's
``stability_margins`` gives Ms, the gain and the phase margin; the table's rows must
match the worst of the three, and every form must keep Ms within the bound, at the
breakpoints and between them. Two plants: the shipped heater model, and a near-static
plant (the power jumps to ``f'`` one sample after a step of the input and sags by 5 %:
for the tuning rules a gain with 1.5 samples of dead time, Ts = 2 s), on which SIMC and
the ``ms`` rule ask for ``Ti < Ts``.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from czmpc.cli import main
from czmpc.shipped import HAMMERSTEIN_MODEL_JSON, shipped_path
from sysid.modelfile import load_model, save_model
from tests.tolerances import MARGIN_REFERENCE_RTOL

control = pytest.importorskip("control")

FORMS = ("forward", "backward", "tustin")
#: The issue's acceptance bound: Ms <= 1.4 asked, at most 5 % above it in any form.
MS_ACCEPTED = 1.47
#: Interior points checked between two breakpoints (both ends are checked too).
INTERIOR_POINTS = 3


def _near_static_model(tmp_path: Path) -> Path:
    """The shipped model with a fast, nearly cancelled lag: g q^-1 (1 - 0.905 q^-1)/(1 - 0.9 q^-1)."""
    shipped = load_model(shipped_path(HAMMERSTEIN_MODEL_JSON))
    model = shipped.with_updates(a=np.array([1.0, -0.9]), b=np.array([0.0, 1.0, -0.905]),
                                 c=np.array([1.0, -0.5]), covariance=None)
    path = tmp_path / "near_static.json"
    save_model(model, path)
    return path


@pytest.fixture(scope="module", params=["shipped", "near_static"])
def tuned(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
          ) -> tuple[dict[str, Any], Path]:
    tmp = tmp_path_factory.mktemp(request.param)
    model = (Path(shipped_path(HAMMERSTEIN_MODEL_JSON)) if request.param == "shipped"
             else _near_static_model(tmp))
    out = tmp / "out"
    assert main(["tune-pid", str(model), "--ms", "1.4", "--out", str(out), "--form", "deltav",
                 "--form", "siemens", "--pv-range-kw", "0", "100", "--out-range-pct", "0",
                 "100"]) == 0
    return json.loads(model.read_text()), out


def _read(path: Path) -> tuple[list[str], list[dict[str, float]]]:
    """Header comments and rows of a CSV written by tune-pid."""
    lines = path.read_text().splitlines()
    comments = [line for line in lines if line.startswith("#")]
    rows = [{k: float(v) for k, v in r.items()}
            for r in csv.DictReader(line for line in lines if not line.startswith("#"))]
    return comments, rows


def _slope(doc: dict[str, Any], s_pct: float) -> float:
    """f'(s - s_nom) from the file's input polynomial f(ds) = sum_i p_i ds^i."""
    ds = s_pct - doc["operating_point"]["triac_pct"]
    return sum(i * p * ds ** (i - 1) for i, p in enumerate(doc["input_poly"], start=1))


def _loop(doc: dict[str, Any], kc: float, ti_s: float, form: str, s_pct: float) -> Any:
    """L(z) = C(z) f'(s) B(z)/A(z) as a python-control transfer function."""
    ts = doc["ts_s"]
    r = ts / ti_s
    c_num = kc * np.array({"forward": [1.0, r - 1.0], "backward": [1.0 + r, -1.0],
                           "tustin": [1.0 + r / 2, r / 2 - 1.0]}[form])
    num = np.convolve(c_num, _slope(doc, s_pct) * np.asarray(doc["B"]))
    den = np.convolve([1.0, -1.0], np.asarray(doc["A"]))
    n = max(num.size, den.size)  # polynomials in z^-1 -> descending powers of z
    return control.tf(np.pad(num, (0, n - num.size)), np.pad(den, (0, n - den.size)), ts)


def _margins(loop: Any) -> tuple[float, float, float]:
    """(Ms, gain margin, phase margin [deg]) of a sampled loop."""
    gms, pms, sms, wpcs, _, _ = control.stability_margins(loop, returnall=True)
    # w = 0 is the integrator's pole, not a phase crossover; python-control leaves out the
    # Nyquist frequency, where L is real: a negative L there is one
    gains = [g for g, w in zip(gms, wpcs, strict=True) if w > 0]
    at_nyquist = complex(loop(-1.0))
    if at_nyquist.real < 0:
        gains.append(1.0 / abs(at_nyquist))
    pm = min(pms, key=abs) if len(pms) else math.nan
    return 1.0 / min(sms), min(gains, default=math.inf), float(pm)


def test_every_row_keeps_ms_in_every_discretization_at_and_between_breakpoints(
    tuned: tuple[dict[str, Any], Path],
) -> None:
    doc, out = tuned
    comments, rows = _read(out / "pid_table.csv")
    assert "# discretization: worst" in comments and f"# ts_s: {doc['ts_s']!r}" in comments
    # the default breakpoints include the top of the range: the last row holds at one input
    ends = [r["triac_pct"] for r in rows[1:]] + [rows[-1]["triac_pct"]]
    for row, nxt in zip(rows, ends, strict=True):
        assert row["td_s"] == 0.0  # a PI: the loops above hold no derivative
        kc, ti = row["kc_pct_per_kw"], row["ti_s"]
        assert ti >= doc["ts_s"]  # no integral time below the sampling time
        at_row = {f: _margins(_loop(doc, kc, ti, f, row["triac_pct"])) for f in FORMS}
        # the table's margins are the worst of the three forms
        rtol = MARGIN_REFERENCE_RTOL
        assert row["ms"] == pytest.approx(max(m[0] for m in at_row.values()), rel=rtol)
        assert row["gain_margin"] == pytest.approx(min(m[1] for m in at_row.values()), rel=rtol)
        assert row["phase_margin_deg"] == pytest.approx(
            min((m[2] for m in at_row.values()), key=abs), rel=rtol)
        between = [max(_margins(_loop(doc, kc, ti, f, float(s)))[0] for f in FORMS)
                   for s in np.linspace(row["triac_pct"], nxt, INTERIOR_POINTS + 2)]
        assert max(between) <= MS_ACCEPTED
        assert max(between) == pytest.approx(row["worst_ms_to_next"], rel=rtol)
        assert all(m[0] <= MS_ACCEPTED for m in at_row.values())


def test_the_gain_margin_is_the_factor_that_destabilises_the_loop(
    tuned: tuple[dict[str, Any], Path],
) -> None:
    doc, out = tuned
    _, rows = _read(out / "pid_table.csv")
    row = rows[len(rows) // 2]
    worst = min(FORMS, key=lambda f: _margins(_loop(doc, row["kc_pct_per_kw"], row["ti_s"], f,
                                                     row["triac_pct"]))[1])
    for factor, stable in ((1 - MARGIN_REFERENCE_RTOL, True), (1 + MARGIN_REFERENCE_RTOL, False)):
        loop = _loop(doc, row["kc_pct_per_kw"] * row["gain_margin"] * factor, row["ti_s"], worst,
                     row["triac_pct"])
        poles = control.poles(control.feedback(loop, 1))
        assert bool(np.all(np.abs(poles) < 1.0)) is stable


def test_an_integral_dominant_loop_is_said_so_with_its_integral_only_law(
    tuned: tuple[dict[str, Any], Path],
) -> None:
    # on both plants the rule asks for Ti below Ts: the table says so, and the integral-only
    # law u_k = u_{k-1} + Ki Ts e_k keeps the bound (one law: the same in every block)
    doc, out = tuned
    comments, _ = _read(out / "pid_table.csv")
    assert any("integral-dominant" in c for c in comments)
    assert "Integral-dominant loop" in (out / "report.md").read_text()
    law_comments, laws = _read(out / "sampled_integral.csv")
    assert f"# ts_s: {doc['ts_s']!r}" in law_comments
    ends = [r["triac_pct"] for r in laws[1:]] + [laws[-1]["triac_pct"]]
    for law, nxt in zip(laws, ends, strict=True):
        move = law["ki_pct_per_kw_s"] * doc["ts_s"]
        assert law["move_gain_pct_per_kw"] == pytest.approx(move, rel=1e-12)

        def loop(s: float, move: float = move) -> Any:
            # du_k = (Ki Ts) e_k: C(z) = Ki Ts / (1 - z^-1)
            num = np.convolve([move], _slope(doc, s) * np.asarray(doc["B"]))
            den = np.convolve([1.0, -1.0], np.asarray(doc["A"]))
            n = max(num.size, den.size)
            return control.tf(np.pad(num, (0, n - num.size)), np.pad(den, (0, n - den.size)),
                              doc["ts_s"])

        ms, _, pm = _margins(loop(law["triac_pct"]))
        assert law["ms"] == pytest.approx(ms, rel=MARGIN_REFERENCE_RTOL) and ms <= MS_ACCEPTED
        assert law["phase_margin_deg"] == pytest.approx(pm, rel=MARGIN_REFERENCE_RTOL)
        assert max(_margins(loop(float(s)))[0] for s in np.linspace(law["triac_pct"], nxt, 3)
                   ) <= MS_ACCEPTED


def test_every_vendor_file_states_its_discretization_and_sampling_time(
    tuned: tuple[dict[str, Any], Path],
) -> None:
    doc, out = tuned
    for form in ("deltav", "siemens"):
        comments = [line for line in (out / f"vendor_{form}.csv").read_text().splitlines()
                    if line.startswith("#")]
        assert f"# ts_s: {doc['ts_s']!r}" in comments and "# discretization: worst" in comments
        text = "\n".join(comments)
        assert "was not available" in text and "forward, backward and trapezoidal" in text
