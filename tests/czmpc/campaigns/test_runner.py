"""Executors give the same rows; an interrupted campaign resumes to the same table."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from czmpc.campaigns.campaign import DETERMINISTIC_COLUMNS, CampaignError, spec_from_dict
from czmpc.campaigns.runner import RESULTS_FILE, ROWS_FILE, read_results, run_campaign

SPEC = {
    "name": "tiny", "seeds": 2, "base_seed": 11, "time_scale": 0.02, "scenarios": ["staircase"],
    "controllers": [{"name": "mpc", "preset": "mpc"}, {"name": "pi", "preset": "pi"}],
    "plants": [{"kind": "model"}, {"kind": "sampled", "n": 1},
               {"kind": "perturbed", "gain_factors": [0.8],
                "time_constant_factors": [2.0], "extra_delays_steps": [1]}],
}


def _det(rows: list[dict[str, Any]]) -> list[tuple[Any, ...]]:
    """Deterministic columns; NaN replaced by a marker so equal rows compare equal."""
    return [tuple("nan" if isinstance(v, float) and math.isnan(v) else v
                  for v in (r[c] for c in DETERMINISTIC_COLUMNS)) for r in rows]


@pytest.fixture(scope="module")
def serial_rows(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    out = tmp_path_factory.mktemp("serial")
    run_campaign(spec_from_dict(SPEC), out)
    return read_results(out)


def test_serial_table_has_one_ok_row_per_run(serial_rows: list[dict[str, Any]]) -> None:
    assert len(serial_rows) == 12
    assert all(r["status"] == "ok" for r in serial_rows)
    assert len({r["iae_kw_s"] for r in serial_rows}) == 12


@pytest.mark.slow
def test_process_executor_gives_identical_rows(serial_rows: list[dict[str, Any]], tmp_path: Path) -> None:
    run_campaign(spec_from_dict(SPEC), tmp_path, executor="processes", workers=2)
    assert _det(read_results(tmp_path)) == _det(serial_rows)


@pytest.mark.slow
def test_dask_local_cluster_gives_identical_rows(serial_rows: list[dict[str, Any]], tmp_path: Path) -> None:
    pytest.importorskip("dask.distributed")
    t0 = time.perf_counter()
    run_campaign(spec_from_dict(SPEC), tmp_path, executor="dask", workers=2, dask_address="local")
    assert time.perf_counter() - t0 < 120.0
    assert _det(read_results(tmp_path)) == _det(serial_rows)


def test_interrupted_then_resumed_equals_uninterrupted(serial_rows: list[dict[str, Any]],
                                                       tmp_path: Path) -> None:
    spec = spec_from_dict(SPEC)
    first = run_campaign(spec, tmp_path, max_runs=3)
    assert first.n_run == 3 and not (tmp_path / RESULTS_FILE).exists()
    # a torn last line, as a process killed while writing leaves it
    with (tmp_path / ROWS_FILE).open("a", encoding="utf-8") as fh:
        fh.write('{"run_id": "mpc|model|stair')
    second = run_campaign(spec, tmp_path)
    assert (second.n_skipped, second.n_run) == (3, 9)
    assert _det(read_results(tmp_path)) == _det(serial_rows)
    lines = (tmp_path / ROWS_FILE).read_text(encoding="utf-8").splitlines()
    assert len(lines) == 12 and len({json.loads(x)["run_id"] for x in lines}) == 12


@pytest.mark.slow
def test_killed_process_resumes_to_the_same_table(serial_rows: list[dict[str, Any]],
                                                  tmp_path: Path) -> None:
    spec_file = tmp_path / "tiny.toml"
    lines = [f"{k} = {json.dumps(v)}" for k, v in SPEC.items() if not isinstance(v, list)
             or not isinstance(v[0], dict)]
    for c in SPEC["controllers"]:  # type: ignore[attr-defined]
        lines += ["[[controllers]]", *(f"{k} = {json.dumps(v)}" for k, v in c.items())]
    for p in SPEC["plants"]:  # type: ignore[attr-defined]
        lines += ["[[plants]]", *(f"{k} = {json.dumps(v)}" for k, v in p.items())]
    spec_file.write_text("\n".join(lines) + "\n", encoding="utf-8")
    out = tmp_path / "out"
    cmd = [str(Path(sys.executable).parent / "czmpc"), "campaign", "run", str(spec_file), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rows = out / ROWS_FILE
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline and proc.poll() is None:
        if rows.is_file() and len(rows.read_text(encoding="utf-8").splitlines()) >= 2:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    n_before = len(rows.read_text(encoding="utf-8").splitlines())
    assert 2 <= n_before < 12, "the kill came too late to test a resume"
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    assert f"{12 - n_before} run now" in done.stdout or "resumed" in done.stdout
    assert _det(read_results(out)) == _det(serial_rows)


def test_a_directory_of_another_spec_is_refused(tmp_path: Path) -> None:
    run_campaign(spec_from_dict(SPEC), tmp_path, max_runs=1)
    with pytest.raises(CampaignError, match="another spec"):
        run_campaign(spec_from_dict({**SPEC, "base_seed": 12}), tmp_path)


def test_bad_executor_and_workers_are_refused(tmp_path: Path) -> None:
    with pytest.raises(CampaignError, match="'threads'"):
        run_campaign(spec_from_dict(SPEC), tmp_path, executor="threads")  # type: ignore[arg-type]
    with pytest.raises(CampaignError, match="workers"):
        run_campaign(spec_from_dict(SPEC), tmp_path, workers=0)


def test_env_pins_blas_in_workers() -> None:
    from czmpc.campaigns.runner import pin_blas_threads

    pin_blas_threads()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"


def test_dask_batches_keep_every_run_once_in_order() -> None:
    from czmpc.campaigns.runner import DASK_BATCH_MAX, dask_batches

    runs = list(range(10_001))
    batches = dask_batches(runs, 2)   # type: ignore[arg-type]
    assert [r for b in batches for r in b] == runs
    assert max(len(b) for b in batches) == DASK_BATCH_MAX
    small = dask_batches(list(range(30)), 2)   # type: ignore[arg-type]
    assert [len(b) for b in small] == [1] * 30      # few runs: one per task, all workers busy
