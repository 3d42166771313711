"""Everything ``czmpc tune-pid`` writes into its directory, from a tuned schedule.

``pid_table.csv`` (`czmpc.pid.table`), ``characterizer.csv``, one ``vendor_<form>.csv``
per asked vendor form (`czmpc.pid.vendor`), ``report.md`` and its figures
(`czmpc.pid.report`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from czmpc.pid.report import write_report
from czmpc.pid.schedule import PIDSchedule, merge_regions
from czmpc.pid.table import characterizer_error_pct, write_characterizer, write_pid_table
from czmpc.pid.vendor import Spans, vendor_csv_text, vendor_table
from sysid.atomic import atomic_write_text
from sysid.model import HammersteinModel

PID_TABLE_FILE = "pid_table.csv"
CHARACTERIZER_FILE = "characterizer.csv"
#: Regions of the merged schedule (DeltaV's gain-scheduling template has three).
N_REGIONS = 3


def write_outputs(
    schedule: PIDSchedule, model: HammersteinModel, directory: str | os.PathLike[str], *,
    forms: Sequence[str] = (), spans: Spans | None = None, command: str = "",
    model_source: str = "",
) -> tuple[Path, ...]:
    """Write the tables, vendor forms and report of ``schedule`` into ``directory``.

    Parameters
    ----------
    schedule :
        The tuned schedule.
    model :
        The model it was tuned on.
    directory :
        Output directory (created).
    forms :
        Vendor forms to write (`czmpc.pid.vendor.FORMS`).
    spans :
        The block's PV and output ranges; required when ``forms`` is not empty.
    command, model_source :
        Recorded in the report.

    Raises
    ------
    PIDTuningError
        A vendor form without spans (checked before anything is written).
    """
    regions = merge_regions(schedule, model, N_REGIONS)
    tables = [vendor_table(schedule, form, spans, regions) for form in forms]
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    written = [write_pid_table(schedule, out / PID_TABLE_FILE),
               write_characterizer(model, schedule.triac_range_pct, out / CHARACTERIZER_FILE)]
    for vt in tables:
        path = out / f"vendor_{vt.form}.csv"
        atomic_write_text(path, vendor_csv_text(vt))
        written.append(path)
    written += write_report(
        schedule, out, command=command, model_source=model_source,
        files=[p.name for p in written],
        characterizer_error_pct=characterizer_error_pct(model, schedule.triac_range_pct),
        regions=regions, vendor_tables=tables)
    return tuple(written)


__all__ = ["CHARACTERIZER_FILE", "N_REGIONS", "PID_TABLE_FILE", "write_outputs"]
