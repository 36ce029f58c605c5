"""Where jobs run: a local process pool, or Ray (a local Ray, or a cluster at an address).

Both start a fresh process per job (so peak memory belongs to the job, and no GTSAM or
OpenCV threads are inherited through ``fork``), hand results to ``on_result`` as jobs
finish, and turn a worker that dies into a failed result instead of an exception.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Protocol

from .jobs import Job, JobResult, failed_result, run_job

log = logging.getLogger(__name__)

ResultCallback = Callable[[JobResult], None]


class Executor(Protocol):
    """Runs jobs and reports each result as it arrives."""

    name: str

    def run(self, jobs: Sequence[Job], on_result: ResultCallback) -> list[JobResult]: ...


def _init_worker(level: int) -> None:
    """Worker logging: the parent's level when it shows details (--verbose), else errors only (warnings are in the results)."""
    logging.basicConfig(level=level if level < logging.WARNING else logging.ERROR,
                        format="%(levelname)s %(name)s: %(message)s")


class LocalExecutor:
    """A ``spawn`` process pool of ``workers`` processes (default: one per CPU), one process per job."""

    name = "local"

    def __init__(self, workers: int | None = None):
        self.workers = workers or os.cpu_count() or 1

    def run(self, jobs: Sequence[Job], on_result: ResultCallback) -> list[JobResult]:
        """Run ``jobs`` in the pool; results in the order they finish."""
        if not jobs:
            return []
        results = []
        level = logging.getLogger().getEffectiveLevel()
        with ProcessPoolExecutor(max_workers=min(self.workers, len(jobs)), max_tasks_per_child=1,
                                 mp_context=multiprocessing.get_context("spawn"),
                                 initializer=_init_worker, initargs=(level,)) as pool:
            futures = {pool.submit(run_job, job): job for job in jobs}
            for future in as_completed(futures):
                try:
                    result = future.result()
                except Exception as exc:  # noqa: BLE001 - a dead worker fails its job only
                    result = failed_result(futures[future], f"worker process failed: {exc!r}")
                on_result(result)
                results.append(result)
        return results


class RayExecutor:
    """One Ray task per job with ``cpus_per_job`` CPUs, on the cluster at ``address`` or a local Ray.

    A Ray already initialised in this process is used as it is; otherwise one is started
    (locally with ``workers`` CPUs, default all) and shut down afterwards. Workers must be
    able to import ``osslam`` (same environment, or installed on the cluster's nodes).
    """

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None, cpus_per_job: float = 1.0):
        self.address = address
        self.workers = workers
        self.cpus_per_job = cpus_per_job

    def run(self, jobs: Sequence[Job], on_result: ResultCallback) -> list[JobResult]:
        """Submit every job, then gather results as they finish."""
        try:
            import ray
        except ImportError:
            raise RuntimeError("the ray executor needs Ray: pip install 'osslam[ray]'") from None
        if not jobs:
            return []
        started = not ray.is_initialized()
        if started:
            ray.init(address=self.address, num_cpus=None if self.address else self.workers,
                     include_dashboard=False, log_to_driver=False, configure_logging=False)
        try:
            task = ray.remote(num_cpus=self.cpus_per_job, max_calls=1, max_retries=0)(run_job)
            pending = {task.remote(job): job for job in jobs}
            results = []
            while pending:
                (ref,), _ = ray.wait(list(pending), num_returns=1)
                job = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - a lost task fails its job only
                    result = failed_result(job, f"ray task failed: {exc.__class__.__name__}: {exc}".splitlines()[0])
                on_result(result)
                results.append(result)
            return results
        finally:
            if started:
                ray.shutdown()


def make_executor(name: str, workers: int | None = None, address: str | None = None) -> Executor:
    """The executor called ``name`` (``local`` or ``ray``)."""
    if name == "local":
        if address:
            raise ValueError("--address applies to the ray executor only")
        return LocalExecutor(workers)
    if name == "ray":
        return RayExecutor(address, workers)
    raise ValueError(f"unknown executor '{name}' (local, ray)")
