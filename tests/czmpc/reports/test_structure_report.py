"""The report's structure section: the true delay of a known plant, and V from rest by scipy."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from czmpc.reports.figure_style import FigureError
from czmpc.reports.structure_report import (
    GRID_ROWS,
    draw_structure_choice,
    plot_structure_choice,
    structure_section,
)
from sysid.rest_oe import RestOEFit, RestOESearch, search_oe_from_rest
from sysid.structure import select_structure

#: The plant: y = q^-3 (0.5 + 0.3 q^-1) / (1 - 0.9 q^-1) u, a delay of three samples.
TRUE_DELAY = 3
B_TRUE = np.array([0.0, 0.0, 0.0, 0.5, 0.3])
F_TRUE = np.array([1.0, -0.9])


@pytest.fixture(scope="module")
def known_plant() -> tuple[np.ndarray, np.ndarray]:
    """600 samples of random steps through the plant, from rest, noise 1 % of its span."""
    rng = np.random.default_rng(7)
    u = np.repeat(rng.uniform(-1.0, 1.0, 40), 15)
    u[:30] = 0.0                                         # at rest before the first move
    y = lfilter(B_TRUE, F_TRUE, u)
    return y + 0.01 * np.ptp(y) * rng.standard_normal(y.size), u


def _table_rows(text: str, heading: str) -> list[list[str]]:
    """Cells of the Markdown table that follows the paragraph starting with ``heading``."""
    block = text[text.index(heading):].split("\n\n")[1]
    return [[c.strip() for c in line.strip("|").split("|")] for line in block.splitlines()[2:]]


def test_the_section_finds_the_known_delay_and_lists_the_structures_within_ten_percent(
    known_plant: tuple[np.ndarray, np.ndarray],
) -> None:
    y, u = known_plant
    choice = select_structure([(y, u)])
    search = search_oe_from_rest(y, u)
    text = structure_section(choice, search, v_unit="kW^2", gain_unit="kW/%")
    assert f"**Delay: {TRUE_DELAY} sample(s).**" in text
    assert choice.chosen.nk == TRUE_DELAY
    rows = _table_rows(text, "**Linear OE from rest**")
    # every V from rest recomputed by scipy: zero state, rest at the first sample, burn-in
    # of the structures whose static gain B(1)/F(1) is at most 10 x ptp(y) / ptp(u)
    plausible = [f for f in search.candidates
                 if abs(np.sum(f.b) / np.sum(f.f)) <= 10.0 * np.ptp(y) / np.ptp(u)]
    v = [float(np.mean((y - y[0] - lfilter(f.b, f.f, u - u[0]))[f.burn_in_steps:] ** 2))
         for f in plausible]
    near = sorted(x for x in v if x <= 1.10 * min(v))
    assert len(rows) == len(near) >= 2                  # nested structures fit the truth too
    shown = [float(r[2]) for r in rows]
    np.testing.assert_allclose(shown, near, rtol=5e-4)  # 4 significant digits in the table
    assert sum(r[4] == "**chosen**" for r in rows) == 1
    chosen_row = next(r for r in rows if r[4] == "**chosen**")
    assert chosen_row[0] == f"{search.chosen.nb}, {search.chosen.nf}, {search.chosen.nk}"
    assert f"{len(rows)} of the {len(search.candidates)} structures lie within 10 %" in text
    # the search keeps a fit of admissible gain per structure when a start gives one; on
    # this record every structure has one (left-out structures: the tests below)
    left_out = len(search.candidates) - len(plausible)
    assert left_out == 0 and "static gain above" not in text
    grid = _table_rows(text, "**Orders on validation data**")
    chosen = [r for r in grid if "**chosen**" in r[5]]
    assert len(chosen) == 1 and float(chosen[0][4]) == 1.0
    assert chosen[0][0] == ", ".join(str(x) for x in choice.chosen.orders)
    ratios = [float(r[4]) for r in grid[:GRID_ROWS]]
    assert ratios == sorted(ratios)                     # the best by validation V first


def _fit(nb: int, v_rest: float, pole: float = 0.5) -> RestOEFit:
    return RestOEFit(nb=nb, nf=1, nk=0, b=np.ones(nb), f=np.array([1.0, -pole]),
                     v_rest=v_rest, burn_in_steps=10, start="arx", n_iterations=3,
                     converged=True)


def test_a_record_that_singles_out_its_structure_says_so() -> None:
    fits = (_fit(1, 1.0), _fit(2, 1.2), _fit(3, 2.0))
    search = RestOESearch(chosen=fits[0], candidates=fits, max_abs_gain=100.0)
    text = structure_section(None, search, v_unit="degC^2", gain_unit="degC/V")
    assert "Only the chosen of the 3 structures lies within 10 %" in text
    assert "static gain above" not in text
    assert len(_table_rows(text, "**Linear OE from rest**")) == 1
    assert "V from rest [degC^2]" in text
    assert [f.nb for f in search.near(0.25)] == [1, 2]


def test_near_and_admissible_leave_out_a_gain_the_record_cannot_hold() -> None:
    # z = 0.999: B(1)/F(1) = 3 / 0.001 = 3000, against gains of 2 and 4 for the others
    fits = (_fit(3, 0.5, pole=0.999), _fit(1, 1.0), _fit(2, 1.05))
    search = RestOESearch(chosen=fits[1], candidates=fits, max_abs_gain=10.0)
    assert [f.nb for f in search.admissible] == [1, 2]
    assert [f.nb for f in search.near()] == [1, 2]
    text = structure_section(None, search, v_unit="degC^2", gain_unit="degC/V")
    assert "1 structure(s) with a static gain above 10 degC/V (10 times" in text
    larger = RestOESearch(chosen=fits[0], candidates=fits, max_abs_gain=5000.0)
    assert [f.nb for f in larger.near()] == [3]         # 1.0 > 1.10 x 0.5
    every = RestOESearch(chosen=fits[0], candidates=fits[:1], max_abs_gain=10.0)
    assert every.admissible == fits[:1]                 # none plausible: all are kept


def test_no_search_no_section() -> None:
    assert structure_section(None, None, v_unit="kW^2", gain_unit="kW/%") == ""


def test_the_figure_marks_the_delay_and_each_searchs_choice_with_units(
    known_plant: tuple[np.ndarray, np.ndarray], tmp_path: Path,
) -> None:
    y, u = known_plant
    choice = select_structure([(y, u)])
    search = search_oe_from_rest(y, u)
    fig = draw_structure_choice(choice, search, tmp_path / "structure.png",
                                gain_unit="kW/%", v_unit="kW^2")
    assert (tmp_path / "structure.png").stat().st_size > 10_000
    upper, lower = fig.axes
    assert (upper.get_xlabel(), upper.get_ylabel()) == ("lag [samples]", "coefficient [kW/%]")
    assert (lower.get_xlabel(), lower.get_ylabel()) == ("parameters [-]", "V [kW^2]")
    assert any(re.search(rf"delay {TRUE_DELAY} sample", t.get_text())
               for t in upper.get_legend().get_texts())
    # the second search's ring sits on its chosen structure's V
    ring = lower.collections[3].get_offsets()[0]
    assert ring[1] == pytest.approx(search.chosen.v_rest)
    with pytest.raises(FigureError, match="chosen index 5"):
        plot_structure_choice([0, 1], [0.1, 0.2], [0.01, 0.01], 3.0, 1,
                              [("grid", [1, 2], [0.3, 0.2], 5)], tmp_path / "x.png",
                              gain_unit="kW/%", v_unit="kW^2")
