"""Read a `czmpc run` log (and its ``<log>.meta.json``) as identification data.

The log of `czmpc run` (an open-loop test, a dithered MPC or a plain MPC run) is read
directly by `czmpc identify`. The rules:

- rows without a sample index (the safe ramp after a stop) are not data;
- the input of row ``j`` is the input that acted from sample ``j`` to ``j + 1``: the
  applied input the plant publishes at row ``j + 1`` where it does, else the command
  written at row ``j`` (the plant applies a command over the sample after it arrives
  and publishes it with the power it produced);
- a sample whose quality is not Good (Bad, Uncertain, stale, repeated, disconnected) is a gap,
  and so is every period the loop skipped after an overrun (nothing was read there;
  the heater's power jumps at a step, so no interpolation is right just after one: on a
  loopback journey whose overruns fell just after steps, filling them by
  interpolation gave a held-out fit of 53 %, gaps 95 %); the data are split into
  segments at the gaps (`sysid.data.Dataset.segment_starts`), each identified
  with its own initial state; segments shorter than `MIN_SEGMENT_SAMPLES` are dropped;
- the provenance (config and its SHA-256, schedule and its SHA-256, start time, what
  drove the input, closed loop or not) goes into the data set's ``preprocessing`` and
  from there into the model file.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from czmpc.runtime.config import RunConfigError
from czmpc.runtime.loop import LOG_COLUMNS, RUN_META_FORMAT, meta_path
from sysid.data import Dataset

#: Shortest segment kept between gaps [samples]: shorter ones carry too little to fit
#: an initial state and a model (a model of the paper's orders has 5 parameters).
MIN_SEGMENT_SAMPLES = 10
#: The columns that mark a file as a czmpc run log (the first of `LOG_COLUMNS`).
_SIGNATURE = LOG_COLUMNS[:4]


def is_run_log(path: str | Path) -> bool:
    """True if the file's header is the one of a `czmpc run` log."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            header = next(csv.reader(fh), [])
    except (OSError, UnicodeDecodeError):
        return False
    return tuple(h.strip() for h in header[:len(_SIGNATURE)]) == _SIGNATURE


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
    path = Path(path)
    raw = path.read_bytes()
    rows = list(csv.DictReader(raw.decode("utf-8-sig").splitlines()))
    missing = [c for c in ("k", "time_s", "power_kw", "quality", "triac_pct", "applied_triac_pct")
               if rows and c not in rows[0]]
    if not rows or missing:
        raise RunConfigError(f"{path}: not a czmpc run log with data (missing columns {missing})")
    rows = [r for r in rows if r["k"].strip() != ""]
    meta = read_run_meta(path)
    ks = np.array([int(_float(r["k"])) for r in rows])
    if ks.size < MIN_SEGMENT_SAMPLES or (np.diff(ks) <= 0).any():
        raise RunConfigError(f"{path}: expected at least {MIN_SEGMENT_SAMPLES} rows with an "
                             "increasing sample index k")
    ts_s = float(meta.get("ts_s") or _float(rows[1]["time_s"]) / max(1, int(ks[1])))
    # one slot per sample period k, also for the periods the loop skipped after an overrun
    n = int(ks[-1] - ks[0]) + 1
    slot = ks - ks[0]
    power = np.full(n, np.nan)
    command = np.full(n, np.nan)
    applied = np.full(n, np.nan)
    logged = np.zeros(n, dtype=bool)
    logged[slot] = True
    power[slot] = [_float(r["power_kw"]) if r["quality"] == "good" else math.nan for r in rows]
    command[slot] = [_float(r["triac_pct"]) for r in rows]
    applied[slot] = [_float(r["applied_triac_pct"]) for r in rows]
    # the command stays written through skipped periods: hold it there
    for i in range(1, n):
        if not logged[i]:
            command[i] = command[i - 1]
    triac = command.copy()
    nxt = applied[1:]
    triac[:-1] = np.where(np.isfinite(nxt), nxt, command[:-1])
    usable = np.isfinite(power) & np.isfinite(triac)
    starts: list[int] = []
    stops: list[int] = []
    i = 0
    while i < n:
        if not usable[i]:
            i += 1
            continue
        j = i
        while j < n and usable[j]:
            j += 1
        starts.append(i)
        stops.append(j)
        i = j
    kept = [(a, b) for a, b in zip(starts, stops, strict=True) if b - a >= MIN_SEGMENT_SAMPLES]
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
                                "start_utc", "endpoint", "model", "dither") if k in meta},
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
    return Dataset(
        time_s=time_s[index], triac_pct=triac[index], power_kw=power[index], ts_s=ts_s,
        source=str(path), sha256=hashlib.sha256(raw).hexdigest(),
        preprocessing=(provenance, split), segment_starts=seg_starts)


def describe_run_data(data: Dataset) -> str:
    """One paragraph for the terminal: what kind of run the data come from and what it implies."""
    info = next((p for p in data.preprocessing if p.get("what") == "czmpc run log"), None)
    if info is None:
        return ""
    empty: dict[str, Any] = {}
    split = next((p for p in data.preprocessing if p.get("what") == "split at unusable samples"),
                 empty)
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
           "read_run_meta"]
