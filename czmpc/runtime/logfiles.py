"""Where a run's log goes: never over an earlier run's, rotated on long runs, found again as a set.

A run log is the controller's evidence after a crash, so a start never overwrites one
(`open_run_log`):

- ``[run] log = "run.csv"``: a start refuses when ``run.csv`` or its meta file exists,
  unless told ``--append`` (the meta file keeps every run's provenance) or
  ``--replace-log``;
- ``[run] log = "logs/"`` (ends with ``/`` or is a directory; `RunConfig.log_per_run`):
  each run writes its own ``logs/run-YYYYMMDDTHHMMSSZ.csv``.

Long runs rotate (``[run] rotate = "daily"`` at midnight UTC, or ``rotate_mb``) into
``<stem>-part002.csv`` and on, each meta file naming its part and the previous one.
Readers take a file, a directory or a glob as one log (`log_parts`): parts of one run
join up; between runs (the sample index starts again) there is a gap.
"""

from __future__ import annotations

import csv
import datetime as dt
import glob
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

from czmpc.errors import CzmpcError

#: Log columns, in order.
LOG_COLUMNS = ("k", "time_s", "wall_time_s", "power_kw", "quality", "setpoint_kw",
               "triac_pct", "applied_triac_pct", "status", "verdict", "mode", "connected",
               "written", "lateness_s", "step_latency_s", "skipped", "predicted_kw", "health",
               "stale_alarm", "event", "candidate_predicted_kw", "candidate_health",
               "candidate_stale_alarm", "grid_voltage_factor", "voltage_factor_used",
               "voltage_verdict", "preview_samples")
#: Format tag of the run log's provenance file ``<log>.meta.json``.
RUN_META_FORMAT = "czmpc-runlog/1"
#: How a start treats an existing log file: refuse, append to it, or replace it.
LOG_POLICIES = ("new", "append", "force")


class RunLogExistsError(CzmpcError):
    """A start would overwrite an earlier run's log (exit 2)."""


def meta_path(log_path: Path) -> Path:
    """The provenance file beside a run log: ``run.csv`` -> ``run.meta.json``."""
    return log_path.with_suffix(".meta.json")


def run_file_name(start: dt.datetime) -> str:
    """The file of a run started at ``start`` in a log directory."""
    return f"run-{start.astimezone(dt.UTC):%Y%m%dT%H%M%SZ}.csv"


def part_path(first: Path, part: int) -> Path:
    """The file of part ``part`` (1 = the first) of a rotated log."""
    return first if part == 1 else first.with_name(f"{first.stem}-part{part:03d}{first.suffix}")


def _fmt(value: object) -> object:
    if isinstance(value, float) and abs(value) >= 1e6:
        return f"{value:.3f}"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return value


class RunLog:
    """CSV log of every step, flushed per row (readable after a crash), rotated when asked.

    Parameters
    ----------
    path :
        The (first) CSV file (columns `LOG_COLUMNS`).
    meta :
        Provenance for `meta_path` ``(path)`` (JSON, `RUN_META_FORMAT`); None: no file.
    append :
        Continue an existing file (the meta file keeps every run's under ``runs``).
    rotate :
        ``"none"`` or ``"daily"`` (a new part at midnight UTC).
    rotate_bytes :
        A new part when the current one reaches this size; None: no size limit.
    """

    def __init__(self, path: Path, meta: Mapping[str, object] | None = None, *,
                 append: bool = False, rotate: str = "none",
                 rotate_bytes: int | None = None) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.first = self.path = path
        self.part = 1
        self._meta = dict(meta or {})
        self._with_meta = meta is not None
        self._rotate, self._rotate_bytes = rotate, rotate_bytes
        self._fh: IO[str] = self._open(path, append)
        self._w = csv.writer(self._fh)

    def _open(self, path: Path, append: bool) -> IO[str]:
        if self._with_meta:
            doc: dict[str, Any] = {"format": RUN_META_FORMAT, **self._meta}
            if self.part > 1:
                doc |= {"part": self.part, "previous_part": part_path(self.first,
                                                                      self.part - 1).name,
                        "first_part": self.first.name}
            if append and meta_path(path).is_file():
                earlier = json.loads(meta_path(path).read_text(encoding="utf-8"))
                doc["runs"] = [*earlier.get("runs", [{k: v for k, v in earlier.items()
                                                      if k != "runs"}]), dict(self._meta)]
            meta_path(path).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        self._columns: tuple[str, ...] = LOG_COLUMNS
        if append and path.is_file():
            # a log of an earlier version has fewer columns: continue it with its own
            with open(path, newline="", encoding="utf-8-sig") as old:
                header = tuple(next(csv.reader(old), []))
            if header and LOG_COLUMNS[:len(header)] == header:
                self._columns = header
        fh = open(path, "a" if append else "w", newline="", encoding="utf-8")  # noqa: SIM115
        if not append or fh.tell() == 0:
            self._columns = LOG_COLUMNS
            csv.writer(fh).writerow(LOG_COLUMNS)
            fh.flush()
        self._day = dt.datetime.now(dt.UTC).date()
        return fh

    def row(self, values: dict[str, object]) -> None:
        """Write one row (flushed), after opening the next part if one is due."""
        if self._due():
            self._fh.close()
            self.part += 1
            self.path = part_path(self.first, self.part)
            self._fh = self._open(self.path, append=False)
            self._w = csv.writer(self._fh)
        self._w.writerow([_fmt(values[c]) for c in self._columns])
        self._fh.flush()

    def _due(self) -> bool:
        if self._rotate == "daily" and dt.datetime.now(dt.UTC).date() != self._day:
            return True
        return self._rotate_bytes is not None and self._fh.tell() >= self._rotate_bytes

    def close(self) -> None:
        """Close the current part."""
        self._fh.close()


def open_run_log(configured: Path, meta: Mapping[str, object], *, per_run: bool = False,
                 policy: str = "new", rotate: str = "none", rotate_bytes: int | None = None,
                 now: dt.datetime | None = None) -> RunLog:
    """Open a run's log as the module docstring says; never over an earlier run's.

    ``per_run``: ``configured`` is a directory, where the run writes its own file.

    Raises
    ------
    RunLogExistsError
        ``configured`` is a file that exists (or its meta file does) and ``policy`` is
        ``"new"``: the message says how to keep or replace it.
    """
    refuse_overwrite(configured, policy, per_run=per_run)
    options = {"rotate": rotate, "rotate_bytes": rotate_bytes}
    if per_run:
        start = now or dt.datetime.now(dt.UTC)
        path = Path(configured) / run_file_name(start)
        n = 1
        while path.exists() or meta_path(path).exists():
            n += 1
            path = Path(configured) / f"{run_file_name(start)[:-4]}-{n}.csv"
        return RunLog(path, meta, **options)  # type: ignore[arg-type]
    exists = configured.exists() or meta_path(configured).exists()
    return RunLog(configured, meta, append=exists and policy == "append",
                  **options)  # type: ignore[arg-type]


def refuse_overwrite(configured: Path, policy: str, *, per_run: bool = False) -> None:
    """Raise `RunLogExistsError` when opening ``configured`` with ``policy`` would overwrite."""
    if policy not in LOG_POLICIES:
        raise ValueError(f"policy: expected one of {LOG_POLICIES}; got {policy!r}")
    if per_run or policy != "new":
        return
    if configured.exists() or meta_path(configured).exists():
        raise RunLogExistsError(
            f"{configured} holds an earlier run's log (its evidence is kept): --append "
            f"continues it, --replace-log replaces it, or set [run] log = "
            f"\"{configured.parent / 'logs'}/\" for one file per run")


def _first_wall_time(path: Path) -> float:
    """The first row's wall time [s since the epoch]; inf for none."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            for row in csv.DictReader(fh):
                try:
                    return float(row.get("wall_time_s") or "nan")
                except ValueError:
                    continue
    except OSError:
        pass
    return math.inf


def is_log_file(path: Path) -> bool:
    """True if the file's header is the one of a run log (its first `LOG_COLUMNS`)."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            header = next(csv.reader(fh), [])
    except (OSError, UnicodeDecodeError):
        return False
    return tuple(h.strip() for h in header[:4]) == LOG_COLUMNS[:4]


def log_parts(spec: str | Path) -> list[Path]:
    """The run-log files a file, directory or glob names, in the order they were written.

    Files whose header is not a run log's are left out; the order is that of their first
    row's wall time.
    """
    text = str(spec)
    path = Path(text)
    if path.is_dir():
        candidates = sorted(path.glob("*.csv"))
    elif any(c in text for c in "*?["):
        candidates = sorted(Path(p) for p in glob.glob(text))
    else:
        return [path]
    parts = [p for p in candidates if p.is_file() and is_log_file(p)]
    return sorted(parts, key=lambda p: (_first_wall_time(p), p.name))


__all__ = ["LOG_COLUMNS", "LOG_POLICIES", "RUN_META_FORMAT", "RunLog",
           "RunLogExistsError", "is_log_file", "log_parts", "meta_path", "open_run_log",
           "part_path", "refuse_overwrite", "run_file_name"]
