"""Running a suite: plan its jobs, skip the finished ones, build the composites they need, run the rest on an executor."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from .executors import Executor, ResultCallback
from .jobs import (
    Job,
    JobResult,
    is_finished,
    plan_jobs,
    prepare_sequence,
    skipped_result,
)
from .suite import Suite

log = logging.getLogger(__name__)


@dataclass
class Preparation:
    """A composite sequence built (or not: ``error``) before dispatch, for the sequence labelled ``label``."""

    label: str
    folder: Path
    wall_s: float
    error: str = ""


PreparationCallback = Callable[[Preparation], None]


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


def prepare_composites(jobs: Sequence[Job], on_prepared: PreparationCallback | None = None) -> list[Preparation]:
    """Build, once each and in this process, the composite sequences ``jobs`` need and lack.

    A build that fails is reported, not raised: its jobs try again and fail with the error.
    """
    done = []
    for job in {j.sequence.key: j for j in jobs if j.sequence.composite is not None}.values():
        start, error = time.perf_counter(), ""
        try:
            if not prepare_sequence(job):
                continue
        except Exception as exc:  # noqa: BLE001 - its jobs fail with the error, the others run
            error = f"{exc.__class__.__name__}: {exc}".splitlines()[0]
            log.warning("composite %s: %s", job.sequence.label, error)
        prepared = Preparation(job.sequence.label, job.sequence_dir, time.perf_counter() - start, error)
        done.append(prepared)
        if on_prepared:
            on_prepared(prepared)
    return done


def run_suite(suite: Suite, out_dir: str | Path, executor: Executor, on_result: ResultCallback | None = None,
              rerun: bool = False, on_prepared: PreparationCallback | None = None) -> BenchRun:
    """Run every unfinished job of ``suite`` into ``out_dir`` (all of them with ``rerun``); never raises for a job.

    Composite sequences the jobs to run need are built first (``on_prepared`` hears of each build).
    """
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
    prepare_composites(todo, on_prepared)
    log.info("suite %s: %d jobs, %d to run on %s", suite.name, len(jobs), len(todo), executor.name)
    executor.run(todo, collect)
    return BenchRun(suite, out, results)
