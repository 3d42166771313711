"""The schedule in the forms and units of DCS and PLC PID blocks.

Blocks that work in percent of span need the spans of their PV (power) and output (TRIAC)
ranges: the dimensionless gain is ``K = Kc * pv_span_kw / out_span_pct`` [% of output
span per % of PV span]. The spans are the user's (the ranges configured in the block);
they are never assumed, so `Spans` has no defaults. `FORMS` are Siemens ``PID_Compact``,
Emerson DeltaV ``PID``, Honeywell Experion ``PID`` and Rockwell Logix ``PIDE``, with the
parameter names of the vendors' published descriptions (docs/guides/pid.rst lists each
form's columns and units; check them against the manual of the firmware on site). Every
form also has the proportional band ``PB = 100/K`` [%].

A block runs the ISA numbers through its own difference equation, so each form holds for
the discretization of its block (`VENDOR_DISCRETIZATION`, `czmpc.pid.discretization`):
the vendor's documented algorithm, or where its documentation of the discrete algorithm
was not available, the worst case over forward, backward and trapezoidal integration;
`VENDOR_DISCRETIZATION_SOURCE` says which, and every form's file and notes state it with
the sampling time. A schedule not designed for a form's discretization is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from czmpc.pid.discretization import Discretization, describe, forms_of
from czmpc.pid.errors import PIDTuningError
from czmpc.pid.schedule import PIDSchedule, Region

FORMS: tuple[str, ...] = ("siemens", "deltav", "honeywell", "rockwell")
SECONDS_PER_MINUTE = 60.0
_UNDOCUMENTED = ("its documentation of the discrete algorithm (how the integral and the "
                 "derivative filter are sampled) was not available when this form was "
                 "written, so the numbers hold for the worst case")
#: The discretization each form's numbers hold for (`czmpc.pid.discretization`).
VENDOR_DISCRETIZATION: dict[str, Discretization] = {
    "siemens": "worst", "deltav": "worst", "honeywell": "worst", "rockwell": "worst"}
#: Why: the vendor's documented algorithm, or what of it was not available.
VENDOR_DISCRETIZATION_SOURCE: dict[str, str] = {
    "siemens": "PID_Compact's function manual states its law in continuous time only (a "
               "PIDT1 in the Laplace variable); " + _UNDOCUMENTED,
    "deltav": "DeltaV PID: " + _UNDOCUMENTED,
    "honeywell": "Experion PID: " + _UNDOCUMENTED,
    "rockwell": "Logix PIDE: " + _UNDOCUMENTED,
}


def gain_to_band_pct(gain: float) -> float:
    """Proportional band [%] of a dimensionless gain [%/%]: ``100/K``."""
    return 100.0 / gain


def seconds_to_minutes(time_s: float) -> float:
    """[s] to [min]."""
    return time_s / SECONDS_PER_MINUTE


def dependent_to_independent(kc: float, ti_min: float, td_min: float) -> tuple[float, float, float]:
    """Dependent ``Kc (e + 1/Ti int e + Td de/dt)`` to independent ``Kp e + Ki int e + Kd de/dt``.

    Returns ``(Kp, Ki [1/min], Kd [min]) = (Kc, Kc/Ti, Kc Td)``.
    """
    return kc, kc / ti_min, kc * td_min


@dataclass(frozen=True, slots=True, kw_only=True)
class Spans:
    """The PV and output ranges configured in the block (no defaults: never assumed).

    Parameters
    ----------
    pv_range_kw :
        ``(lo, hi)`` of the PV (power) range [kW].
    out_range_pct :
        ``(lo, hi)`` of the output (TRIAC) range [%].

    Raises
    ------
    PIDTuningError
        A range that is not finite and increasing.
    """

    pv_range_kw: tuple[float, float]
    out_range_pct: tuple[float, float]

    def __post_init__(self) -> None:
        for name, (lo, hi) in (("pv_range_kw", self.pv_range_kw),
                               ("out_range_pct", self.out_range_pct)):
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise PIDTuningError(
                    f"Spans.{name}: expected LO < HI, both finite; got {lo!r} {hi!r}")

    @property
    def pv_span_kw(self) -> float:
        """PV span [kW]."""
        return self.pv_range_kw[1] - self.pv_range_kw[0]

    @property
    def out_span_pct(self) -> float:
        """Output span [%]."""
        return self.out_range_pct[1] - self.out_range_pct[0]

    def dimensionless_gain(self, kc_pct_per_kw: float) -> float:
        """``K = Kc pv_span/out_span`` [% of output span per % of PV span]."""
        return kc_pct_per_kw * self.pv_span_kw / self.out_span_pct


@dataclass(frozen=True, kw_only=True)
class VendorTable:
    """One vendor form of the schedule: columns with units, one row per breakpoint, notes.

    Parameters
    ----------
    form :
        The form's name.
    block :
        The vendor's block.
    header :
        Column names, each with its unit in brackets.
    rows :
        Values (numbers or the vendor's option strings), one tuple per breakpoint.
    notes :
        What the engineer must know to enter them.
    discretization :
        The discretization the numbers hold for (`VENDOR_DISCRETIZATION`).
    comments :
        The file's header comments: block, sampling time, discretization and Ms.
    """

    form: str
    block: str
    header: tuple[str, ...]
    rows: tuple[tuple[float | str, ...], ...]
    notes: tuple[str, ...]
    discretization: Discretization = "worst"
    comments: tuple[str, ...] = ()


def _weight_notes(block: str, schedule: PIDSchedule) -> list[str]:
    """Notes for setpoint weights strictly between 0 and 1, which ``block`` cannot hold."""
    weights = sorted({r.tuning.setpoint_weight for r in schedule.rows} - {0.0, 1.0})
    return [f"{block}: setpoint weight b = {b:g} has no setting here; the table gives b = 1 "
            "(proportional on error). The margins are unchanged; the setpoint response "
            "overshoots more than tuned." for b in weights]


def _siemens(schedule: PIDSchedule, spans: Spans) -> VendorTable:
    scale = 100.0 / spans.out_span_pct
    rows = []
    for r in schedule.rows:
        t = r.tuning
        rows.append((r.triac_pct, t.kc_pct_per_kw * scale, t.ti_s, t.td_s,
                     t.td_filter_s / t.td_s if t.td_s > 0 else 0.0, t.setpoint_weight, 0.0,
                     schedule.ts_s, gain_to_band_pct(spans.dimensionless_gain(t.kc_pct_per_kw))))
    return VendorTable(
        form="siemens", block="Siemens S7-1200/1500 PID_Compact",
        header=("from_triac_pct [%]", "Gain [% output per kW]", "Ti [s]", "Td [s]",
                "TdFiltRatio [-]", "PWeighting [-]", "DWeighting [-]", "Cycle [s]", "PB [%]"),
        rows=tuple(rows),
        notes=(f"Gain is in % of the PID output (0..100 %, driving the TRIAC over "
               f"{spans.out_range_pct[0]:g}..{spans.out_range_pct[1]:g} %) per kW of the "
               "scaled input.",
               "PID_Compact does not schedule by itself: the user program writes "
               "Retain.CtrlParams (Gain, Ti, Td, TdFiltRatio, PWeighting, DWeighting, Cycle) "
               "when the TRIAC output enters another row's range; pretuning or fine tuning "
               "overwrites them.",
               "DWeighting 0: derivative on the measurement only, as tuned.",
               f"Cycle must be the loop's sampling time, {schedule.ts_s:g} s: the tuning is "
               "for it."))


def _structure(b: float, has_d: bool) -> str:
    if b == 1.0:
        return "PI action on error, D action on PV" if has_d else "PI action on error"
    if b == 0.0:
        return "I action on error, PD action on PV" if has_d else "I action on error, P action on PV"
    return "Two degrees of freedom controller"


def _deltav(schedule: PIDSchedule, spans: Spans, regions: tuple[Region, ...]) -> VendorTable:
    rows = []
    for r in schedule.rows:
        t = r.tuning
        k = spans.dimensionless_gain(t.kc_pct_per_kw)
        rows.append((r.triac_pct, k, t.ti_s, t.td_s, _structure(t.setpoint_weight, t.td_s > 0),
                     t.setpoint_weight, gain_to_band_pct(k)))
    notes = [f"GAIN in % of PV span ({spans.pv_range_kw[0]:g}..{spans.pv_range_kw[1]:g} kW) "
             f"per % of OUT span ({spans.out_range_pct[0]:g}..{spans.out_range_pct[1]:g} %); "
             "FORM Standard; RESET in seconds per repeat; RATE in seconds.",
             "Three-region template (GAIN, RESET, RATE per region of the TRIAC output):"]
    for j, reg in enumerate(regions, start=1):
        t = reg.row.tuning
        notes.append(f"region {j}: {reg.lo_pct:g}..{reg.hi_pct:g} %: GAIN "
                     f"{spans.dimensionless_gain(t.kc_pct_per_kw):.4g}, RESET {t.ti_s:.4g} s, "
                     f"RATE {t.td_s:.4g} s (row at {reg.row.triac_pct:g} %; worst Ms in the "
                     f"region {reg.worst_ms:.3f})")
    return VendorTable(
        form="deltav", block="Emerson DeltaV PID",
        header=("from_triac_pct [%]", "GAIN [%/%]", "RESET [s/repeat]", "RATE [s]",
                "STRUCTURE", "BETA [-]", "PB [%]"),
        rows=tuple(rows), notes=tuple(notes))


def _honeywell(schedule: PIDSchedule, spans: Spans) -> VendorTable:
    rows, notes = [], [
        f"K in % of the output range ({spans.out_range_pct[0]:g}..{spans.out_range_pct[1]:g} %) "
        f"per % of the PV range ({spans.pv_range_kw[0]:g}..{spans.pv_range_kw[1]:g} kW); "
        "T1 and T2 in minutes; PIDFORM non-interactive: CV = K (e + 1/T1 int e dt + T2 de/dt).",
        "CTLEQN: A = P, I, D on error; B = P, I on error, D on PV; C = I on error, P, D on PV.",
        "Experion's derivative filter is its own (derivative gain); check it against "
        "td_filter_s of pid_table.csv."]
    for r in schedule.rows:
        t = r.tuning
        k = spans.dimensionless_gain(t.kc_pct_per_kw)
        rows.append((r.triac_pct, k, seconds_to_minutes(t.ti_s), seconds_to_minutes(t.td_s),
                     "C" if t.setpoint_weight == 0.0 else "B", gain_to_band_pct(k)))
    notes += _weight_notes("Experion", schedule)
    return VendorTable(form="honeywell", block="Honeywell Experion PID",
                       header=("from_triac_pct [%]", "K [%/%]", "T1 [min]", "T2 [min]",
                               "CTLEQN", "PB [%]"),
                       rows=tuple(rows), notes=tuple(notes))


def _rockwell(schedule: PIDSchedule, spans: Spans) -> VendorTable:
    rows, notes = [], [
        f"Gains in % of the CV span per % of the PV span: set PVEUMin/PVEUMax to "
        f"{spans.pv_range_kw[0]:g}/{spans.pv_range_kw[1]:g} kW and CVEUMin/CVEUMax to "
        f"{spans.out_range_pct[0]:g}/{spans.out_range_pct[1]:g} %.",
        "Dependent gains (DependIndepend = 1): PGain, IGain = Ti [min/repeat], DGain = Td "
        "[min]. Independent (DependIndepend = 0): PGain, IGain [1/min], DGain [min].",
        "PVEProportional 0 (P on error, b = 1) or 1 (P on PV, b = 0); PVEDerivative 1 "
        "(D on PV)."]
    for r in schedule.rows:
        t = r.tuning
        k = spans.dimensionless_gain(t.kc_pct_per_kw)
        ti_min, td_min = seconds_to_minutes(t.ti_s), seconds_to_minutes(t.td_s)
        kp, ki, kd = dependent_to_independent(k, ti_min, td_min)
        rows.append((r.triac_pct, k, ti_min, td_min, kp, ki, kd,
                     1.0 if t.setpoint_weight == 0.0 else 0.0, gain_to_band_pct(k)))
    notes += _weight_notes("PIDE", schedule)
    return VendorTable(
        form="rockwell", block="Rockwell Logix PIDE",
        header=("from_triac_pct [%]", "dependent PGain [-]", "dependent IGain [min/repeat]",
                "dependent DGain [min]", "independent PGain [-]", "independent IGain [1/min]",
                "independent DGain [min]", "PVEProportional [0/1]", "PB [%]"),
        rows=tuple(rows), notes=tuple(notes))


def vendor_table(schedule: PIDSchedule, form: str, spans: Spans | None,
                 regions: tuple[Region, ...] = ()) -> VendorTable:
    """The schedule in vendor form ``form``.

    Parameters
    ----------
    schedule :
        The tuned schedule.
    form :
        One of `FORMS`.
    spans :
        The block's PV and output ranges; required (None raises, naming what to give).
    regions :
        The DeltaV template's regions (`czmpc.pid.schedule.merge_regions`).

    Raises
    ------
    PIDTuningError
        An unknown form, no spans, or a schedule not designed for the form's
        discretization (`VENDOR_DISCRETIZATION`).
    """
    if form not in FORMS:
        raise PIDTuningError(f"vendor form: expected one of {', '.join(FORMS)}; got {form!r}")
    if spans is None:
        raise PIDTuningError(
            f"vendor form {form!r} needs the spans the block scales with: give the PV range "
            "in kW and the output range in % (--pv-range-kw LO HI --out-range-pct LO HI); "
            "they are not assumed")
    disc = VENDOR_DISCRETIZATION[form]
    if not set(forms_of(disc)) <= set(schedule.spec.forms):
        raise PIDTuningError(
            f"vendor form {form!r}: its numbers must hold for {disc} "
            f"({', '.join(forms_of(disc))}: {VENDOR_DISCRETIZATION_SOURCE[form]}); the schedule "
            f"was designed for {schedule.spec.discretization} only: tune it with "
            f"--discretization {disc}")
    if form == "deltav":
        table = _deltav(schedule, spans, regions)
    else:
        table = {"siemens": _siemens, "honeywell": _honeywell, "rockwell": _rockwell}[form](
            schedule, spans)
    stated = _discretization_lines(schedule, form)
    return replace(table, discretization=disc, notes=table.notes + stated,
                   comments=(table.block, f"ts_s: {schedule.ts_s!r}", f"discretization: {disc}",
                             *stated))


def _discretization_lines(schedule: PIDSchedule, form: str) -> tuple[str, ...]:
    """Sampling time, discretization and Ms of ``form``'s numbers, one sentence each."""
    disc = VENDOR_DISCRETIZATION[form]
    forms = forms_of(disc)
    worst = max(r.margins_for(disc)[1] for r in schedule.rows)
    bound = schedule.spec.ms_bound
    return (f"Sampling time {schedule.ts_s:g} s: the block must run every {schedule.ts_s:g} s "
            "(its cycle, scan or update time); the numbers hold for no other.",
            f"Discretization: {describe(disc)}. {VENDOR_DISCRETIZATION_SOURCE[form]}.",
            f"Largest Ms at and between the breakpoints in {', '.join(forms)}: {worst:.3f}"
            + (f" (bound {bound:g})." if bound is not None else "."))


def vendor_csv_text(table: VendorTable) -> str:
    """CSV text of a `VendorTable`: comment lines (``#``), header with units, rows.

    Floats are written with the shortest round-trip repr.
    """
    def cell(v: float | str) -> str:
        return repr(float(v)) if isinstance(v, float | int) else f'"{v}"'
    return "\n".join([f"# {c}" for c in table.comments]
                     + [",".join(f'"{h}"' for h in table.header)]
                     + [",".join(cell(v) for v in row) for row in table.rows]) + "\n"


__all__ = ["FORMS", "SECONDS_PER_MINUTE", "VENDOR_DISCRETIZATION", "VENDOR_DISCRETIZATION_SOURCE",
           "Spans", "VendorTable",
           "dependent_to_independent", "gain_to_band_pct", "seconds_to_minutes", "vendor_table",
           "vendor_csv_text"]
