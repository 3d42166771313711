"""A czmpc run log read as identification data: applied input, gaps, fills, provenance."""

from __future__ import annotations

import datetime as dt
import json
import math
from pathlib import Path

import numpy as np
import pytest

from czmpc.runtime.config import RunConfigError
from czmpc.runtime.logfiles import LOG_COLUMNS, RunLog, meta_path
from czmpc.runtime.runlog import (
    MIN_SEGMENT_SAMPLES,
    describe_run_data,
    is_run_log,
    read_run_log,
)
from tests.tolerances import IDENTITY_RTOL


def _write(path: Path, ks: list[int], quality: dict[int, str], *, closed: bool) -> None:
    """Rows k with power 40 + k/10, command 30 + k, applied = previous command; one safe-ramp row."""
    log = RunLog(path, {"ts_s": 2.0, "kind": "test kind", "closed_loop": closed,
                        "schedule_sha256": "ab" * 32, "start_utc": "2026-01-01T00:00:00+00:00",
                        "czmpc_version": "9.9", "model_sha256": "cd" * 32})
    prev_cmd = math.nan
    for k in ks:
        log.row({c: "" for c in LOG_COLUMNS} | {
            "k": k, "time_s": 2.0 * k, "power_kw": 40.0 + k / 10, "quality": quality.get(k, "good"),
            "triac_pct": 30.0 + k, "applied_triac_pct": 30.0 + k - 1 if k - 1 in ks else prev_cmd,
            "status": "TEST"})
        prev_cmd = 30.0 + k
    log.row({c: "" for c in LOG_COLUMNS} | {"triac_pct": 20.0, "status": "SAFE_RAMP"})
    log.close()


def test_applied_input_and_gaps(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    # k = 0..59 logged except 20 (one skipped period) and 40..44 (five skipped); 30 and 31
    # are Bad quality: every one of them is a gap
    ks = [k for k in range(60) if k != 20 and not 40 <= k <= 44]
    _write(path, ks, {30: "bad", 31: "stale"}, closed=False)
    assert is_run_log(path)
    data = read_run_log(path)
    # segments: 0..19, 21..29 (9 samples) and 32..39 (8: both too short, dropped), 45..59
    assert 30 - 21 < MIN_SEGMENT_SAMPLES and 40 - 32 < MIN_SEGMENT_SAMPLES
    expected_k = np.r_[0:20, 45:60]
    np.testing.assert_allclose(data.time_s, 2.0 * expected_k, rtol=IDENTITY_RTOL)
    assert data.segment_starts == (0, 20)
    np.testing.assert_allclose(data.power_kw, 40.0 + expected_k / 10, rtol=IDENTITY_RTOL)
    # input of sample k: the applied input published at k + 1 (= command k here); at
    # k = 19 the next row is missing, so the command written at 19
    u = data.triac_pct
    np.testing.assert_allclose(u[:20], 30.0 + np.arange(20), rtol=IDENTITY_RTOL)
    info, split = data.preprocessing[0], data.preprocessing[1]
    assert info["what"] == "czmpc run log" and info["closed_loop"] is False
    assert info["schedule_sha256"] == "ab" * 32
    assert (info["czmpc_version"], info["model_sha256"]) == ("9.9", "cd" * 32)
    assert split["segments"] == 2 and split["samples_kept"] == 35
    assert data.sha256 is not None
    assert "CLOSED-LOOP" not in describe_run_data(data)


def test_closed_loop_logs_say_so(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    _write(path, list(range(30)), {}, closed=True)
    data = read_run_log(path)
    assert data.preprocessing[0]["closed_loop"] is True
    assert "CLOSED-LOOP" in describe_run_data(data)


def test_a_log_without_usable_stretch_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    _write(path, list(range(30)), {k: "bad" for k in range(0, 30, 5)}, closed=False)
    with pytest.raises(RunConfigError, match="usable samples in a row"):
        read_run_log(path)


def test_meta_file_sits_beside_the_log(tmp_path: Path) -> None:
    assert meta_path(tmp_path / "run.csv") == tmp_path / "run.meta.json"
    plain = tmp_path / "plain.csv"
    plain.write_text("time_s,triac_pct,power_kw\n0,1,2\n", encoding="utf-8")
    assert not is_run_log(plain)


def test_a_rotated_log_is_read_as_one_and_each_part_has_its_meta(tmp_path: Path) -> None:
    """Parts written by size rotation join up without a gap; a restart leaves one."""
    from czmpc.runtime.logfiles import log_parts, open_run_log
    from czmpc.runtime.runlog import read_run_log as read_dataset

    def rows(log: RunLog, n: int, start_wall: float) -> None:
        for k in range(n):
            log.row({c: "" for c in LOG_COLUMNS} | {
                "k": k, "time_s": 2.0 * k, "wall_time_s": start_wall + 2.0 * k,
                "power_kw": 30.0 + 0.01 * k, "quality": "good", "triac_pct": 40.0 + 0.1 * (k % 7),
                "applied_triac_pct": 40.0 + 0.1 * ((k - 1) % 7), "status": "GOOD"})

    meta = {"ts_s": 2.0, "time_scale": 1.0}
    log = open_run_log(tmp_path / "logs", meta, per_run=True, rotate_bytes=2000)
    rows(log, 120, 1000.0)
    log.close()
    parts = log_parts(tmp_path / "logs")
    assert len(parts) >= 3                                 # rotated by size
    metas = [json.loads(meta_path(p).read_text(encoding="utf-8")) for p in parts]
    assert [m.get("part", 1) for m in metas] == list(range(1, len(parts) + 1))
    assert all(m["ts_s"] == 2.0 for m in metas)
    one = read_dataset(tmp_path / "logs")
    assert one.n_samples == 120 and one.n_segments == 1
    # a restart 100 s later: its own file; read together, a gap of the wall time between
    later = open_run_log(tmp_path / "logs", meta, per_run=True,
                         now=dt.datetime(2031, 1, 1, tzinfo=dt.UTC))
    rows(later, 30, 1000.0 + 2.0 * 119 + 100.0)     # 100 s after the first run's last row
    later.close()
    both = read_dataset(tmp_path / "logs")
    assert both.n_segments == 2 and both.n_samples == 120 + 30
    split = next(p for p in both.preprocessing if p.get("what") == "split at unusable samples")
    (_, end0), (start1, _) = split["segment_time_s"]
    assert start1 - end0 == pytest.approx(100.0)    # the wall time between them, time scale 1
