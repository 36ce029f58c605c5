"""Reading a suite's results back: one record per job (metrics.json, masks.json, stats.json, job.json), plus external estimates.

External estimates (trajectories from another system, e.g. ORB-SLAM3) are a folder of TUM
files named after the sequences (``fr3_walking_xyz.txt``, ``rgbd_dataset_freiburg3_walking_xyz.txt``
or the label's last part, ``walking_xyz.txt``); each is evaluated against the sequence's
ground truth into ``<out>/<sequence>/<name>/external/eval`` and becomes one more column.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

from osslam.errors import OsslamError

from .jobs import JOB_FILE, plan_jobs
from .suite import SequenceSpec, Suite

log = logging.getLogger(__name__)


@dataclass
class RunRecord:
    """What one run left behind: ``status`` ok / failed / missing / external, metrics and stats when ok.

    ``masks`` holds the dynamic-mask scores over the whole run (``eval/masks.json``'s total)
    on sequences with ground-truth masks (composites), else nothing.
    """

    sequence: str
    config: str
    repeat: int
    status: str
    run_dir: Path
    metrics: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    job: dict = field(default_factory=dict)
    error: str = ""
    groundtruth: Path | None = None
    masks: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Whether the run has metrics to tabulate."""
        return self.status in ("ok", "external") and bool(self.metrics)


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _external_file(folder: Path, seq: SequenceSpec) -> Path | None:
    """The external trajectory for ``seq`` in ``folder``, if any."""
    names = [seq.key, seq.label.rsplit("/", 1)[-1]] + ([seq.path.name] if seq.path is not None else [])
    for name in names:
        candidate = folder / f"{name}.txt"
        if candidate.is_file():
            return candidate
    return None


def _external_records(suite: Suite, out: Path, gts: dict[str, Path | None]) -> list[RunRecord]:
    """Evaluate the external estimates of ``suite`` against each sequence's ground truth."""
    from osslam.config import EvalConfig
    from osslam.eval.report import evaluate_files

    records = []
    for name, folder in suite.external:
        for seq in suite.sequences:
            estimate, gt = _external_file(folder, seq), gts.get(seq.key)
            run_dir = out / seq.key / name / "external"
            if estimate is None or gt is None:
                reason = "no estimate file" if estimate is None else "no ground truth"
                records.append(RunRecord(seq.label, name, 0, "missing", run_dir, error=reason))
                continue
            try:
                report = evaluate_files(gt, estimate, run_dir / "eval", EvalConfig(plots=False))
            except OsslamError as exc:
                records.append(RunRecord(seq.label, name, 0, "failed", run_dir, error=str(exc)))
                continue
            records.append(RunRecord(seq.label, name, 0, "external", run_dir, metrics=report.metrics,
                                     groundtruth=gt, job={"estimate": str(estimate)}))
    return records


def collect_records(suite: Suite, out_dir: str | Path) -> list[RunRecord]:
    """One record per job of ``suite`` in ``out_dir`` (in suite order), then the external estimates."""
    out = Path(out_dir)
    records = []
    gts: dict[str, Path | None] = {}
    for job in plan_jobs(suite, out):
        d = job.out_dir
        job_record = _read_json(d / JOB_FILE)
        status = job_record.get("status", "missing")
        error = (job_record.get("error") or "failed") if status == "failed" else ""
        gt = job.sequence.groundtruth(out, d)
        if gts.get(job.sequence.key) is None:
            gts[job.sequence.key] = gt
        records.append(RunRecord(job.sequence.label, job.config.name, job.repeat, status, d,
                                 metrics={k: v for k, v in _read_json(d / "eval" / "metrics.json").items() if k != "info"},
                                 stats=_read_json(d / "stats.json"), job=job_record, error=error, groundtruth=gt,
                                 masks=_read_json(d / "eval" / "masks.json").get("total", {})))
    return records + _external_records(suite, out, gts)
