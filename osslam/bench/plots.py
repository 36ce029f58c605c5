"""Benchmark figures as PNG: grouped bar charts of a metric table, and a grid of trajectory plots.

Drawn on matplotlib's Agg canvas without pyplot, as in :mod:`osslam.eval.plots`.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .collect import RunRecord
from .tables import Stat, Table

log = logging.getLogger(__name__)

DPI = 100


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    return path


def bar_chart(table: Table, path: str | Path, ylabel: str) -> Path:
    """Grouped bars of a sequences x configs table (:func:`osslam.bench.tables.metric_table`), std as error bars."""
    configs = table.header[1:]
    n_seq = len(table.rows)
    fig = Figure(figsize=(max(5.0, 1.2 + 0.6 * n_seq * max(len(configs), 1)), 4.0))
    ax = fig.add_subplot()
    width = 0.8 / max(len(configs), 1)
    x = np.arange(n_seq)
    for j, config in enumerate(configs):
        cells = [row[j + 1] for row in table.rows]
        means = [c.mean if isinstance(c, Stat) and c.n else math.nan for c in cells]
        stds = [c.std if isinstance(c, Stat) and c.n else 0.0 for c in cells]
        ax.bar(x + (j - (len(configs) - 1) / 2) * width, means, width, yerr=stds, capsize=3, label=config)
    ax.set_xticks(x, [str(row[0]) for row in table.rows], rotation=20, ha="right")
    ax.set_ylabel(ylabel)
    ax.set_title(table.title)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    return _save(fig, Path(path))


def _aligned_positions(record: RunRecord) -> tuple[np.ndarray, np.ndarray] | None:
    """Ground-truth and aligned estimated positions of a run, or None when they cannot be compared."""
    from osslam.config import EvalConfig
    from osslam.errors import OsslamError
    from osslam.eval.metrics import compute_metrics, to_evo
    from osslam.trajectory_io import read_tum

    estimate = Path(record.job.get("estimate", record.run_dir / "trajectory.txt"))
    if record.groundtruth is None or not estimate.is_file():
        return None
    try:
        errors = compute_metrics(to_evo(read_tum(record.groundtruth)), to_evo(read_tum(estimate)), EvalConfig())
    except OsslamError as exc:
        log.warning("no trajectory plot for %s/%s: %s", record.sequence, record.config, exc)
        return None
    return errors.reference.positions_xyz, errors.aligned_estimate.positions_xyz


def trajectory_grid(records: list[RunRecord], path: str | Path) -> Path:
    """One top-view (x-y) panel per sequence (rows) and config (columns): ground truth and the first repeat, aligned."""
    first = {(r.sequence, r.config): r for r in reversed(records) if r.ok}
    sequences = list(dict.fromkeys(r.sequence for r in records))
    configs = list(dict.fromkeys(r.config for r in records))
    fig = Figure(figsize=(3.2 * len(configs), 3.0 * len(sequences)))
    for i, seq in enumerate(sequences):
        for j, cfg in enumerate(configs):
            ax = fig.add_subplot(len(sequences), len(configs), i * len(configs) + j + 1)
            ax.set_title(f"{seq} | {cfg}", fontsize="small")
            ax.tick_params(labelsize="x-small")
            record = first.get((seq, cfg))
            positions = _aligned_positions(record) if record else None
            if positions is None:
                ax.text(0.5, 0.5, "no result", ha="center", va="center", transform=ax.transAxes)
                continue
            ref, est = positions
            ax.plot(ref[:, 0], ref[:, 1], "--", color="0.4", linewidth=1.0, label="ground truth")
            ax.plot(est[:, 0], est[:, 1], "-", color="tab:blue", linewidth=1.0, label="estimate")
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(True, alpha=0.3)
            if i == 0 and j == 0:
                ax.legend(loc="best", fontsize="x-small")
    fig.tight_layout()
    return _save(fig, Path(path))
