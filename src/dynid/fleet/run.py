"""``dynid fleet``: every (robot, log) pair of a fleet identified in parallel on ``dask.distributed``.

One Dask task per log (:func:`dynid.fleet.jobs.run_log`, one BLAS thread each) on a
``LocalCluster`` of process workers (``fleet.workers``) or on an existing cluster
(``fleet.scheduler``); then, in this process, the fleet statistics
(:func:`dynid.fleet.analysis.analyse`).

Faults: a log's own failure (missing, unreadable, wrong columns, another robot) is a result with
its error (:data:`~dynid.fleet.jobs.LOG_ERRORS`). A worker that dies mid-run loses nothing: the
scheduler reruns its tasks elsewhere (a task whose workers keep dying is given up after the
scheduler's ``allowed-failures`` and reported as that log's failure); an unexpected exception in
a task is retried ``fleet.retries`` times, then reported as that log's failure. Results are
collected by task key, one per log: none is lost or counted twice. The outputs depend on the
results alone, never on where, in which order or how parallel the jobs ran.
"""

from __future__ import annotations

import contextlib
import logging
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

from dynid.config.fleet import FleetConfig
from dynid.errors import InputError, require
from dynid.fleet.analysis import FleetResult, analyse
from dynid.fleet.jobs import LogJob, LogResult, run_log

__all__ = ["build_jobs", "run_fleet", "fleet_client", "local_cluster", "SCHEDULER_TIMEOUT_S"]

SCHEDULER_TIMEOUT_S = 10.0
"""Seconds to wait for a Dask scheduler before giving up."""

Progress = Callable[[str, int, int], None]


def _no_progress(task: str, done: int, total: int) -> None:
    return None


def build_jobs(cfg: FleetConfig) -> tuple[list[LogJob], str | None]:
    """One job per log of the table, and the fleet's first date (ISO; days are counted from it)."""
    dates = [log.date for log in cfg.logs if log.date is not None]
    first = min(dates) if dates else None
    jobs = [LogJob(index=log.index, robot=log.robot, file=str(log.file),
                   days=None if log.date is None else float((log.date - first).days), config=cfg.log_config(log))
            for log in cfg.logs]
    return jobs, None if first is None else first.isoformat()


def local_cluster(n: int) -> Any:
    """A ``distributed.LocalCluster`` of ``n`` process workers with one thread each, without Dask's
    ``MALLOC_TRIM_THRESHOLD_=65536`` in the workers' environment.

    Dask's nanny sets that variable (``distributed.nanny.pre-spawn-environ``) so that long-lived
    workers give freed memory back to the system. Setting it at all switches off glibc's dynamic
    mmap threshold: every array above 128 kB is then mapped and unmapped on each allocation, and an
    identification, which makes many such temporaries, ran 1.6-2.4 times slower on a worker than in
    one process (``bench/fleet_scaling.py``, 2e4 samples x 6 joints). A fleet's workers live for one
    run, so the glibc default is kept (a value the user set in the environment still wins)."""
    import dask

    distributed = require("distributed", "montecarlo")
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        return distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                                        silence_logs=logging.ERROR)


@contextlib.contextmanager
def fleet_client(cfg: FleetConfig) -> Iterator[tuple[Any, str, int]]:
    """A ``distributed.Client``: on ``cfg.scheduler``, or on a LocalCluster of ``cfg.n_workers``
    process workers with one thread each (closed on exit); its description and worker count."""
    distributed = require("distributed", "montecarlo")
    if cfg.scheduler is not None:
        try:
            client = distributed.Client(cfg.scheduler, timeout=SCHEDULER_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            raise InputError(f"cannot reach the Dask scheduler at {cfg.scheduler!r} ({exc})") from None
        try:
            yield client, f"Dask scheduler {cfg.scheduler}", max(1, sum(client.nthreads().values()))
        finally:
            client.close()
        return
    n = max(1, min(cfg.n_workers, len(cfg.logs)))
    cluster = local_cluster(n)
    try:
        client = distributed.Client(cluster, set_as_default=False)
        try:
            yield client, f"LocalCluster, {n} process workers", n
        finally:
            client.close()
    finally:
        cluster.close()


def _failed(job: LogJob, exc: BaseException) -> LogResult:
    kind = type(exc).__name__
    why = ("its worker died each time it ran (the scheduler gave it up)" if kind == "KilledWorker"
           else "an unexpected error, also after the retries (a fault of dynid or of the worker)")
    return LogResult(index=job.index, robot=job.robot, file=job.file, days=job.days,
                     error=f"{kind}: {' '.join(str(exc).split())} ({why})")


def run_jobs(client: Any, jobs: list[LogJob], retries: int, progress: Progress = _no_progress,
             on_result: Callable[[int], None] | None = None) -> list[LogResult]:
    """Run ``jobs`` on ``client``; one result per job, in job order. ``on_result(done)`` is called
    after each result arrives (tests use it to kill a worker mid-run)."""
    from distributed import as_completed

    run = uuid.uuid4().hex[:12]  # keys of this run only: a shared scheduler may hold another run's
    keys = [f"dynid-fleet-{run}-{job.index}" for job in jobs]
    futures = client.map(run_log, jobs, key=keys, retries=retries, pure=False)
    by_key = {f.key: job for f, job in zip(futures, jobs)}
    results: dict[int, LogResult] = {}
    progress("logs", 0, len(jobs))
    try:
        for fut in as_completed(futures, loop=client.loop):
            job = by_key[fut.key]
            if job.index in results:  # as_completed yields each future once; kept as a guard
                continue
            if fut.status == "error":
                results[job.index] = _failed(job, fut.exception())
            else:
                results[job.index] = fut.result()
            progress("logs", len(results), len(jobs))
            if on_result is not None:
                on_result(len(results))
    finally:
        client.cancel(futures)
    return [results[job.index] for job in jobs]


def run_fleet(cfg: FleetConfig, progress: Progress = _no_progress, *,
              on_result: Callable[[int], None] | None = None) -> FleetResult:
    """Identify every log of ``cfg`` on Dask and analyse the fleet (nothing is written)."""
    jobs, first = build_jobs(cfg)
    t0 = time.perf_counter()
    with fleet_client(cfg) as (client, backend, workers):
        t1 = time.perf_counter()
        results = run_jobs(client, jobs, cfg.retries, progress, on_result)
        t2 = time.perf_counter()
    models_of = {}
    for log in cfg.logs:
        models_of.setdefault(log.robot, log.model)
    result = analyse(results, models_of, cfg.alpha, first)
    timing = {"total_s": time.perf_counter() - t0, "cluster_start_s": t1 - t0, "jobs_s": t2 - t1, "backend": backend,
              "workers": workers, "identify_s_per_log": [r.seconds for r in result.logs]}
    import dataclasses

    return dataclasses.replace(result, timing=timing)
