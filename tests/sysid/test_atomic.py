"""Atomic outputs: complete new content or the old file, never half a file or a stray temp."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import sysid.atomic
from sim.loop import ClosedLoopResult
from sim.scenario import Scenario
from sysid.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from sysid.data import Dataset, read_csv, write_csv
from sysid.model import HammersteinModel
from sysid.modelfile import load_model, save_model


class _DiskFullAfterHalf:
    """File wrapper whose write puts half the bytes on disk, then fails like a full disk."""

    def __init__(self, fh: Any) -> None:
        self._fh = fh

    def write(self, data: bytes) -> int:
        self._fh.write(data[: len(data) // 2])
        self._fh.flush()
        raise OSError(errno.ENOSPC, "No space left on device")

    def __enter__(self) -> _DiskFullAfterHalf:
        return self

    def __exit__(self, *exc: object) -> None:
        self._fh.close()


@pytest.fixture
def disk_full(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every atomic write fails half-way through (the temporary file holds half the data)."""
    real_open = open

    def failing_open(file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        return _DiskFullAfterHalf(real_open(file, mode, *args, **kwargs))

    monkeypatch.setattr(sysid.atomic, "open", failing_open, raising=False)


def _dataset(n: int = 5) -> Dataset:
    k = np.arange(n, dtype=float)
    return Dataset(time_s=2.0 * k, triac_pct=45.0 + 0.1 * k, power_kw=45.0 + 0.3 * k, ts_s=2.0)


def test_write_text_creates_the_file_with_exactly_the_text_and_nothing_else(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    atomic_write_text(target, "a,b\r\n1,2\n")
    assert target.read_bytes() == b"a,b\r\n1,2\n"      # newlines as given
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_write_bytes_replaces_an_existing_file(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"
    target.write_bytes(b"old content")
    atomic_write_bytes(target, b"\x00new")
    assert target.read_bytes() == b"\x00new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]


def test_written_file_gets_the_permissions_a_plain_open_gives(tmp_path: Path) -> None:
    plain = tmp_path / "plain.txt"
    with open(plain, "w", encoding="utf-8") as fh:
        fh.write("x")
    atomic_write_text(tmp_path / "atomic.txt", "x")
    assert (tmp_path / "atomic.txt").stat().st_mode == plain.stat().st_mode


def test_atomic_path_yields_a_sibling_with_the_same_suffix(tmp_path: Path) -> None:
    target = tmp_path / "figure.png"
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path
        assert tmp.suffix == ".png"
        assert tmp.exists() and not target.exists()
        tmp.write_bytes(b"png bytes")
    assert target.read_bytes() == b"png bytes"
    assert not tmp.exists()


def test_exception_inside_atomic_path_keeps_the_old_file_and_removes_the_temp(
    tmp_path: Path,
) -> None:
    target = tmp_path / "report.md"
    target.write_text("old report", encoding="utf-8")
    with pytest.raises(KeyboardInterrupt), atomic_path(target) as tmp:
        tmp.write_text("half a rep", encoding="utf-8")
        raise KeyboardInterrupt
    assert target.read_text(encoding="utf-8") == "old report"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.md"]


def test_failed_rename_removes_the_temp_and_leaves_no_target(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def failing_replace(src: object, dst: object) -> None:
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(sysid.atomic.os, "replace", failing_replace)
    with pytest.raises(OSError, match="cross-device"):
        atomic_write_text(tmp_path / "out.txt", "text")
    assert list(tmp_path.iterdir()) == []


def test_savefig_through_atomic_path_writes_a_png(tmp_path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 2))
    fig.add_subplot().plot([0, 1], [0, 1])
    target = tmp_path / "line.png"
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=20)      # format picked from the kept .png suffix
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["line.png"]


def test_missing_directory_raises_oserror_and_creates_nothing(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        atomic_write_text(tmp_path / "no" / "such" / "dir.txt", "x")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.usefixtures("disk_full")
def test_write_csv_failing_mid_write_keeps_the_old_file_and_leaves_no_temp(tmp_path: Path) -> None:
    target = tmp_path / "data.csv"
    target.write_text("old", encoding="utf-8")
    with pytest.raises(OSError, match="No space"):
        write_csv(_dataset(), target)
    assert target.read_text(encoding="utf-8") == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv"]


@pytest.mark.usefixtures("disk_full")
def test_save_model_failing_mid_write_leaves_no_file(
    tmp_path: Path, paper_armax_model: HammersteinModel
) -> None:
    with pytest.raises(OSError, match="No space"):
        save_model(paper_armax_model, tmp_path / "model.json")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.usefixtures("disk_full")
def test_closed_loop_csv_failing_mid_write_leaves_no_file(tmp_path: Path) -> None:
    scenario = Scenario(name="flat", duration_s=6.0, initial_setpoint_kw=45.0)
    result = ClosedLoopResult(
        scenario=scenario, seed=1, time_s=scenario.time_s(), setpoint_kw=[45.0] * 3,
        power_measured_kw=[45.0, float("nan"), 45.1], power_true_kw=[45.0] * 3,
        triac_pct=[45.0] * 3, step_time_s=[1e-4] * 3,
    )
    with pytest.raises(OSError, match="No space"):
        result.to_csv(tmp_path / "run.csv")
    assert list(tmp_path.iterdir()) == []


def test_the_switched_writers_still_round_trip(
    tmp_path: Path, paper_armax_model: HammersteinModel
) -> None:
    data = _dataset()
    write_csv(data, tmp_path / "data.csv")
    back = read_csv(tmp_path / "data.csv")
    np.testing.assert_array_equal(back.power_kw, data.power_kw)
    save_model(paper_armax_model, tmp_path / "model.json")
    np.testing.assert_array_equal(load_model(tmp_path / "model.json").b, paper_armax_model.b)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.csv", "model.json"]
    assert os.access(tmp_path / "data.csv", os.R_OK)


def test_identification_figure_failing_mid_save_leaves_no_png(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from matplotlib.figure import Figure

    from czmpc.reports.identification_figures import plot_dataset

    def half_then_fail(self: Figure, fname: Any, *args: Any, **kwargs: Any) -> None:
        Path(fname).write_bytes(b"\x89PNG half")
        raise MemoryError("renderer ran out of memory")

    monkeypatch.setattr(Figure, "savefig", half_then_fail)
    t = np.arange(5.0)
    with pytest.raises(MemoryError):
        plot_dataset(t, 45.0 + t, 45.0 + t, path=tmp_path / "fig2.png")
    assert list(tmp_path.iterdir()) == []
