"""Evaluation of a trajectory file against a ground-truth file: metrics.json, plots and report.md."""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import evo

from osslam.config import EvalConfig
from osslam.errors import InputError
from osslam.eval.metrics import (
    ALIGNMENT,
    METRICS,
    RPE_DELTA_SECONDS,
    STATISTICS,
    UNITS,
    EvaluationError,
    TrajectoryErrors,
    compute_metrics,
    to_evo,
)
from osslam.eval.plots import write_plots
from osslam.trajectory_io import read_tum

log = logging.getLogger(__name__)

METRICS_FILE = "metrics.json"
REPORT_FILE = "report.md"
ROW_LABELS = {"max": "Max", "mean": "Mean", "median": "Median", "min": "Min", "rmse": "RMSE", "sse": "SSE",
              "std": "Std"}
PLOT_TITLES = {"trajectory_top": "Trajectory, top view (x-y)", "trajectory_side": "Trajectory, side view (x-z)",
               "ape": "APE over time"}


@dataclass
class EvalReport:
    """What an evaluation found and where it wrote it.

    ``metrics`` maps each metric name (ape, rpe_trans, rpe_rot, rpe_trans_per_second,
    rpe_rot_per_second) to evo's statistics; ``info`` is the ``info`` section of metrics.json.
    """

    out_dir: Path
    metrics: dict[str, dict[str, float]]
    info: dict[str, Any]
    errors: TrajectoryErrors
    metrics_path: Path
    report_path: Path
    plots: dict[str, Path]


def evaluation_info(errors: TrajectoryErrors, gt_path: str | Path, est_path: str | Path,
                    cfg: EvalConfig) -> dict[str, Any]:
    """The ``info`` section of metrics.json: files, pose counts, units, settings and alignment."""
    return {
        "groundtruth": str(gt_path),
        "estimate": str(est_path),
        "poses_groundtruth": errors.n_reference,
        "poses_estimate": errors.n_estimate,
        "poses_associated": errors.n_associated,
        "max_time_diff_s": cfg.max_time_diff,
        "rpe_delta_frames": cfg.rpe_delta_frames,
        "rpe_pairs": errors.n_rpe_pairs,
        "rpe_delta_seconds": RPE_DELTA_SECONDS,
        "rpe_pairs_per_second": errors.n_rpe_pairs_per_second,
        "units": dict(UNITS),
        "alignment": ALIGNMENT,
        "alignment_transform": errors.alignment.tolist(),
        "evo_version": evo.__version__,
    }


def write_metrics_json(path: str | Path, metrics: dict[str, dict[str, float]], info: dict[str, Any]) -> Path:
    """Write the statistics of every metric plus ``info`` as JSON; NaN statistics become null."""
    doc: dict[str, Any] = {
        name: {s: (float(metrics[name][s]) if math.isfinite(metrics[name][s]) else None) for s in STATISTICS}
        for name in METRICS
    }
    doc["info"] = info
    path = Path(path)
    path.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")
    return path


def _number(value: Any) -> str:
    """A table cell: floats with four decimals (n/a when not finite), anything else as text."""
    if isinstance(value, float):
        return f"{value:.4f}" if math.isfinite(value) else "n/a"
    return str(value)


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    """Markdown table lines; every column but the first right-aligned."""
    lines = ["| " + " | ".join(header) + " |", "|---" + "|---:" * (len(header) - 1) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def _stats_table(metrics: dict[str, dict[str, float]], columns: dict[str, str]) -> list[str]:
    """A table with one row per statistic and one column per metric (``columns``: metric -> heading)."""
    rows = [[label] + [_number(metrics[m][s]) for m in columns] for s, label in ROW_LABELS.items()]
    return _table([""] + list(columns.values()), rows)


def _relative(image: Path, folder: Path) -> str:
    """An image path relative to the report's folder, with forward slashes."""
    return Path(os.path.relpath(image, folder)).as_posix()


def write_markdown(path: str | Path, metrics: dict[str, dict[str, float]], info: dict[str, Any],
                   plots: dict[str, Path] | None = None, extra: dict[str, Any] | None = None,
                   images: dict[str, Path] | None = None) -> Path:
    """Write the Markdown report: inputs, statistics tables, an optional "Run" section from ``extra``, plots.

    ``plots`` maps keys of :data:`osslam.eval.plots.PLOT_FILES` to image paths; ``images``
    maps section titles to further images, each shown in a section of its own after the
    plots. Images are embedded relative to the report's folder.
    """
    path = Path(path)
    lines = [
        "# Trajectory evaluation",
        "",
        f"- Ground truth: `{info['groundtruth']}` ({info['poses_groundtruth']} poses)",
        f"- Estimate: `{info['estimate']}` ({info['poses_estimate']} poses)",
        f"- Associated poses: {info['poses_associated']} (max. time difference {info['max_time_diff_s']} s)",
        f"- Alignment: {info['alignment']}",
        f"- RPE: consecutive pairs {info['rpe_delta_frames']} frame(s) apart ({info['rpe_pairs']} pairs) "
        f"and {info['rpe_delta_seconds']:g} s apart ({info['rpe_pairs_per_second']} pairs)",
        "",
        f"## Errors (RPE over {info['rpe_delta_frames']} frame(s))",
        "",
        *_stats_table(metrics, {"ape": "APE (m)", "rpe_trans": "RPE trans (m)", "rpe_rot": "RPE rot (deg)"}),
        "",
        f"## RPE over {info['rpe_delta_seconds']:g} s",
        "",
        *_stats_table(metrics, {"rpe_trans_per_second": "RPE trans (m)", "rpe_rot_per_second": "RPE rot (deg)"}),
        "",
    ]
    if extra:
        lines += ["## Run", "", *_table(["", "value"], [[str(k), _number(v)] for k, v in extra.items()]), ""]
    if plots:
        lines += ["## Plots", ""]
        for key, image in plots.items():
            lines += [f"![{PLOT_TITLES.get(key, key)}]({_relative(image, path.parent)})", ""]
    for title, image in (images or {}).items():
        lines += [f"## {title}", "", f"![{title}]({_relative(image, path.parent)})", ""]
    path.write_text("\n".join(lines))
    return path


def evaluate_files(gt_path: str | Path, est_path: str | Path, out_dir: str | Path, cfg: EvalConfig,
                   extra: dict[str, Any] | None = None, images: dict[str, Path] | None = None) -> EvalReport:
    """Evaluate the TUM trajectory ``est_path`` against ground truth ``gt_path`` into ``out_dir``.

    Writes metrics.json, report.md (with a "Run" section from ``extra`` and a section per
    entry of ``images`` (title -> image path) when given) and,
    when ``cfg.plots``, the PNG plots; creates ``out_dir`` if needed. Raises InputError for
    an unreadable file or trajectories that cannot be compared.
    """
    groundtruth = read_tum(gt_path)
    estimate = read_tum(est_path)
    try:
        errors = compute_metrics(to_evo(groundtruth), to_evo(estimate), cfg)
    except EvaluationError as exc:
        raise InputError(est_path, f"cannot evaluate against {gt_path}: {exc}") from None
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(out, f"cannot create the output folder: {exc.strerror}") from None
    info = evaluation_info(errors, gt_path, est_path, cfg)
    metrics_path = write_metrics_json(out / METRICS_FILE, errors.stats, info)
    plots = write_plots(errors, out) if cfg.plots else {}
    report_path = write_markdown(out / REPORT_FILE, errors.stats, info, plots, extra, images)
    log.info("evaluation written to %s", out)
    return EvalReport(out_dir=out, metrics=errors.stats, info=info, errors=errors,
                      metrics_path=metrics_path, report_path=report_path, plots=plots)
