"""Run case tasks on the campaign runner's executors: serial, processes or Dask.

The executors are those of `czmpc.campaigns.runner` (same names, same worker set-up: spawned
processes, one BLAS thread each through `pin_blas_threads`, a Dask LocalCluster of
one-thread worker processes on 127.0.0.1 or a scheduler address). The runner executes
campaign runs only; a case task carries a settings file and a mutation, which campaign
runs do not, so the tasks are mapped here with the same machinery. Results come back in
task order whatever the executor; each case is a pure function of its task, so every
executor gives the same numbers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context

from czmpc.campaigns.campaign import CampaignError
from czmpc.campaigns.runner import EXECUTORS, dask_client, pin_blas_threads
from czmpc.testing.cases import CaseResult, CaseTask, run_task
from czmpc.testing.suite import RegressError

#: ``progress(done, total)`` after each finished task.
TaskProgress = Callable[[int, int], None]


def _dask_results(tasks: Sequence[CaseTask], workers: int, address: str,
                  done: Callable[[int, CaseResult], None]) -> None:
    try:
        with dask_client(workers, address) as (distributed, client):
            futures = client.map(run_task, list(tasks), pure=False)
            index = {f.key: i for i, f in enumerate(futures)}
            for future in distributed.as_completed(futures):
                done(index[future.key], future.result())
    except CampaignError as exc:
        raise RegressError(str(exc)) from None


def map_tasks(tasks: Sequence[CaseTask], *, executor: str = "serial", workers: int = 2,
              dask_address: str = "local", progress: TaskProgress | None = None
              ) -> list[CaseResult]:
    """Run every task and return the results in task order.

    Parameters
    ----------
    tasks :
        The tasks.
    executor :
        ``"serial"``, ``"processes"`` or ``"dask"`` (`czmpc.campaigns.runner.EXECUTORS`).
    workers :
        Worker processes of ``processes`` and of a local Dask cluster, >= 1.
    dask_address :
        ``"local"`` or a scheduler address such as ``"tcp://10.0.0.5:8786"``.
    progress :
        Called as ``progress(done, total)`` after every task.

    Raises
    ------
    RegressError
        Unknown executor, bad worker count, Dask missing.
    """
    if executor not in EXECUTORS:
        raise RegressError(f"expected executor one of {list(EXECUTORS)}; got {executor!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise RegressError(f"expected workers an integer >= 1; got {workers!r}")
    results: list[CaseResult | None] = [None] * len(tasks)
    n_done = 0

    def done(i: int, result: CaseResult) -> None:
        nonlocal n_done
        results[i] = result
        n_done += 1
        if progress is not None:
            progress(n_done, len(tasks))

    if executor == "serial" or not tasks:
        for i, task in enumerate(tasks):
            done(i, run_task(task))
    elif executor == "processes":
        pin_blas_threads()
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
            futures = {pool.submit(run_task, task): i for i, task in enumerate(tasks)}
            for future in as_completed(futures):
                done(futures[future], future.result())
    else:
        _dask_results(tasks, workers, dask_address, done)
    return [r for r in results if r is not None]


__all__ = ["TaskProgress", "map_tasks"]
