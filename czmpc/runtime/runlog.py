"""Read a `czmpc run` log (and its ``<log>.meta.json``) as identification data or a report's record.

`czmpc identify` reads the log of `czmpc run` (an open-loop test, a dithered or a plain
MPC run) directly. The rules:

- rows without a sample index (the safe ramp after a stop) are not data;
- the input of row ``j`` acted from sample ``j`` to ``j + 1``: the applied input the
  plant publishes at row ``j + 1`` where it does, else the command written at row ``j``;
- a sample that is not Good (Bad, Uncertain, stale, repeated, disconnected) is a gap, and
  so is every period skipped after an overrun (the power jumps at a step, so no
  interpolation is right there; measured on a loopback journey: held-out fit 53 %
  interpolated, 95 % with gaps); the data are split into segments at the gaps
  (`sysid.data.Dataset.segment_starts`), each with its own initial state; segments
  shorter than `MIN_SEGMENT_SAMPLES` are dropped;
- the provenance (config, schedule and their SHA-256, start time, what drove the input,
  closed loop or not) goes into the data set's ``preprocessing``, then the model file.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from czmpc.reports.run_report import RunRecord
from czmpc.runtime.config import RunConfigError
from czmpc.runtime.logfiles import RUN_META_FORMAT, is_log_file, log_parts, meta_path
from sysid._arrays import true_runs
from sysid._typing import FloatArray
from sysid.data import Dataset

#: Shortest segment kept between gaps [samples] (a model of the paper's orders has 5
#: parameters, and each segment its initial state).
MIN_SEGMENT_SAMPLES = 10


def is_run_log(path: str | Path) -> bool:
    """True if the file's header is the one of a `czmpc run` log, or a directory or glob
    names such files (a rotated log, several runs: `czmpc.runtime.logfiles.log_parts`)."""
    return any(is_log_file(part) for part in log_parts(path))


def read_run_meta(log_path: str | Path) -> dict[str, Any]:
    """The run's provenance (``<log>.meta.json``), or ``{}`` if there is none."""
    path = meta_path(Path(log_path))
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RunConfigError(f"{path}: not a readable run provenance file: {exc}") from exc
    if not isinstance(doc, dict) or doc.get("format") != RUN_META_FORMAT:
        raise RunConfigError(f"{path}: expected a JSON object with format {RUN_META_FORMAT!r}")
    return doc


def _float(cell: str) -> float:
    try:
        return float(cell)
    except ValueError:
        return math.nan


def read_run_log(path: str | Path) -> Dataset:
    """Read a `czmpc run` log as a data set (module docstring for the rules).

    Raises
    ------
    RunConfigError
        Not a run log, missing columns, or fewer than `MIN_SEGMENT_SAMPLES` usable
        samples in a row anywhere.
    """
    parts = log_parts(path)
    rows, slots, meta, digest, _ = _joined_rows(path, parts)
    if len(rows) < MIN_SEGMENT_SAMPLES:
        raise RunConfigError(f"{path}: expected at least {MIN_SEGMENT_SAMPLES} rows with a "
                             "sample index k")
    ks = np.asarray(slots)
    ts_s = _ts_s(rows, meta)
    # one slot per sample period k, also for the periods the loop skipped after an overrun
    n = int(ks[-1] - ks[0]) + 1
    slot = ks - ks[0]
    power, command, applied = np.full((3, n), np.nan)
    power[slot] = [_float(r["power_kw"]) if r["quality"] == "good" else math.nan for r in rows]
    command[slot] = [_float(r["triac_pct"]) for r in rows]
    applied[slot] = [_float(r["applied_triac_pct"]) for r in rows]
    # the command stays written through skipped periods: hold it there
    logged = np.zeros(n, dtype=bool)
    logged[slot] = True
    for i in range(1, n):
        if not logged[i]:
            command[i] = command[i - 1]
    triac = command.copy()
    nxt = applied[1:]
    triac[:-1] = np.where(np.isfinite(nxt), nxt, command[:-1])
    usable = np.isfinite(power) & np.isfinite(triac)
    kept = [(a, b) for a, b in true_runs(usable) if b - a >= MIN_SEGMENT_SAMPLES]
    if not kept:
        raise RunConfigError(
            f"{path}: no stretch of {MIN_SEGMENT_SAMPLES} or more usable samples in a row "
            f"(Good quality, known input); {int(usable.sum())} usable of {n}")
    index = np.concatenate([np.arange(a, b) for a, b in kept])
    time_s = (ks[0] + np.arange(n)) * ts_s
    seg_starts = tuple(int(v) for v in np.cumsum([0] + [b - a for a, b in kept[:-1]]))
    closed = bool(meta.get("closed_loop", any(r.get("status", "") not in ("", "LEAD_IN", "TEST")
                                              for r in rows)))
    provenance: dict[str, Any] = {
        "what": "czmpc run log",
        "kind": meta.get("kind", "closed-loop run" if closed else "open-loop run"),
        "closed_loop": closed,
        "input": "applied input published at the next sample, else the command",
        **{k: meta[k] for k in ("config", "config_sha256", "schedule", "schedule_sha256",
                                "start_utc", "endpoint", "model", "model_sha256", "czmpc_version",
                                "dither") if k in meta},
    }
    split: dict[str, Any] = {
        "what": "split at unusable samples",
        "rule": f"Bad/Uncertain/stale/disconnected samples and periods skipped by the loop "
                f"are gaps; segments shorter than {MIN_SEGMENT_SAMPLES} samples dropped",
        "samples_in_log": int(ks.size), "periods": n,
        "samples_kept": int(index.size),
        "segments": len(kept),
        "segment_time_s": [[float(time_s[a]), float(time_s[b - 1])] for a, b in kept],
    }
    if len(parts) > 1:
        provenance["parts"] = [str(p) for p in parts]
    return Dataset(
        time_s=time_s[index], triac_pct=triac[index], power_kw=power[index], ts_s=ts_s,
        source=str(path), sha256=digest,
        preprocessing=(provenance, split), segment_starts=seg_starts)


def read_run_record(path: str | Path) -> RunRecord:
    """A run log (a file, a directory or a glob of its parts) for the operator's report.

    The parts join as for identification (`read_run_log`): a step's plant time is its
    sample period on one axis; a later run follows after the wall time between the runs.

    Raises
    ------
    RunConfigError
        Not a run log (missing columns), or no step row.
    """
    parts = log_parts(path)
    rows, slots, meta, _, n_safe = _joined_rows(path, parts)
    if not rows:
        raise RunConfigError(f"{path}: expected at least one step row; got none")

    def arr(column: str) -> FloatArray:
        return np.asarray([_float(r.get(column) or "nan") for r in rows])

    def words(column: str) -> tuple[str, ...]:
        return tuple(r.get(column) or "" for r in rows)

    return RunRecord(
        source=", ".join(str(p) for p in parts), time_s=np.asarray(slots) * _ts_s(rows, meta),
        power_kw=arr("power_kw"), setpoint_kw=arr("setpoint_kw"), triac_pct=arr("triac_pct"),
        applied_triac_pct=arr("applied_triac_pct"), predicted_kw=arr("predicted_kw"),
        good=np.asarray(words("quality")) == "good", mode=words("mode"),
        written=np.nan_to_num(arr("written")) > 0, lateness_s=arr("lateness_s"),
        latency_s=arr("step_latency_s"), skipped=np.nan_to_num(arr("skipped")).astype(int),
        health=arr("health"), stale_alarm=np.nan_to_num(arr("stale_alarm")) > 0,
        candidate_predicted_kw=arr("candidate_predicted_kw"), n_safe_rows=n_safe,
        status=words("status"), connected=np.asarray(words("connected")) != "0",
        event=words("event"))


def _ts_s(rows: list[dict[str, str]], meta: dict[str, Any]) -> float:
    """The run's sampling time [s]: from its meta file, else from the rows' time and index."""
    if meta.get("ts_s"):
        return float(meta["ts_s"])
    k = next((int(_float(r["k"])) for r in rows if _float(r["k"]) > 0), 1)
    return next((_float(r["time_s"]) for r in rows if _float(r["k"]) == k), 1.0) / k


def _joined_rows(path: str | Path, parts: list[Path],
                 ) -> tuple[list[dict[str, str]], list[int], dict[str, Any], str, int]:
    """The step rows of ``path``'s parts as one log: (rows, slot of each row, first meta,
    SHA-256, rows without a sample index: the safe action's).

    A row's slot is its sample period on one axis. The parts of one run (meta ``part`` >
    1) continue its sample index; a new run (a part without ``part``, or the index
    starting again within a file appended to) begins after a gap of at least one empty
    slot, as long as the wall time between the runs at the run's period.
    """
    if not parts:
        raise RunConfigError(f"{path}: no czmpc run log there (a file, a directory or a glob "
                             "of run logs)")
    rows: list[dict[str, str]] = []
    slots: list[int] = []
    n_unindexed = 0
    digest = hashlib.sha256()
    first_meta: dict[str, Any] = {}
    offset = 0          # slot of sample index 0 of the current run
    last_k: int | None = None
    last_wall = math.nan
    period_wall = math.nan
    for i, part in enumerate(parts):
        try:
            raw = part.read_bytes()
        except OSError as exc:
            raise RunConfigError(f"{part}: cannot read: {exc.strerror}") from exc
        digest.update(raw)
        part_rows = list(csv.DictReader(raw.decode("utf-8-sig").splitlines()))
        missing = [c for c in ("k", "time_s", "power_kw", "quality", "triac_pct",
                               "applied_triac_pct") if part_rows and c not in part_rows[0]]
        if missing:
            raise RunConfigError(f"{part}: not a czmpc run log with data (missing columns "
                                 f"{missing})")
        meta = read_run_meta(part)
        if i == 0:
            first_meta = meta
        elif meta.get("ts_s") and first_meta.get("ts_s") and meta["ts_s"] != first_meta["ts_s"]:
            raise RunConfigError(f"{part}: Ts {meta['ts_s']} s differs from {parts[0]}'s "
                                 f"{first_meta['ts_s']} s; read them separately")
        if meta.get("ts_s"):
            period_wall = float(meta["ts_s"]) / float(meta.get("time_scale") or 1.0)
        new_run_part = i > 0 and int(meta.get("part", 1)) <= 1
        for row in part_rows:
            if row["k"].strip() == "":
                n_unindexed += 1
                continue
            k = int(_float(row["k"]))
            wall = _float(row.get("wall_time_s", "") or "nan")
            if last_k is not None and (new_run_part or k <= last_k):
                gap = (wall - last_wall) / period_wall if period_wall > 0 else math.nan
                next_free = offset + last_k + 2    # at least one empty slot: a gap
                offset = max(next_free, offset + last_k + round(gap)
                             if math.isfinite(gap) else next_free) - k
                new_run_part = False
            rows.append(row)
            slots.append(offset + k)
            last_k, last_wall = k, wall
    return rows, slots, first_meta, digest.hexdigest(), n_unindexed


def describe_run_data(data: Dataset) -> str:
    """One paragraph for the terminal: what kind of run the data come from and what it implies."""
    info = next((p for p in data.preprocessing if p.get("what") == "czmpc run log"), None)
    if info is None:
        return ""
    split = next((p for p in data.preprocessing if p.get("what") == "split at unusable samples"),
                 {})
    text = (f"{data.source} is a czmpc run log ({info.get('kind')}): {data.n_samples} samples in "
            f"{data.n_segments} segment(s) of {split.get('samples_in_log', '?')} logged; the input "
            f"is the plant's applied input where published.")
    if info.get("closed_loop"):
        text += (" CLOSED-LOOP DATA: the MPC computed the input from the measured power, so the "
                 "input is correlated with past noise. The noise-model Hammerstein (model.json, "
                 "direct prediction-error method) stays consistent when its noise model is right "
                 "and the data are informative (the dither makes them so); output-error (OE) and "
                 "ballistic-criterion fits in the report are biased on such data.")
    return text


__all__ = ["MIN_SEGMENT_SAMPLES", "describe_run_data", "is_run_log", "read_run_log",
           "read_run_meta", "read_run_record"]
