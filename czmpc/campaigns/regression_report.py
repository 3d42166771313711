"""Reports of a regression check: terminal table, Markdown, figures, JUnit XML.

For every failing case the reports name the metric, its golden value, its tolerance and
the new value, and the first time the new trajectory leaves the golden band; the figure
of the case draws the golden trajectory with its band and the new one on shared axes. A
changed input file (model, settings, scenario) or czmpc version is reported as the
likely cause, with the keys that changed in the file.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

from czmpc.campaigns.regression import AuditReport, CaseCheck, CheckReport
from czmpc.reports import tables
from sysid.atomic import atomic_write_text


def _g(value: float) -> str:
    return "nan" if math.isnan(value) else f"{value:.6g}"


def divergence_text(case: CaseCheck) -> str:
    """``"t = 612 s (power_true_kw: 50.31 vs golden 50.02, band 0.0013)"`` or ``"none"``."""
    d = case.divergence
    if d is None:
        return "none"
    return (f"t = {d.time_s:g} s ({d.signal}: {_g(d.new)} vs golden {_g(d.golden)}, "
            f"band {d.band:.3g})")


def failure_lines(case: CaseCheck) -> list[str]:
    """One line per failed metric (or the error) of a case, and its first divergence."""
    if case.error:
        lines = [f"{case.case_id}: the run raised {case.error}"]
    else:
        lines = [f"{case.case_id}: {f.metric} = {_g(f.new)}, golden {_g(f.golden)} +- "
                 f"{f.tolerance:.3g}" for f in case.failures]
        lines.append(f"{case.case_id}: first divergence from the golden trajectory: "
                     f"{divergence_text(case)}")
    if case.changed_inputs:
        lines.append(f"{case.case_id}: likely cause: changed input(s) {', '.join(case.changed_inputs)}")
    return lines


def cause_lines(report: CheckReport) -> list[str]:
    """What changed since recording: the czmpc version and the input files (with keys)."""
    lines = []
    if report.recorded_version != report.current_version:
        lines.append(f"czmpc version changed: recorded with {report.recorded_version}, "
                     f"checked with {report.current_version}")
    for ch in report.input_changes:
        lines.append(f"input file changed: {ch.name} (sha256 {ch.recorded_sha256[:12]} -> "
                     f"{ch.current_sha256[:12]})")
        lines += [f"    {d}" for d in ch.details]
    return lines


def check_table(report: CheckReport) -> str:
    """The terminal report: one row per case, then every failure in full and the causes."""
    rows = [("case", "result", "metric", "golden", "tolerance", "new", "first divergence")]
    for c in report.cases:
        if c.error:
            rows.append((c.case_id, "ERROR", "-", "-", "-", "-", c.error[:60]))
        elif c.failures:
            for i, f in enumerate(c.failures):
                rows.append((c.case_id if i == 0 else "", "FAIL" if i == 0 else "", f.metric,
                             _g(f.golden), f"{f.tolerance:.3g}", _g(f.new),
                             divergence_text(c) if i == 0 else ""))
        else:
            rows.append((c.case_id, "ok", "", "", "", "",
                         "" if c.divergence is None else divergence_text(c)))
    lines = [tables.format_table(rows[0], rows[1:], align="l" * len(rows[0])), ""]
    n_fail = len(report.failed)
    lines.append(f"{report.golden.suite.name}: {len(report.cases) - n_fail} of {len(report.cases)} "
                 f"case(s) hold{'' if n_fail == 0 else f'; {n_fail} FAILED'} "
                 f"({report.wall_time_s:.1f} s)")
    causes = cause_lines(report)
    if causes:
        lines += ["Likely cause:" if n_fail else "Changed since recording (every case still holds):",
                  *[f"  {c}" for c in causes]]
    return "\n".join(lines) + "\n"


def safe_name(case_id: str) -> str:
    """A file name for a case id."""
    return re.sub(r"[^A-Za-z0-9.+-]+", "_", case_id).strip("_")


def markdown(report: CheckReport, figures: dict[str, str] | None = None) -> str:
    """The Markdown report (figures named relative to it)."""
    figures = figures or {}
    prov = report.golden.doc["provenance"]
    lines = [
        f"# Regression check: {report.golden.suite.name}",
        "",
        f"Golden directory `{report.golden.path}`, recorded {prov['recorded_utc']} with czmpc "
        f"{report.recorded_version}; checked with czmpc {report.current_version} in "
        f"{report.wall_time_s:.1f} s.",
        "",
        f"**{'PASSED' if report.passed else 'FAILED'}**: {len(report.cases) - len(report.failed)} "
        f"of {len(report.cases)} case(s) hold.",
        "",
    ]
    causes = cause_lines(report)
    if causes:
        lines += ["## Likely cause" if report.failed else "## Changed since recording", "",
                  *[f"- {c.strip()}" if not c.startswith("    ") else f"  - `{c.strip()}`"
                    for c in causes], ""]
    if report.failed:
        lines += ["## Failing cases", "",
                  "| case | metric | golden | tolerance | new | first divergence |",
                  "|---|---|---|---|---|---|"]
        for c in report.failed:
            if c.error:
                lines.append(f"| {c.case_id} | error | | | | {c.error} |")
            for f in c.failures:
                lines.append(f"| {c.case_id} | {f.metric} | {_g(f.golden)} | {f.tolerance:.3g} | "
                             f"{_g(f.new)} | {divergence_text(c)} |")
        lines.append("")
        for c in report.failed:
            if c.case_id in figures:
                lines += [f"![{c.case_id}]({figures[c.case_id]})", ""]
    lines += ["## Every case", "", "| case | result | first divergence |", "|---|---|---|"]
    lines += [f"| {c.case_id} | {'ok' if c.passed else 'FAIL'} | {divergence_text(c)} |"
              for c in report.cases]
    return "\n".join(lines) + "\n"


def write_report(report: CheckReport, out_dir: str | Path) -> tuple[Path, ...]:
    """Write DIR/report.md and DIR/figures/<case>.png (failing cases); return the paths."""
    from czmpc.reports.regression_figure import plot_regression_case

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures: dict[str, str] = {}
    paths: list[Path] = []
    for case in report.failed:
        if case.error:
            continue
        rel = f"figures/{safe_name(case.case_id)}.png"
        plot_regression_case(
            report.golden.trajectory(case.case_id), report.golden.doc["cases"][case.case_id]["band"],
            case.new_trajectory, title=case.case_id, path=out / rel,
            divergence_time_s=None if case.divergence is None else case.divergence.time_s)
        figures[case.case_id] = rel
        paths.append(out / rel)
    atomic_write_text(out / "report.md", markdown(report, figures))
    return (out / "report.md", *paths)


def junit_xml(report: CheckReport) -> str:
    """JUnit XML: one ``testsuite`` (the suite), one ``testcase`` per case."""
    suite = ET.Element("testsuite", {
        "name": report.golden.suite.name, "tests": str(len(report.cases)),
        "failures": str(sum(1 for c in report.cases if c.failures and not c.error)),
        "errors": str(sum(1 for c in report.cases if c.error)), "skipped": "0",
        "time": f"{report.wall_time_s:.3f}"})
    props = ET.SubElement(suite, "properties")
    for name, value in (("golden_dir", str(report.golden.path)),
                        ("czmpc_version_recorded", report.recorded_version),
                        ("czmpc_version_checked", report.current_version),
                        *((f"changed_input:{ch.name}", ch.current_sha256) for ch in report.input_changes)):
        ET.SubElement(props, "property", {"name": name, "value": value})
    causes = cause_lines(report)
    for c in report.cases:
        case = ET.SubElement(suite, "testcase", {"classname": f"czmpc.regress.{report.golden.suite.name}",
                                                 "name": c.case_id})
        if c.error:
            err = ET.SubElement(case, "error", {"message": c.error, "type": "run error"})
            err.text = "\n".join(failure_lines(c) + causes)
        elif c.failures:
            first = c.failures[0]
            fail = ET.SubElement(case, "failure", {
                "message": (f"{first.metric} = {_g(first.new)}, golden {_g(first.golden)} +- "
                            f"{first.tolerance:.3g}; first divergence {divergence_text(c)}"),
                "type": "regression"})
            fail.text = "\n".join(failure_lines(c) + causes)
    ET.indent(suite)
    text: str = ET.tostring(suite, encoding="unicode", xml_declaration=True)
    return text + "\n"


def audit_table(report: AuditReport) -> str:
    """The audit's terminal report: per mutation, the cases it changes and those that caught it."""
    rows = [("mutation", "cases", "caught by", "first catch")]
    for m in report.mutations:
        first = f"{m.caught[0][0]} ({m.caught[0][1]})" if m.caught else "-"
        rows.append((m.mutation, str(m.n_cases),
                     f"{len(m.caught)} case(s)" if m.n_cases else "not applicable", first))
    lines = [tables.format_table(rows[0], rows[1:], align="l" * len(rows[0]))]
    if report.baseline_failures:
        lines.append(f"left out: {len(report.baseline_failures)} case(s) that fail unmutated: "
                     f"{', '.join(report.baseline_failures)}")
    n = sum(m.is_caught for m in report.mutations)
    lines.append("")
    if report.catches_any:
        lines.append(f"the suite catches {n} of {len(report.mutations)} mutation(s)")
    else:
        lines.append("FLAGGED: the suite catches none of the mutations; it would not notice a "
                     "changed controller (add scenarios with setpoint changes, disturbances or "
                     "binding limits, or tighten [tolerances])")
    return "\n".join(lines) + "\n"


__all__ = ["audit_table", "cause_lines", "check_table", "divergence_text", "failure_lines", "junit_xml",
           "markdown", "safe_name", "write_report"]
