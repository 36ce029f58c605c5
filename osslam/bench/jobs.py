"""One benchmark job: a (sequence, config, repeat) run into its own folder, with cost records.

A job writes what ``osslam run`` writes, plus ``job.json`` (its specification, status, wall
time, CPU utilisation and peak memory) and, last, a ``done`` marker. A job is finished when
``done`` exists and ``job.json`` records the same specification; a failed job writes
``error.txt`` and no marker, so it runs again next time. :func:`run_job` never raises: it
is what the executors send to worker processes.

Peak memory is the worker process's ``ru_maxrss`` (resident set, imports included);
executors start a fresh process per job, so it belongs to that job alone. A composite
sequence is built by the runner before dispatch; a job that finds it missing (run on its
own, or on a machine that does not share the suite's output folder) builds it first, and
then its costs include the build.
"""

from __future__ import annotations

import json
import logging
import resource
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

from .composites import ensure_composite
from .suite import ConfigSpec, SequenceSpec, Suite

log = logging.getLogger(__name__)

DONE_FILE = "done"
JOB_FILE = "job.json"
ERROR_FILE = "error.txt"


@dataclass(frozen=True)
class Job:
    """Run ``config`` on ``sequence`` for the ``repeat``-th time (seed offset by ``repeat``) below the suite output ``root``."""

    sequence: SequenceSpec
    config: ConfigSpec
    repeat: int
    root: Path

    @property
    def key(self) -> str:
        """``<sequence>/<config>/run<k>``, the job's folder below the suite's output folder."""
        return f"{self.sequence.key}/{self.config.name}/run{self.repeat}"

    @property
    def out_dir(self) -> Path:
        """The job's folder."""
        return self.root / self.key

    @property
    def sequence_dir(self) -> Path | None:
        """The TUM folder the job reads (None for a synthetic room)."""
        return self.sequence.folder(self.root)

    def spec(self) -> dict:
        """What defines the job's results; a finished job with another spec runs again."""
        return {"sequence": self.sequence.text, "config": self.config.name, "preset": self.config.preset,
                "overrides": list(self.config.overrides), "repeat": self.repeat}


@dataclass
class JobResult:
    """How a job ended: ``ok``, ``failed`` (with a one-line ``error``) or ``skipped`` (finished before)."""

    key: str
    status: str
    wall_s: float = 0.0
    cpu_utilisation: float = 0.0
    peak_memory_mb: float = 0.0
    ape_rmse: float | None = None
    error: str = ""


def plan_jobs(suite: Suite, out_dir: Path) -> list[Job]:
    """Every job of ``suite`` in order (sequence, config, repeat), each in its folder below ``out_dir``."""
    return [Job(seq, cfg, k, out_dir)
            for seq in suite.sequences for cfg in suite.configs for k in range(suite.repeats)]


def read_job_record(job: Job) -> dict | None:
    """The job's ``job.json``, or None when missing or unreadable."""
    try:
        return json.loads((job.out_dir / JOB_FILE).read_text())
    except (OSError, ValueError):
        return None


def is_finished(job: Job) -> bool:
    """Whether ``job`` has run to the end with its current specification."""
    record = read_job_record(job)
    return (job.out_dir / DONE_FILE).is_file() and record is not None and record.get("spec") == job.spec()


def skipped_result(job: Job) -> JobResult:
    """The result of a finished job, read back from its ``job.json``."""
    record = read_job_record(job) or {}
    return JobResult(job.key, "skipped", record.get("wall_s", 0.0), record.get("cpu_utilisation", 0.0),
                     record.get("peak_memory_mb", 0.0), record.get("ape_rmse"))


def prepare_sequence(job: Job) -> bool:
    """Build the job's composite sequence unless it is there (see :mod:`.composites`); True when built here."""
    if job.sequence.composite is None:
        return False
    return ensure_composite(job.sequence.composite, job.sequence_dir, job.sequence.default_preset)


def _execute(job: Job) -> float | None:
    """Run the job's sequence through the pipeline; the APE RMSE when there is ground truth."""
    from osslam.config import load_config
    from osslam.datasets import open_sequence
    from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
    from osslam.pipeline import run_sequence

    cfg = load_config(job.config.preset_for(job.sequence), list(job.config.overrides))
    cfg.run.seed += job.repeat
    prepare_sequence(job)
    folder = job.sequence_dir
    if folder is None:
        source = SyntheticSequence(SyntheticConfig(**dict(job.sequence.synthetic)))
    else:
        source = open_sequence(folder, cfg)
    summary = run_sequence(source, cfg, job.out_dir, groundtruth=source.groundtruth_path, progress=False)
    if source.groundtruth_path is not None or folder is None:
        if not (job.out_dir / "eval" / "metrics.json").is_file():
            raise RuntimeError("no evaluation: nothing was tracked")
    return summary.ape_rmse


def run_job(job: Job) -> JobResult:
    """Run one job in this process and record it; failures are recorded and returned, not raised."""
    out = job.out_dir
    out.mkdir(parents=True, exist_ok=True)
    for stale in (DONE_FILE, ERROR_FILE):
        (out / stale).unlink(missing_ok=True)
    start_wall = time.perf_counter()
    start = resource.getrusage(resource.RUSAGE_SELF)
    status, error, ape = "ok", "", None
    try:
        ape = _execute(job)
    except Exception as exc:  # noqa: BLE001 - a job's failure is recorded, never propagated
        status, error = "failed", f"{exc.__class__.__name__}: {exc}".splitlines()[0]
        (out / ERROR_FILE).write_text(traceback.format_exc())
        log.warning("job %s failed: %s", job.key, error)
    wall = time.perf_counter() - start_wall
    end = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (end.ru_utime - start.ru_utime) + (end.ru_stime - start.ru_stime)
    result = JobResult(job.key, status, wall, cpu / wall if wall > 0 else 0.0, end.ru_maxrss / 1024.0, ape, error)
    record = {"spec": job.spec(), **asdict(result), "cpu_s": cpu}
    (out / JOB_FILE).write_text(json.dumps(record, indent=2))
    if status == "ok":
        (out / DONE_FILE).write_text("")
    return result


def failed_result(job: Job, error: str) -> JobResult:
    """The result of a job whose worker died or could not run it; recorded in its folder."""
    job.out_dir.mkdir(parents=True, exist_ok=True)
    (job.out_dir / ERROR_FILE).write_text(error + "\n")
    result = JobResult(job.key, "failed", error=error)
    (job.out_dir / JOB_FILE).write_text(json.dumps({"spec": job.spec(), **asdict(result)}, indent=2))
    return result
