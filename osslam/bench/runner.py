"""Running a suite: plan its jobs, skip the finished ones, run the rest on an executor."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from .executors import Executor, ResultCallback
from .jobs import JobResult, is_finished, plan_jobs, skipped_result
from .suite import Suite

log = logging.getLogger(__name__)


@dataclass
class BenchRun:
    """The results of every job of a suite (skipped ones included), in the order they came."""

    suite: Suite
    out_dir: Path
    results: list[JobResult]

    @property
    def failed(self) -> list[JobResult]:
        """The jobs that failed."""
        return [r for r in self.results if r.status == "failed"]


def run_suite(suite: Suite, out_dir: str | Path, executor: Executor, on_result: ResultCallback | None = None,
              rerun: bool = False) -> BenchRun:
    """Run every unfinished job of ``suite`` into ``out_dir`` (all of them with ``rerun``); never raises for a job."""
    out = Path(out_dir)
    jobs = plan_jobs(suite, out)
    todo = [j for j in jobs if rerun or not is_finished(j)]
    results: list[JobResult] = []

    def collect(result: JobResult) -> None:
        results.append(result)
        if on_result:
            on_result(result)

    for job in jobs:
        if job not in todo:
            collect(skipped_result(job))
    log.info("suite %s: %d jobs, %d to run on %s", suite.name, len(jobs), len(todo), executor.name)
    executor.run(todo, collect)
    return BenchRun(suite, out, results)
