"""Run a campaign on one executor into a resumable campaign directory.

Directory layout (``DIR``):

* ``campaign.json``: the spec as run (name, source, the runs' identities) and its digest;
  a directory started with another spec is refused;
* ``rows.jsonl``: one JSON row per finished run, appended and flushed as each run ends.
  After an interruption the runs already there are skipped; a torn last line (the
  process killed while writing it) is dropped and that run is run again, so nothing
  is duplicated or lost;
* ``results.parquet``: all rows in the campaign's run order, written when every run
  is done (`ROW_COLUMNS`);
* ``trajectories/<n>.npz``: the trajectories asked for (`save_trajectories`), float32.

Executors: ``serial`` (this process), ``processes`` (a `ProcessPoolExecutor` of N
spawned workers) and ``dask`` (a `dask.distributed` LocalCluster of N one-thread worker
processes on 127.0.0.1, or the scheduler at an address). BLAS is pinned to one thread in
every worker through the environment it inherits (`pin_blas_threads`).
"""

from __future__ import annotations

import hashlib
import importlib
import json
import logging
import math
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np

from czmpc.campaigns.campaign import (
    ROW_COLUMNS,
    CampaignError,
    CampaignSpec,
    RunSpec,
    execute_run,
    simulate_run,
)

ExecutorName = Literal["serial", "processes", "dask"]
EXECUTORS: tuple[str, ...] = ("serial", "processes", "dask")
CAMPAIGN_FILE = "campaign.json"
ROWS_FILE = "rows.jsonl"
RESULTS_FILE = "results.parquet"
TRAJECTORY_DIR = "trajectories"
_BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_T = TypeVar("_T")
_R = TypeVar("_R")
#: ``progress(done, total)`` after each finished run.
ProgressCallback = Callable[[int, int], None]


@dataclass(frozen=True, kw_only=True)
class CampaignOutcome:
    """What `run_campaign` did.

    Parameters
    ----------
    rows :
        Every row of the campaign, in run order.
    n_skipped :
        Runs found done in the directory (not run again).
    n_run :
        Runs executed by this call.
    n_errors :
        Rows with ``status == "error"``.
    results_path :
        The Parquet table.
    """

    rows: tuple[dict[str, Any], ...]
    n_skipped: int
    n_run: int
    n_errors: int
    results_path: Path


def pin_blas_threads() -> None:
    """Set one BLAS/OpenMP thread for this process and the workers it starts."""
    for var in _BLAS_VARS:
        os.environ[var] = "1"


def spec_digest(spec: CampaignSpec) -> str:
    """SHA-256 of the runs' identities and everything they depend on."""
    text = json.dumps([repr(r) for r in spec.expand()], sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _read_rows(path: Path) -> dict[str, dict[str, Any]]:
    """Rows of ``rows.jsonl`` by run id; a torn (unparsable) line is dropped."""
    rows: dict[str, dict[str, Any]] = {}
    if not path.is_file():
        return rows
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(row, dict) and "run_id" in row:
            rows[str(row["run_id"])] = row
    return rows


def _rewrite_clean(path: Path, rows: dict[str, dict[str, Any]]) -> None:
    """Rewrite ``rows.jsonl`` with only whole rows (drops a torn last line before appending)."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(json.dumps(r, allow_nan=True) + "\n" for r in rows.values()),
                   encoding="utf-8")
    os.replace(tmp, path)


def _prepare_dir(spec: CampaignSpec, out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    record = {"format": "czmpc-campaign/1", "name": spec.name, "source": spec.source,
              "digest": spec_digest(spec), "n_runs": len(spec.expand()),
              "warnings": list(spec.warnings)}
    path = out_dir / CAMPAIGN_FILE
    if path.is_file():
        old = json.loads(path.read_text(encoding="utf-8"))
        if old.get("digest") != record["digest"]:
            raise CampaignError(
                f"campaign directory {out_dir} holds campaign '{old.get('name')}' run from another "
                f"spec ({old.get('source')}); use a new --out directory")
        return
    path.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")


def map_runs(fn: Callable[[_T], _R], items: Sequence[_T], *, executor: str = "serial",
             workers: int = 1, dask_address: str = "local") -> Iterator[tuple[int, _R]]:
    """``(i, fn(items[i]))`` for every item, as each finishes: the one executor map.

    Parameters
    ----------
    fn :
        A module-level function (it is pickled to the workers); each call is pure.
    items :
        Its arguments (picklable).
    executor :
        ``"serial"`` (this process), ``"processes"`` (spawned workers) or ``"dask"``.
    workers :
        Worker processes of ``processes`` and of a local Dask cluster, >= 1.
    dask_address :
        ``"local"`` or a scheduler address such as ``"tcp://10.0.0.5:8786"``.

    Raises
    ------
    CampaignError
        Unknown executor, bad worker count, Dask missing.
    """
    if executor not in EXECUTORS:
        raise CampaignError(f"expected executor one of {list(EXECUTORS)}; got {executor!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise CampaignError(f"expected workers an integer >= 1; got {workers!r}")
    if executor == "serial" or not items:
        for i, item in enumerate(items):
            yield i, fn(item)
    elif executor == "processes":
        pin_blas_threads()
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
            futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
            try:
                for future in as_completed(futures):
                    yield futures[future], future.result()
            finally:
                for future in futures:
                    future.cancel()
    else:
        batches = dask_batches(list(range(len(items))), workers)
        with dask_client(workers, dask_address) as (distributed, client):
            futures = client.map(execute_batch, [fn] * len(batches),
                                 [[items[i] for i in b] for b in batches], pure=False)
            index = {f.key: b for f, b in zip(futures, batches, strict=True)}
            for future in distributed.as_completed(futures):
                yield from zip(index[future.key], future.result(), strict=True)


@contextmanager
def dask_client(workers: int, address: str) -> Iterator[tuple[Any, Any]]:
    """``(dask.distributed, client)``: a local cluster or a scheduler, closed on exit.

    Parameters
    ----------
    workers :
        Worker processes of a ``LocalCluster`` (one thread each, on 127.0.0.1 only, no
        dashboard), for ``address == "local"``.
    address :
        ``"local"`` or a scheduler address such as ``tcp://host:8786``.

    Raises
    ------
    CampaignError
        dask.distributed is not installed (the ``czmpc[dask]`` extra).
    """
    try:  # untyped library: used through Any
        distributed: Any = importlib.import_module("dask.distributed")
    except ImportError:
        raise CampaignError("the dask executor needs dask.distributed: pip install 'czmpc[dask]'") from None
    pin_blas_threads()
    cluster = None
    if address == "local":
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                           host="127.0.0.1", dashboard_address=None,
                                           silence_logs=logging.CRITICAL)
        client = distributed.Client(cluster)
    else:
        client = distributed.Client(address)
    try:
        yield distributed, client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


#: Largest number of runs one Dask task carries. A run of a short scenario takes about
#: 25 ms; a task costs the scheduler and the worker about a millisecond each way, and on
#: a 2-core machine the scheduler competes with the workers for the cores (10,000 one-run
#: tasks: efficiency 0.64). Batches cut the task count by this factor; a batch's rows
#: arrive together, and an interrupted campaign re-runs at most the batches in flight.
DASK_BATCH_MAX = 25


def execute_batch(fn: Callable[[_T], _R], items: Sequence[_T]) -> list[_R]:
    """``fn`` of each item of a batch, in order (a Dask task)."""
    return [fn(item) for item in items]


def dask_batches(items: Sequence[_T], workers: int) -> list[list[_T]]:
    """Items cut into batches of at most `DASK_BATCH_MAX`, at least 20 per worker."""
    size = max(1, min(DASK_BATCH_MAX, len(items) // (20 * max(1, workers))))
    return [list(items[i:i + size]) for i in range(0, len(items), size)]


def write_parquet(rows: Sequence[dict[str, Any]], path: Path) -> None:
    """Write rows as one Parquet table with the columns `ROW_COLUMNS` (atomic replace)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pylist([{k: r[k] for k in ROW_COLUMNS} for r in rows])
    tmp = path.with_suffix(".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def read_results(out_dir: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Rows of a finished campaign directory's ``results.parquet``."""
    import pyarrow.parquet as pq

    path = Path(out_dir) / RESULTS_FILE
    if not path.is_file():
        raise CampaignError(f"{out_dir}: no {RESULTS_FILE}; run the campaign (to the end) first")
    rows: list[dict[str, Any]] = pq.read_table(path).to_pylist()
    return rows


def save_trajectories(runs: Sequence[RunSpec], out_dir: Path) -> list[Path]:
    """Re-run ``runs`` (they are pure) and save each trajectory as float32 ``.npz``.

    Arrays: ``time_s``, ``setpoint_kw``, ``power_true_kw``, ``power_measured_kw``,
    ``triac_pct``; the run id in ``run_id``.
    """
    folder = out_dir / TRAJECTORY_DIR
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for run in runs:
        result = simulate_run(run).result
        path = folder / (hashlib.sha256(run.run_id.encode("utf-8")).hexdigest()[:16] + ".npz")
        arrays: dict[str, Any] = {
            k: np.asarray(getattr(result, k), dtype=np.float32)
            for k in ("time_s", "setpoint_kw", "power_true_kw", "power_measured_kw", "triac_pct")}
        arrays["run_id"] = np.array(run.run_id)
        np.savez_compressed(path, **arrays)
        paths.append(path)
    return paths


def worst_runs(spec: CampaignSpec, rows: Sequence[dict[str, Any]], n_per_controller: int
               ) -> list[RunSpec]:
    """The ``n_per_controller`` runs of highest IAE of each controller (errors first)."""
    by_id = {r.run_id: r for r in spec.expand()}
    chosen: list[RunSpec] = []
    for c in spec.controllers:
        mine = [r for r in rows if r["controller"] == c.name]
        mine.sort(key=lambda r: -math.inf if r["status"] != "ok" else -float(r["iae_kw_s"]))
        chosen += [by_id[r["run_id"]] for r in mine[:n_per_controller] if r["status"] == "ok"]
    return chosen


def run_campaign(
    spec: CampaignSpec,
    out_dir: str | os.PathLike[str],
    *,
    executor: ExecutorName = "serial",
    workers: int = 1,
    dask_address: str = "local",
    progress: ProgressCallback | None = None,
    max_runs: int | None = None,
) -> CampaignOutcome:
    """Run the runs of ``spec`` not yet in ``out_dir`` and write the results table.

    Parameters
    ----------
    spec :
        The campaign.
    out_dir :
        Campaign directory (created; resumed if it holds the same spec).
    executor, workers, dask_address :
        See `map_runs`.
    progress :
        Called as ``progress(done, total)`` after every run (done includes skipped runs).
    max_runs :
        Stop after this many new runs (an interruption on purpose, for tests and for
        splitting a campaign over sessions); None runs them all.

    Raises
    ------
    CampaignError
        Unknown executor, bad worker count, a directory of another spec, Dask missing.
    """
    out = Path(out_dir)
    _prepare_dir(spec, out)
    runs = spec.expand()
    rows_path = out / ROWS_FILE
    done = _read_rows(rows_path)
    _rewrite_clean(rows_path, done)
    todo = [r for r in runs if r.run_id not in done]
    n_skipped = len(runs) - len(todo)
    if max_runs is not None:
        todo = todo[:max_runs]
    n_run = 0
    with rows_path.open("a", encoding="utf-8") as fh:
        for _, row in map_runs(execute_run, todo, executor=executor, workers=workers,
                               dask_address=dask_address):
            fh.write(json.dumps(row, allow_nan=True) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
            done[str(row["run_id"])] = row
            n_run += 1
            if progress is not None:
                progress(n_skipped + n_run, len(runs))
    ordered = tuple(done[r.run_id] for r in runs if r.run_id in done)
    results = out / RESULTS_FILE
    if len(ordered) == len(runs):
        write_parquet(ordered, results)
    return CampaignOutcome(rows=ordered, n_skipped=n_skipped, n_run=n_run,
                           n_errors=sum(r["status"] != "ok" for r in ordered), results_path=results)


__all__ = ["CAMPAIGN_FILE", "DASK_BATCH_MAX", "EXECUTORS", "RESULTS_FILE", "ROWS_FILE", "TRAJECTORY_DIR",
           "CampaignOutcome", "dask_batches", "dask_client", "execute_batch", "map_runs", "pin_blas_threads",
           "read_results", "run_campaign", "save_trajectories", "spec_digest", "worst_runs"]
