"""The paper's pipeline and ``czmpc identify`` on real logs of other rigs (data/real/), not ours.

With ``d2 = 0`` the Hammerstein-OE(nb=2, nf=1) of eq. 27 is exactly the linear OE(2,1),
so its ballistic V can never be worse: a property of the nesting that holds on any
data, checked here on three real rigs.

Issue 29's bar, on every real log: ``czmpc identify`` with its default options exits 0,
and the best model it writes (model.json first) simulates within 1.10 of the best linear
OE a multistart search finds. The reference is computed here, independently of sysid:
random stable starts refined by scipy's Levenberg-Marquardt over nb 1..4, nf 1..3 and
delays 0..3, every model simulated from rest at the first sample and scored after a
burn-in of a fifth of the record. Its values are recorded (`RECORDED_REFERENCE_V`, each
with the log's fingerprint) and three of them searched again in every run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import io
import itertools
import json
import re
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.signal import lfilter

from czmpc.cli import main
from czmpc.reports.identification import MAX_ZOOM_FIGURES
from sysid._arrays import clipped_samples
from sysid.data import Dataset, write_csv
from sysid.model import OperatingPoint
from sysid.modelfile import load_model
from sysid.pipeline import run_paper_pipeline
from sysid.rest_oe import search_oe_from_rest
from tests.conftest import once_per_run, run_cli
from tests.sysid.reallogs import (
    read_cascaded_tanks,
    read_daisy_exchanger,
    read_daisy_heating,
    read_tclab,
)

REAL = Path(__file__).resolve().parents[3] / "data" / "real"
#: Both fits stop at LM tolerances of about 1e-10 relative in cost; 1e-6 is far above.
NESTED_V_RTOL = 1e-6
#: Issue 29: the best model identify writes is within this of the multistart OE reference.
REFERENCE_V_RATIO = 1.10
#: Random stable starts per structure of the reference (the issue's own search used 24 on
#: one short log; here 48 structures x 12 starts per log: with 8 the TCLab optimum
#: 0.1086 degC^2 is missed, 0.1141 found).
N_REFERENCE_STARTS = 12
#: Share of each record at its start that is not scored (the unknown initial state).
BURN_IN_SHARE = 0.2

READERS = {
    "lamp": lambda: read_daisy_heating(REAL / "daisy_heating_system.dat"),
    "tclab": lambda: read_tclab(REAL / "tclab_mimo_steps_data.txt"),
    "tanks": lambda: read_cascaded_tanks(REAL / "cascaded_tanks_dataBenchmark.csv"),
    "exchanger": lambda: read_daisy_exchanger(REAL / "daisy_exchanger.dat"),
}

#: Issue 29, item 3: the short TCLab log (599 samples) with 5 % and 10 % of it cut from the
#: end. The model.json of each keeps the full log's structure, and scored on the full log
#: it errs by at most this factor over the full log's own model.json (measured 1.12, 1.17).
END_CUT_V_RATIO = 1.25
END_CUTS = {
    f"tclab_end{pct}": (lambda pct=pct: READERS["tclab"]().segment(
        0, 599 - int(pct / 100 * 599)))
    for pct in (5, 10)
}
#: The other real logs with 5 % and 10 % cut from their end. The structure of their
#: model.json does not hold there (tanks: nb, nf, nk 4, 3, 2 becomes 3, 3, 0 and 3, 2, 1;
#: the exchanger's Hammerstein 3, 3, 0 becomes 4, 1, 0 at 10 %): the structures within a
#: few per cent of each other's V are many, and which wins moves with the record (no
#: rule tried held them: parsimony margins of 2 to 20 %, BIC, one standard error over
#: 5 to 20 blocks). What holds is the model: scored on the full log, the cut log's
#: model.json errs by at most this factor over the full log's own (measured: lamp 1.00
#: and 1.00, tanks 1.08 and 1.29, exchanger 1.00 and 1.18).
OTHER_END_CUT_V_RATIO = 1.35
OTHER_END_CUTS = {
    f"{log}_end{pct}": (lambda log=log, pct=pct: READERS[log]().segment(
        0, READERS[log]().n_samples - int(pct / 100 * READERS[log]().n_samples)))
    for log in ("lamp", "tanks", "exchanger") for pct in (5, 10)
}
#: The same log with 5 % (29 samples) and 10 % (59) cut from the start: it then begins 19
#: and 49 samples after the 0 -> 100 % heater step, mid-transient, and no longer at rest.
#: The end cuts' bar (model.json within 1.25 of the full log's on the full log) is out of
#: reach there: no linear OE fitted to the cut record with its initial state and output
#: offset estimated (`_free_start_oe`, nb 1..3, nf 1..2, nk 0..3) holds within it, not
#: even the one of the 24 that does best on the full log (a choice only the full log can
#: make): measured 0.4155 and 1.120 degC^2, 3.8 and 10.3 times the full log's model.json
#: (0.1086); the one lowest on its own record (nb 3, nf 2, nk 0 on both) errs 12.29 and
#: 5.988 degC^2. Hammerstein fits of degree 2 and 3 (the same search with u^2, u^3
#: columns, nf up to 3, nk up to 2) are outside the bar too: best on the full log 1.091
#: and 9.246 (5 %), 1.229 and 0.2738 (10 %, 2.5 times). The cut records never show the
#: input at 0 %, the start's rest, and the plant's gain falls as it warms
#: (the full log's secant 0.605 degC/%, the cut records' local fits 0.48..0.53): what
#: the data leave open is the model's rest, not the estimator's choice. So identify warns
#: that such a log does not start at rest (`sysid.criteria.start_at_rest`) and says to log
#: from a steady state instead. The model.json identify writes from the cut logs errs
#: 2,063 and 1,424 degC^2 on the full log, with nb, nf, nk 3, 2, 0 and 4, 2, 0 against
#: the full log's 4, 3, 3: its choice of structure is not stable under a start cut (open).
START_CUT_V_RATIO = 1.25
START_CUTS = {
    f"tclab_start{pct}": (lambda pct=pct: READERS["tclab"]().segment(
        int(pct / 100 * 599), 599))
    for pct in (5, 10)
}


def _from_rest(b: np.ndarray, f: np.ndarray, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``y0 + B/F (u - u0)``, zero state: the model at rest at the first sample."""
    return y[0] + lfilter(b, f, u - u[0])


def _reference_v(y: np.ndarray, u: np.ndarray, burn: int, seed: int) -> float:
    """Lowest V from rest over OE(nb 1..4, nf 1..3, nk 0..3), multistart scipy LM.

    ``yhat = B/F du`` with ``du = u - u0``; its derivatives are ``du/F`` delayed for each
    ``b`` and ``-yhat/F`` delayed for each ``f`` (zero initial state throughout).
    """
    rng = np.random.default_rng(seed)
    target = y[burn:] - y[0]
    du = u - u[0]

    def delayed(x: np.ndarray, lag: int) -> np.ndarray:
        return np.concatenate([np.zeros(lag), x[:x.size - lag]])

    best = np.inf
    for nb, nf, nk in itertools.product(range(1, 5), range(1, 4), range(4)):
        def parts(theta: np.ndarray, nb: int = nb, nk: int = nk) -> tuple[np.ndarray, ...]:
            f = np.concatenate([[1.0], theta[nb:]])
            v = lfilter([1.0], f, du)
            sim = sum(theta[j] * delayed(v, nk + j) for j in range(nb))
            return f, v, np.asarray(sim)

        def errors(theta: np.ndarray) -> np.ndarray:
            return target - parts(theta)[2][burn:]

        def jacobian(theta: np.ndarray, nb: int = nb, nf: int = nf, nk: int = nk) -> np.ndarray:
            f, v, sim = parts(theta)
            w = lfilter([1.0], f, sim)
            cols = [delayed(v, nk + j) for j in range(nb)]
            cols += [-delayed(w, i) for i in range(1, nf + 1)]
            return -np.column_stack(cols)[burn:]

        for _ in range(N_REFERENCE_STARTS):
            # poles with time constants log-uniform from half a sample to a fifth of the
            # record, a complex pair half of the time; B by least squares for that F
            poles = np.exp(-1.0 / np.exp(rng.uniform(np.log(0.5), np.log(y.size / 5), nf)))
            poles = poles.astype(complex)
            if nf >= 2 and rng.random() < 0.5:
                poles[:2] = poles[0] * np.exp(np.array([1j, -1j]) * rng.uniform(0, np.pi / 2))
            f = np.real(np.poly(poles))
            v = lfilter([1.0], f, du)
            lags = np.column_stack([delayed(v, nk + j) for j in range(nb)])[burn:]
            b = np.linalg.lstsq(lags, target, rcond=None)[0]
            with np.errstate(all="ignore"):     # a trial step may leave the stable region
                sol = least_squares(errors, np.concatenate([b, f[1:]]), jac=jacobian,
                                    method="lm", xtol=1e-8, ftol=1e-8, max_nfev=50 * (nb + nf))
            if np.all(np.isfinite(sol.fun)) and np.max(np.abs(np.roots(
                    np.concatenate([[1.0], sol.x[nb:]])))) < 1.0:
                best = min(best, float(np.mean(sol.fun**2)))
    return best


def _written_v(path: Path, data: Dataset, burn: int) -> float:
    """V from rest after the burn-in of a written model file, read as plain JSON."""
    obj = json.loads(path.read_text(encoding="utf-8"))
    ds = data.triac_pct - obj["operating_point"]["triac_pct"]
    w = sum(c * ds ** (i + 1) for i, c in enumerate(obj["input_poly"]))
    with np.errstate(all="ignore"):
        err = data.power_kw - _from_rest(np.asarray(obj["B"]), np.asarray(obj["A"]), w,
                                         data.power_kw)
        v = float(np.mean(err[burn:] ** 2))
    return v if np.isfinite(v) else np.inf


def _assert_within_the_bar(path: Path, name: str) -> None:
    """The model file at ``path`` simulates the log ``name`` (of `BAR_LOGS`) within issue
    29's bar of its reference."""
    data = BAR_LOGS[name]()
    reference = _recorded_reference(name, data)
    v = _written_v(path, data, int(BURN_IN_SHARE * data.n_samples))
    assert v <= REFERENCE_V_RATIO * reference, (v, reference)


#: Issue 29's short records, as windows of the real logs: 250 or 400 samples in which the
#: process does not settle. Simulated from rest, a pole at z = 1 - 1e-9 fits such a window
#: best (a static gain 1e6..1e7 times the recorded one); identify chooses among gains at
#: most 10 times the recorded span ratio, and its model.json stays within the issue's bar.
#: Measured before that rule: model.json 409, 272, 151, 2.4 and 3.3 times the reference;
#: after it 1.00, 1.00, 1.00, 1.015 and 1.014. The unseen TCLab heater 2 log: 481 and
#: 0.64.
EXCERPTS = {
    f"{log}_{lo}_{hi}": (lambda log=log, lo=lo, hi=hi: READERS[log]().segment(lo, hi))
    for log, lo, hi in (("tclab", 0, 250), ("lamp", 550, 800), ("tanks", 774, 1024),
                        ("tanks", 624, 1024), ("exchanger", 1800, 2200))
} | {"tclab_heater2": lambda: read_tclab(REAL / "tclab_mimo_steps_data.txt", heater=2)}


def _held(data: Dataset, every: int) -> Dataset:
    """The log as a logger records a sensor that updates every ``every`` samples."""
    held = np.repeat(data.power_kw[::every], every)[:data.n_samples]
    return dataclasses.replace(data, power_kw=held)


#: The TCLab log as a logger that holds each temperature for three samples records it (a
#: historian polling faster than its sensor updates). The outlier search flags 75 steps of
#: the hold as level shifts of at most 4.0 standard errors: before the rule that a repair
#: needs 5, every one was subtracted, 75 zoom figures were drawn, and the 12 samples the
#: log starts at were warned as clipping.
HELD = {"tclab_held3": lambda: _held(READERS["tclab"](), 3)}


def _sampled_faster(data: Dataset, every: int) -> Dataset:
    """The log at ``every`` times its rate: the input held, the output interpolated."""
    time_s = data.time_s[0] + np.arange(data.n_samples * every) * data.ts_s / every
    return Dataset(time_s=time_s, triac_pct=np.repeat(data.triac_pct, every),
                   power_kw=np.interp(time_s, data.time_s, data.power_kw),
                   ts_s=data.ts_s / every)


#: The exchanger log at 4 times its rate (16 000 samples at 0.25 s). OE(4, 3, 0)'s only fit
#: from the ARX and SRIV starts had a static gain of -6031 degC per unit of normalised flow,
#: more than 10 times the recorded span ratio, so the structure was left out and
#: model.json was OE(4, 2, 0), at 1.17 times the reference. Preferring a fit of admissible
#: gain among the starts, and started also from the structures it contains, OE(4, 3, 0)
#: reaches 0.1714 degC^2 with a gain of -104: 0.99 times.
FASTER = {"exchanger_x4": lambda: _sampled_faster(READERS["exchanger"](), 4)}

#: Every log the bar is checked on, by name.
BAR_LOGS = {**READERS, **EXCERPTS, **HELD, **FASTER}

#: `_reference_v` of each of `BAR_LOGS` (seed 29, burn-in `BURN_IN_SHARE`), recorded on
#: 2026-11-29 with the sha256 (first 16 hex digits) of the log's output and input bytes.
#: The search is independent of sysid but costs about 140 s on a quiet core (the 16,000
#: samples of exchanger_x4 57 s), and the suite ran it on every run, so the bar reads
#: these; `test_the_recorded_references_are_what_the_multistart_search_finds` searches
#: three of them again, and a log whose bytes changed refuses its record. To record
#: again: ``python -c "from tests.czmpc.cli.test_identify_real_logs import
#: print_reference_table; print_reference_table()"``.
RECORDED_REFERENCE_V = {
    "lamp": ("4ff6c796f0140743", 387.73742902038185),
    "tclab": ("63afb772b797059b", 0.10856625254518897),
    "tanks": ("e2f85e962a0069f0", 1.3263320216541425),
    "exchanger": ("b0f58d21efd59ea2", 0.14214625281330087),
    "tclab_0_250": ("722717a9d9d66acd", 0.11181012074525079),
    "lamp_550_800": ("1aac03f956e01fd1", 2.279552668594361),
    "tanks_774_1024": ("e8819f6cc71ecf64", 0.09374520643139166),
    "tanks_624_1024": ("ae7bfe63ff6c8a46", 2.2480369892662764),
    "exchanger_1800_2200": ("a0488d671902a6a4", 5.622147388024684),
    "tclab_heater2": ("73e300329c368509", 1.1754115283613682),
    "tclab_held3": ("570bcf82d308acfc", 0.11806608467223591),
    "exchanger_x4": ("39af46ded5abdedd", 0.1731252913586743),
}
#: The recorded references searched again in every run (the three cheapest, 9 s).
RESEARCHED = ("lamp_550_800", "exchanger_1800_2200", "tanks_774_1024")
#: Between machines the search's floating point may differ in the last bits of BLAS's
#: sums; the LM then stops at the same optimum to about its ftol (1e-8), far below this.
RESEARCH_RTOL = 1e-6


def _fingerprint(data: Dataset) -> str:
    """The first 16 hex digits of the sha256 of the log's output and input bytes."""
    raw = (np.ascontiguousarray(data.power_kw, dtype=float).tobytes()
           + np.ascontiguousarray(data.triac_pct, dtype=float).tobytes())
    return hashlib.sha256(raw).hexdigest()[:16]


def _search_reference(data: Dataset) -> float:
    """`_reference_v` of a log as the bar uses it (seed 29, burn-in `BURN_IN_SHARE`)."""
    return _reference_v(data.power_kw, data.triac_pct, int(BURN_IN_SHARE * data.n_samples),
                        seed=29)


def _recorded_reference(name: str, data: Dataset) -> float:
    """The recorded `_reference_v` of the log ``name``, refused if its bytes changed."""
    fingerprint, v = RECORDED_REFERENCE_V[name]
    assert _fingerprint(data) == fingerprint, (
        f"the log {name} is not the one its reference was recorded on: record again "
        "(RECORDED_REFERENCE_V)")
    return v


def print_reference_table() -> None:
    """Search every log of `BAR_LOGS` and print `RECORDED_REFERENCE_V`'s entries."""
    for name, read in BAR_LOGS.items():
        data = read()
        print(f'    "{name}": ("{_fingerprint(data)}", {_search_reference(data)!r}),')


Identified = Callable[[str], tuple[int, str, Path]]


@pytest.fixture(scope="module")
def identified(tmp_path_factory: pytest.TempPathFactory, worker_id: str) -> Identified:
    """``czmpc identify LOG --out DIR`` with default options on a real log, once per run of
    the suite (`tests.conftest.once_per_run`): `make test` hands a log's tests to either
    worker (`tests.conftest._scope`), and a full log is needed by three groups, its own
    and its 5 % and 10 % end cuts."""
    @functools.cache
    def run(name: str) -> tuple[int, str, Path]:
        (code, err), folder = once_per_run(tmp_path_factory, worker_id, f"real_log_{name}",
                                           lambda folder: _identify(name, folder))
        return code, err, folder / "id"
    return run


def _identify(name: str, folder: Path) -> tuple[int, str]:
    """Write the log ``name`` to ``folder/log.csv``, identify it into ``folder/id``;
    return the exit code and stderr."""
    reading: list[str] = []
    if name == "lamp":   # as logged, through a column mapping and the units (no fit option)
        raw = np.loadtxt(REAL / "daisy_heating_system.dat")
        lines = ["t,u_V,y_degC"] + [f"{t:g},{u:g},{y:g}" for t, u, y in raw.tolist()]
        (folder / "log.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
        reading = ["--columns", "time_s=t,triac_pct=u_V,power_kw=y_degC",
                   "--input-unit", "V", "--output-unit", "degC"]
    else:
        write_csv({**READERS, **END_CUTS, **OTHER_END_CUTS, **START_CUTS, **EXCERPTS,
                   **HELD, **FASTER}[name](),
                  folder / "log.csv")
    return run_cli(["identify", str(folder / "log.csv"), "--out", str(folder / "id"), *reading])


@pytest.mark.slow
@pytest.mark.parametrize("name", list(READERS))
def test_identify_with_default_options_exits_0_within_ten_percent_of_the_multistart_oe(
    name: str, identified: Identified,
) -> None:
    code, err, out = identified(name)
    assert code == 0, err
    assert "czmpc: error" not in err
    data = READERS[name]()
    burn = int(BURN_IN_SHARE * data.n_samples)
    reference = _recorded_reference(name, data)
    v_model_json = _written_v(out / "model.json", data, burn)
    v_best = min([v_model_json] + [_written_v(p, data, burn)
                                   for p in sorted((out / "models").glob("*.json"))])
    assert v_model_json <= REFERENCE_V_RATIO * reference, (v_model_json, reference)
    assert v_best <= v_model_json


@pytest.mark.slow
@pytest.mark.parametrize("name", RESEARCHED)
def test_the_recorded_references_are_what_the_multistart_search_finds(name: str) -> None:
    data = BAR_LOGS[name]()
    assert _search_reference(data) == pytest.approx(_recorded_reference(name, data),
                                                    rel=RESEARCH_RTOL)


def test_every_log_of_the_bar_has_a_recorded_reference() -> None:
    assert set(RECORDED_REFERENCE_V) == set(BAR_LOGS)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(EXCERPTS))
def test_short_windows_and_the_unseen_heater_2_log_get_a_model_within_the_bar(
    name: str, identified: Identified,
) -> None:
    code, err, out = identified(name)
    assert code == 0, err
    data = EXCERPTS[name]()
    _assert_within_the_bar(out / "model.json", name)
    obj = json.loads((out / "model.json").read_text(encoding="utf-8"))
    gain = np.sum(obj["B"]) / np.sum(obj["A"]) * obj["input_poly"][0]
    assert abs(gain) <= 10.0 * np.ptp(data.power_kw) / np.ptp(data.triac_pct)


@pytest.mark.slow
def test_a_log_held_by_its_logger_is_not_repaired_step_by_step(identified: Identified) -> None:
    code, err, out = identified("tclab_held3")
    assert code == 0, err
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "| correct_level_shift |" not in report
    notes = [line for line in err.splitlines() if "not corrected" in line]
    assert len(notes) == 1 and "and 72 more not corrected" in notes[0], notes
    assert len(list((out / "figures").glob("fig04_zoom_*.png"))) == MAX_ZOOM_FIGURES
    assert _identifiability(out / "model.json")["output_clipping"]["passed"]
    _assert_within_the_bar(out / "model.json", "tclab_held3")


@pytest.mark.slow
def test_a_log_sampled_faster_gets_a_model_within_the_bar(identified: Identified) -> None:
    code, err, out = identified("exchanger_x4")
    assert code == 0, err
    _assert_within_the_bar(out / "model.json", "exchanger_x4")


@pytest.mark.slow
@pytest.mark.parametrize("name", [*READERS, *FASTER])
def test_no_oe_structure_from_rest_ends_worse_than_one_it_contains(name: str) -> None:
    # OE(nb, nf, nk) holds OE(nb - 1, nf, nk), OE(nb, nf - 1, nk) and OE(nb - 1, nf, nk + 1):
    # their models, padded with zeros, are its own, so its best V can only be lower
    data = {**READERS, **FASTER}[name]()
    search = search_oe_from_rest(data.power_kw, data.triac_pct)
    fits = {(f.nb, f.nf, f.nk): f for f in search.admissible}
    pairs = [(fit, sub) for (nb, nf, nk), fit in fits.items()
             for key in ((nb - 1, nf, nk), (nb, nf - 1, nk), (nb - 1, nf, nk + 1))
             if (sub := fits.get(key)) is not None]
    assert len(pairs) > 40
    worse = [((f.nb, f.nf, f.nk), f.v_rest, (g.nb, g.nf, g.nk), g.v_rest)
             for f, g in pairs if f.v_rest > g.v_rest * (1 + NESTED_V_RTOL)]
    assert not worse, worse


def _identifiability(path: Path) -> dict[str, dict[str, object]]:
    """A written model file's identifiability checks by name, read as plain JSON."""
    checks = json.loads(path.read_text(encoding="utf-8"))["provenance"]["identifiability"]
    return {c["check"]: c for c in checks}


def _structure(path: Path) -> tuple[int, int, int]:
    """``(nb, nf, nk)`` of a written model file: B's leading zeros are the delay."""
    obj = json.loads(path.read_text(encoding="utf-8"))
    nk = int(np.flatnonzero(obj["B"])[0])
    return len(obj["B"]) - nk, len(obj["A"]) - 1, nk


@pytest.mark.slow
@pytest.mark.parametrize("name", list(END_CUTS))
def test_the_short_logs_model_holds_when_its_end_is_cut(name: str, identified: Identified,
                                                        ) -> None:
    full = READERS["tclab"]()
    assert full.n_samples == 599
    burn = int(BURN_IN_SHARE * full.n_samples)
    code, err, out = identified(name)
    assert code == 0, err
    _, _, out_full = identified("tclab")
    assert _structure(out / "model.json") == _structure(out_full / "model.json")
    v_cut = _written_v(out / "model.json", full, burn)
    assert v_cut <= END_CUT_V_RATIO * _written_v(out_full / "model.json", full, burn)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(OTHER_END_CUTS))
def test_every_real_logs_model_holds_when_its_end_is_cut(name: str, identified: Identified,
                                                         ) -> None:
    log = name.rsplit("_end", 1)[0]
    full = READERS[log]()
    burn = int(BURN_IN_SHARE * full.n_samples)
    code, err, out = identified(name)
    assert code == 0, err
    v_full = _written_v(identified(log)[2] / "model.json", full, burn)
    assert _written_v(out / "model.json", full, burn) <= OTHER_END_CUT_V_RATIO * v_full


def _free_start_oe(y: np.ndarray, u: np.ndarray, nb: int, nf: int, nk: int,
                   rng: np.random.Generator) -> tuple[float, np.ndarray, np.ndarray] | None:
    """Lowest-V OE on a record with its initial state and output offset estimated.

    ``y = c + B/F u + sum_i x_i (1/F) pulse_i``: for a given ``F`` the model is linear in
    ``B``, the offset ``c`` and the transients ``x`` of the first ``max(nf, nk+nb-1)``
    samples (any initial state), which least squares eliminates (variable projection);
    scipy's LM searches ``F`` from random stable starts. Returns ``(V, B, F)``.
    """
    n, n_state = y.size, max(nf, nk + nb - 1)
    pulses = np.zeros((n, n_state))
    pulses[np.arange(n_state), np.arange(n_state)] = 1.0

    def columns(f_tail: np.ndarray) -> np.ndarray:
        f = np.concatenate([[1.0], f_tail])
        v = lfilter([1.0], f, u)
        lags = [np.concatenate([np.zeros(nk + j), v[:n - nk - j]]) for j in range(nb)]
        return np.column_stack([*lags, lfilter([1.0], f, pulses, axis=0), np.ones(n)])

    def errors(f_tail: np.ndarray) -> np.ndarray:
        x = columns(f_tail)
        if not np.all(np.isfinite(x)) or np.max(np.abs(x)) > 1e12:
            return np.full(n, 1e6)                # an unstable trial: a flat high cost
        return y - x @ np.linalg.lstsq(x, y, rcond=None)[0]

    best = None
    for _ in range(N_REFERENCE_STARTS):
        poles = np.exp(-1.0 / np.exp(rng.uniform(np.log(0.5), np.log(n / 2), nf)))
        with np.errstate(all="ignore"):
            sol = least_squares(errors, np.poly(poles)[1:], method="lm", xtol=1e-10,
                                ftol=1e-10)
        f = np.concatenate([[1.0], sol.x])
        v = float(np.mean(sol.fun ** 2))
        if np.max(np.abs(np.roots(f))) < 1.0 and (best is None or v < best[0]):
            b = np.linalg.lstsq(columns(sol.x), y, rcond=None)[0][:nb]
            best = (v, np.concatenate([np.zeros(nk), b]), f)
    return best


@pytest.mark.slow
@pytest.mark.parametrize("name", list(START_CUTS))
def test_no_oe_fitted_on_a_log_cut_at_its_start_holds_on_the_full_log(
    name: str, identified: Identified,
) -> None:
    full = READERS["tclab"]()
    burn = int(BURN_IN_SHARE * full.n_samples)
    _, _, out_full = identified("tclab")
    bar = START_CUT_V_RATIO * _written_v(out_full / "model.json", full, burn)
    cut = START_CUTS[name]()
    rng = np.random.default_rng(29)
    on_full = []
    for nb, nf, nk in itertools.product(range(1, 4), range(1, 3), range(4)):
        fit = _free_start_oe(cut.power_kw, cut.triac_pct, nb, nf, nk, rng)
        if fit is not None:
            err = full.power_kw - _from_rest(fit[1], fit[2], full.triac_pct, full.power_kw)
            on_full.append(float(np.mean(err[burn:] ** 2)))
    assert len(on_full) >= 20
    assert min(on_full) > bar, (min(on_full), bar)


#: The real logs that do not start at rest: the TCLab log cut at its start, and DaISy's
#: lamp log, whose input holds 6 V for its first 200 samples while the plate's temperature
#: climbs 40.6 degC (35 % of its span). The tanks' input moves at once (not judged).
NOT_AT_REST = {*START_CUTS, "lamp"}


@pytest.mark.slow
@pytest.mark.parametrize("name", [*READERS, *END_CUTS, *START_CUTS])
def test_identify_says_when_a_log_does_not_start_at_rest(name: str, identified: Identified,
                                                         ) -> None:
    code, err, out = identified(name)
    assert code == 0, err
    checks = _identifiability(out / "model.json")
    report = (out / "report.md").read_text(encoding="utf-8")
    at_rest = name not in NOT_AT_REST
    assert checks["start_at_rest"]["passed"] is at_rest
    assert ("czmpc: WARNING: start at rest" in err) is not at_rest
    assert ("| start_at_rest | warning |" in report) is not at_rest
    if not at_rest:
        assert "log from a steady state before the first input change" in err


@pytest.mark.slow
@pytest.mark.parametrize("name", list(READERS))
def test_identify_says_when_the_output_clips(name: str, identified: Identified) -> None:
    # the cascaded tanks overflow at 10 V: 47 samples in runs at that maximum
    code, err, out = identified(name)
    assert code == 0, err
    checks = _identifiability(out / "model.json")
    clips = name == "tanks"
    assert checks["output_clipping"]["passed"] is not clips
    assert checks["output_clipping"]["measured"] == (47 if clips else 0)
    assert ("czmpc: WARNING: output clipping: 47 sample(s)" in err) is clips
    report = (out / "report.md").read_text(encoding="utf-8")
    assert ("| output_clipping | warning |" in report) is clips


@pytest.mark.slow
@pytest.mark.parametrize("name", [*READERS, *HELD])
def test_identify_says_when_a_logger_holds_the_output(name: str, identified: Identified) -> None:
    # TCLab's log held for three samples: a sensor updating every 3 s, stamped every 1 s
    code, err, out = identified(name)
    assert code == 0, err
    check = _identifiability(out / "model.json")["output_held"]
    held = name in HELD
    assert check["passed"] is not held and check["measured"] == (3 if held else 1)
    assert ("czmpc: WARNING: output held: the output changes only once in 3 samples" in err) is held
    report = (out / "report.md").read_text(encoding="utf-8")
    assert ("| output_held | warning |" in report) is held


@pytest.mark.slow
@pytest.mark.parametrize("name", list(READERS))
def test_the_report_lists_the_level_shifts_it_did_not_repair(name: str,
                                                             identified: Identified) -> None:
    # the tanks' seven candidates are 18 to 67 % of the span: listed, none subtracted
    code, err, out = identified(name)
    assert code == 0, err
    report = (out / "report.md").read_text(encoding="utf-8")
    start = report.index("## Preprocessing")
    section = report[start:report.index("\n## ", start + 1)]
    bullets = re.findall(r"^- Level shift at [\d.]+ s not corrected: its estimate .* % of the "
                         r"output's span", section, flags=re.MULTILINE)
    assert len(bullets) == (7 if name == "tanks" else 0)
    if name == "tanks":
        assert "provenance):\n\nnone." in section


@pytest.mark.slow
def test_the_clipping_warnings_advice_works_blanked_rows_identify_in_segments(
    tmp_path: Path,
) -> None:
    # the advice: blank the clipped rows and identify with --gaps split
    data = READERS["tanks"]()
    clipped = set(clipped_samples(data.power_kw))
    columns = (data.time_s.tolist(), data.triac_pct.tolist(), data.power_kw.tolist())
    rows = ["time_s,triac_pct,power_kw"] + [
        f"{t!r},{u!r}," + ("" if k in clipped else repr(y))
        for k, (t, u, y) in enumerate(zip(*columns, strict=True))]
    (tmp_path / "blanked.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["identify", str(tmp_path / "blanked.csv"), "--out", str(tmp_path / "id"),
                     "--gaps", "split"])
    assert code == 0, err.getvalue()
    assert "47 incomplete sample(s) dropped; split into 3 segments" in err.getvalue()
    assert "output clipping" not in err.getvalue()
    checks = _identifiability(tmp_path / "id" / "model.json")
    assert checks["output_clipping"]["passed"] and checks["output_clipping"]["measured"] == 0


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 29 item 3: cut at its start, the TCLab log "
                   "gives nb, nf, nk 3, 2, 0 and 4, 2, 0 instead of the full log's 4, 3, 3")
@pytest.mark.parametrize("name", list(START_CUTS))
def test_the_short_logs_structure_holds_when_its_start_is_cut(name: str,
                                                              identified: Identified) -> None:
    _, _, out = identified(name)
    _, _, out_full = identified("tclab")
    assert _structure(out / "model.json") == _structure(out_full / "model.json")


def _pipeline(name: str):  # type: ignore[no-untyped-def]
    if name == "daisy":
        data = read_daisy_heating(REAL / "daisy_heating_system.dat")
        op = OperatingPoint(triac_pct=6.0, power_kw=129.32)   # DaISy: u = 6 V before the test
    elif name == "tclab":
        data, op = read_tclab(REAL / "tclab_mimo_steps_data.txt"), None
    else:
        data, op = read_cascaded_tanks(REAL / "cascaded_tanks_dataBenchmark.csv"), None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # non-convergence is reported in the result
        return run_paper_pipeline(data, operating_point=op)


@pytest.mark.parametrize("name", ["daisy", "tclab", "tanks"])
def test_hammerstein_oe_never_does_worse_than_the_linear_oe_it_contains(name: str) -> None:
    result = _pipeline(name)
    v_oe = result.model("oe_2_1").model.criteria.ballistic_mse_kw2
    v_hammerstein = result.model("hammerstein_oe").model.criteria.ballistic_mse_kw2
    assert v_oe is not None and v_hammerstein is not None
    assert v_hammerstein <= v_oe * (1 + NESTED_V_RTOL)


def test_the_cascaded_tanks_filling_to_overflow_is_not_repaired_as_level_shifts() -> None:
    # ARX(10, 10), the outlier model, misses the tanks filling to overflow (the output
    # clips at 10 V): seven events whose level persists. Each estimated shift is 18 to
    # 67 % of the output's span, far more than a sensor's offset, so none is subtracted
    # and each is said. Subtracted, they made OE(2,1)'s V 40.8 V^2 (Hammerstein-OE 1.17,
    # read then as the nonlinearity); on the log as logged it is 0.363 (Hammerstein-OE
    # 0.357).
    result = _pipeline("tanks")
    not_corrected = [s for s in result.skipped if "not corrected" in s]
    assert result.outliers is not None
    shifts = [c for c in result.outliers.candidates if c.kind == "level_shift"]
    assert len(not_corrected) == len(shifts) == 7
    np.testing.assert_array_equal(result.data.power_kw, result.raw_data.power_kw)
    assert result.model("oe_2_1").model.criteria.ballistic_mse_kw2 < 0.5
    assert any("steady" in s for s in result.skipped)     # says it fell back to the means


def test_identify_cli_reads_a_log_of_another_rig_through_a_column_mapping(
    identified: Identified, capsys: pytest.CaptureFixture[str]
) -> None:
    code, err, out = identified("lamp")
    assert code == 0, err
    model = load_model(out / "model.json")
    assert model.ts_s == 2.0 and model.input_range_pct == (3.0, 9.0)
    assert "degC" in (out / "report.md").read_text(encoding="utf-8")
    assert model.units is not None
    assert (model.units.input, model.units.output) == ("V", "degC")
    assert main(["show-model", str(out / "model.json")]) == 0
    shown = capsys.readouterr().out
    assert "units: input V, output degC" in shown
    assert re.search(r"u_nom = \S+ V, y_nom = \S+ degC", shown)   # u, y: not the puller's s, P
    assert " kW" not in shown and "[%]" not in shown


#: A unit change is exact in the data (a power of ten times each value, rounded once);
#: the searches normalise their data, so only the LM's rounding path moves: 1e-5.
UNIT_CHANGE_RTOL = 1e-5


@pytest.mark.slow
def test_a_unit_change_of_the_output_gives_the_same_model_in_the_new_unit(
    identified: Identified, tmp_path: Path,
) -> None:
    data = READERS["lamp"]()
    milli = Dataset(time_s=data.time_s, triac_pct=data.triac_pct, power_kw=1e3 * data.power_kw,
                    ts_s=data.ts_s)
    write_csv(milli, tmp_path / "mdegc.csv")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["identify", str(tmp_path / "mdegc.csv"), "--out", str(tmp_path / "id")])
    assert code == 0, err.getvalue()
    base = load_model(identified("lamp")[2] / "model.json")
    scaled = load_model(tmp_path / "id" / "model.json")
    assert (scaled.kind, scaled.linear_block, scaled.b.size) == (
        base.kind, base.linear_block, base.b.size)
    np.testing.assert_allclose(scaled.a, base.a, rtol=UNIT_CHANGE_RTOL, atol=1e-9)
    np.testing.assert_allclose(scaled.b, base.b, rtol=UNIT_CHANGE_RTOL, atol=1e-9)
    np.testing.assert_allclose(scaled.input_poly, 1e3 * base.input_poly, rtol=UNIT_CHANGE_RTOL,
                               atol=0)
    assert scaled.operating_point.power_kw == pytest.approx(
        1e3 * base.operating_point.power_kw, rel=UNIT_CHANGE_RTOL)
    assert scaled.noise_std_kw == pytest.approx(1e3 * base.noise_std_kw, rel=UNIT_CHANGE_RTOL)


@pytest.mark.parametrize(("column", "factor", "pattern"), [
    ("power_kw", 1e200, r"the output spans 1.16e\+202"),
    ("power_kw", 1e-200, r"the output spans 1.16e-198"),
    ("triac_pct", 1e200, r"the input spans 6e\+200"),
    ("triac_pct", 1e-200, r"the input spans 6e-200"),
], ids=["output-1e200", "output-1e-200", "input-1e200", "input-1e-200"])
def test_data_scaled_by_1e200_is_a_clean_refusal_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], column: str, factor: float,
    pattern: str,
) -> None:
    data = READERS["lamp"]()
    values = {"triac_pct": data.triac_pct, "power_kw": data.power_kw}
    values[column] = factor * values[column]
    write_csv(Dataset(time_s=data.time_s, ts_s=data.ts_s, **values), tmp_path / "log.csv")
    code = main(["identify", str(tmp_path / "log.csv"), "--out", str(tmp_path / "id")])
    err = capsys.readouterr().err
    assert code == 2
    assert re.search(r"czmpc: error: identify .*log.csv: " + pattern, err), err
    assert "Traceback" not in err and not (tmp_path / "id").exists()


@pytest.mark.slow
@pytest.mark.parametrize("name", list(READERS))
def test_the_report_shows_which_structures_the_log_does_not_tell_apart(
    name: str, identified: Identified,
) -> None:
    _, err, out = identified(name)
    report = (out / "report.md").read_text(encoding="utf-8")
    section = report[report.index("## Structure selection"):report.index("## Linear models")]
    rest = section[section.index("**Linear OE from rest**"):].split("\n\n")[1].splitlines()[2:]
    ratios = [float(line.split("|")[4]) for line in rest]
    assert ratios == sorted(ratios) and ratios[0] == 1.0 and ratios[-1] <= 1.10
    chosen = [line.split("|")[1].strip() for line in rest if "**chosen**" in line]
    assert len(chosen) == 1
    meta = json.loads((out / "model.json").read_text(encoding="utf-8"))
    from_rest = meta["provenance"]["method"].startswith("sysid.rest_oe")
    if from_rest:                                                  # model.json is that OE
        assert chosen[0] == ", ".join(str(x) for x in _structure(out / "model.json"))
    said = f"is one of {len(rest)} of the 48 OE structures within 10 %" in err
    assert said is (from_rest and len(rest) > 1)
    assert ("the record does not single out one structure" in section) is (len(rest) > 1)
    assert (out / "figures" / "structure_choice.png").stat().st_size > 10_000
