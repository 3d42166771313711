"""Identification figures: each writes a PNG whose every axis names its unit."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from czmpc.reports import identification_figures as figs

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
UNIT = re.compile(r"\[[^\]]+\]")
N = 200


def _signals() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    t = 2.0 * np.arange(N)
    s = np.repeat([40.0, 45.0, 50.0, 55.0], N // 4)
    p = 1.3 * (s - 45.0) + rng.normal(0.0, 0.02, N)
    return t, s, p


def _draw_each(tmp: Path) -> dict[str, Figure]:
    t, s, p = _signals()
    rng = np.random.default_rng(4)
    e = rng.normal(0.0, 0.02, N)
    lags = np.arange(0, 26)
    return {
        "dataset": figs.plot_dataset(t, s, p + 45.0, tmp / "d.png", marked_time_s=[100.0]),
        "dataset_dev": figs.plot_dataset(t, s - 45.0, p, tmp / "d7.png", deviation=True),
        "residuals": figs.plot_residuals(t, {"ARX(10,10)": e}, tmp / "r.png", marked_time_s=[50.0, 300.0]),
        "residuals2": figs.plot_residuals(t, {"ARMAX": e, "Hammerstein": 0.5 * e}, tmp / "r2.png"),
        "zoom": figs.plot_outlier_zoom(t, e, p, 200.0, tmp / "z.png"),
        "sims": figs.plot_simulations(t, p, {"ARX": p + 0.1, "OE": p - 0.1}, tmp / "s.png",
                                   input_pct=s - 45.0),
        "sims_no_input": figs.plot_simulations(t, p, {"final": p}, tmp / "s1.png"),
        "errors": figs.plot_simulation_errors(t, {"ARX": e, "OE": 2 * e}, tmp / "e.png"),
        "corr": figs.plot_correlations(lags, np.r_[1.0, e[:25]], 0.1, np.arange(-25, 26), e[:51], 0.1,
                                    tmp / "c.png"),
        "gain": figs.plot_gain_curve(np.linspace(-5, 20, 30), {"f'": np.linspace(1.4, 1.1, 30)},
                                  tmp / "g.png", step_ds_pct=[2.5, 7.5], step_gain_kw_per_pct=[1.35, 1.31]),
    }


@pytest.fixture(scope="module")
def drawn(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Figure]]:
    tmp = tmp_path_factory.mktemp("figs")
    return tmp, _draw_each(tmp)


def test_every_figure_function_writes_a_nonempty_png(drawn: tuple[Path, dict[str, Figure]]) -> None:
    tmp, figs = drawn
    pngs = sorted(tmp.glob("*.png"))
    assert len(pngs) == len(figs)
    for png in pngs:
        data = png.read_bytes()
        assert data.startswith(PNG_MAGIC), png.name
        assert 5_000 < len(data) < 400_000, f"{png.name}: {len(data)} bytes"


@pytest.mark.parametrize("name", ["dataset", "dataset_dev", "residuals", "residuals2", "zoom", "sims",
                                  "sims_no_input", "errors", "corr", "gain"])
def test_every_axis_of_every_figure_names_its_unit(
    drawn: tuple[Path, dict[str, Figure]], name: str
) -> None:
    fig = drawn[1][name]
    assert fig.get_suptitle(), "figure has a title"
    labelled_x = [ax for ax in fig.axes if UNIT.search(ax.get_xlabel())]
    assert labelled_x, "at least one x axis is labelled with a unit"
    for ax in fig.axes:
        assert UNIT.search(ax.get_ylabel()), f"y label {ax.get_ylabel()!r} lacks a [unit]"
        if not UNIT.search(ax.get_xlabel()):
            shared = ax.get_shared_x_axes()
            assert any(shared.joined(ax, other) for other in labelled_x), "x axis has no unit"
        assert ax.get_legend() is not None, "every panel has a legend"


def test_residual_panels_share_the_y_scale_so_sizes_compare(
    drawn: tuple[Path, dict[str, Figure]],
) -> None:
    upper, lower = drawn[1]["residuals2"].axes
    assert upper.get_ylim() == lower.get_ylim()


def test_correlation_legend_counts_the_lags_outside_the_band_without_lag_zero(tmp_path: Path) -> None:
    auto = np.array([1.0, 0.5, 0.01, -0.3, 0.0])  # lags 0..4: lags 1 and 3 outside 0.1
    cross = np.array([0.2, 0.0, 0.05])
    fig = figs.plot_correlations(np.arange(5), auto, 0.1, np.arange(-1, 2), cross, 0.1, tmp_path / "c.png")
    texts = [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
    assert "outside band (2 of 4)" in texts
    assert "outside band (1 of 3)" in texts


def test_simulation_error_legend_reports_the_mean_square_error(tmp_path: Path) -> None:
    t = 2.0 * np.arange(4)
    fig = figs.plot_simulation_errors(t, {"OE": [0.1, -0.1, 0.3, -0.3]}, tmp_path / "e.png")
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert texts == ["OE (V = 0.05 kW^2)"]  # mean of 0.01, 0.01, 0.09, 0.09


BAD_CALLS: list[tuple[str, Callable[[Path], object], str]] = [
    ("length", lambda p: figs.plot_dataset([0, 2, 4], [1, 2], [1, 2, 3], p), r"triac_pct must have 3"),
    ("empty", lambda p: figs.plot_residuals([0, 2], {}, p), r"at least one residual"),
    ("2-D", lambda p: figs.plot_simulations([[0, 2]], [1, 2], {"a": [1, 2]}, p), r"1-D"),
    ("window", lambda p: figs.plot_outlier_zoom([0, 2], [0, 0], [0, 0], 500.0, p), r"got none"),
    ("bound", lambda p: figs.plot_correlations([0, 1], [1, 0], -1.0, [0], [0], 0.1, p), r"bound"),
    ("steps", lambda p: figs.plot_gain_curve([0, 1], {"f": [1, 1]}, p, step_ds_pct=[1.0]), r"equal length"),
]


@pytest.mark.parametrize(("case", "call", "match"), BAD_CALLS, ids=[c[0] for c in BAD_CALLS])
def test_bad_arrays_raise_figure_error_and_write_nothing(
    tmp_path: Path, case: str, call: Callable[[Path], object], match: str
) -> None:
    path = tmp_path / f"{case}.png"
    with pytest.raises(figs.FigureError, match=match):
        call(path)
    assert not path.exists()


def test_labels_of_another_rig_reach_every_axis_and_legend(tmp_path: Path) -> None:
    t, s, p = _signals()
    labels = figs.axis_labels(input_name="input lamp", input_unit="V", output_name="output plate",
                              output_unit="degC", input_symbol="du", output_symbol="dy")
    ds = figs.plot_dataset(t, s, p, tmp_path / "d.png", labels=labels)
    assert [ax.get_ylabel() for ax in ds.axes] == ["output plate [degC]", "input lamp [V]"]
    err = figs.plot_simulation_errors(t, {"OE": p - p.mean()}, tmp_path / "e.png", labels=labels)
    assert err.axes[0].get_ylabel() == "simulation error [degC]"
    legend = err.axes[0].get_legend()
    assert legend is not None
    assert legend.get_texts()[0].get_text().endswith("degC^2)")
    gain = figs.plot_gain_curve(np.linspace(-2, 2, 9), {"f'": np.ones(9)}, tmp_path / "g.png",
                                labels=labels)
    assert (gain.axes[0].get_xlabel(), gain.axes[0].get_ylabel()) == (
        "input lamp deviation du [V]", "gain [degC/V]")
    # the defaults name the puller's signals and units
    defaults = figs.axis_labels()
    for key in ("power", "triac", "residual", "gain", "unit_out"):
        assert defaults[key] == figs.AXIS_LABELS[key]
