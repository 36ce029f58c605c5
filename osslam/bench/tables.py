"""The benchmark tables, built from run records (no I/O): accuracy per sequence x config, statistics per run, cost.

* :func:`metric_table` - one statistic of one metric, sequences x configs, mean ± std over
  repeats (the paper's Table 5 for APE RMSE, Table 6 for translational RPE);
* :func:`statistics_table` - every evo statistic of one metric per run (Tables 3-4);
* :func:`mask_table` - on sequences with ground-truth masks (composites), how well each
  config's dynamic mask covers the movers: recall of the movers' keypoints, share of static
  keypoints removed, pixel precision and recall;
* :func:`cost_table` - mean tracking and segmentation ms per frame, CPU utilisation, peak
  memory, wall time (Table 7); all its measured columns are timing columns;
* :func:`failures_table` - the runs that failed, with their error.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field

from .collect import RunRecord

STATISTICS = ("max", "mean", "median", "min", "rmse", "sse", "std")
METRIC_TITLES = {"ape": "APE (m)", "rpe_trans": "RPE translation (m, per frame)",
                 "rpe_trans_per_second": "RPE translation (m, per second)", "rpe_rot": "RPE rotation (deg, per frame)"}
DECIMALS = 4


@dataclass(frozen=True)
class Stat:
    """The mean and sample standard deviation of ``n`` values (std 0 for one value)."""

    mean: float
    std: float
    n: int

    @classmethod
    def of(cls, values: Sequence[float]) -> "Stat":
        """The Stat of finite ``values`` (NaN mean when there are none)."""
        finite = [v for v in values if v is not None and math.isfinite(v)]
        if not finite:
            return cls(math.nan, math.nan, 0)
        return cls(statistics.fmean(finite), statistics.stdev(finite) if len(finite) > 1 else 0.0, len(finite))


Cell = str | int | float | Stat


@dataclass
class Table:
    """A titled table; ``timing`` names the columns that measure time or resources (they vary run to run)."""

    name: str
    title: str
    header: list[str]
    rows: list[list[Cell]]
    timing: set[str] = field(default_factory=set)
    decimals: int = DECIMALS


def _value(record: RunRecord, metric: str, stat: str) -> float | None:
    value = record.metrics.get(metric, {}).get(stat)
    return float(value) if value is not None else None


def _columns(records: list[RunRecord]) -> tuple[list[str], list[str]]:
    """Sequence labels and config names, in order of first appearance."""
    return list(dict.fromkeys(r.sequence for r in records)), list(dict.fromkeys(r.config for r in records))


def _cell(group: list[RunRecord], values: list[float | None]) -> Cell:
    """A Stat of the ok runs, else why there is none (failed / missing)."""
    stat = Stat.of([v for r, v in zip(group, values) if r.ok])
    if stat.n:
        return stat
    if any(r.status == "failed" for r in group):
        return "failed"
    return "n/a" if any(r.ok for r in group) else "-"


def metric_table(records: list[RunRecord], metric: str, stat: str = "rmse", name: str | None = None) -> Table:
    """``stat`` of ``metric`` for each sequence (rows) and config (columns), mean ± std over repeats."""
    sequences, configs = _columns(records)
    rows: list[list[Cell]] = []
    for seq in sequences:
        row: list[Cell] = [seq]
        for cfg in configs:
            group = [r for r in records if r.sequence == seq and r.config == cfg]
            row.append(_cell(group, [_value(r, metric, stat) for r in group]))
        rows.append(row)
    title = f"{METRIC_TITLES.get(metric, metric)} {stat.upper()}"
    return Table(name or f"{metric}_{stat}", title, ["sequence", *configs], rows)


def statistics_table(records: list[RunRecord], metric: str) -> Table:
    """Every statistic of ``metric`` (max ... std) for each run that has metrics."""
    rows: list[list[Cell]] = [[r.sequence, r.config, r.repeat, *(_value(r, metric, s) for s in STATISTICS)]
                              for r in records if r.ok]
    rows = [[c if c is not None else "n/a" for c in row] for row in rows]
    return Table(f"{metric}_statistics", f"{METRIC_TITLES.get(metric, metric)}, all statistics per run",
                 ["sequence", "config", "run", *STATISTICS], rows)


MASK_SCORES = {"keypoint_recall": "mover keypoints removed", "static_keypoints_removed": "static keypoints removed",
               "off_outline_keypoints_removed": "static keypoints removed, off movers' outlines",
               "clear_keypoints_removed": "static keypoints removed, 15+ px from movers",
               "pixel_precision": "pixel precision", "pixel_recall": "pixel recall"}


def mask_table(records: list[RunRecord]) -> Table:
    """Dynamic-mask scores per sequence with ground-truth masks and config, means over repeats (n/a: nothing masked)."""
    sequences, configs = _columns(records)
    rows: list[list[Cell]] = []
    for seq in sequences:
        for cfg in configs:
            group = [r for r in records if r.sequence == seq and r.config == cfg and r.ok and r.masks]
            if group:
                stats = [Stat.of([r.masks.get(k) for r in group]) for k in MASK_SCORES]
                rows.append([seq, cfg, *(s if s.n else "n/a" for s in stats)])
    return Table("masks", "Dynamic masks against the ground-truth masks (fractions, whole run)",
                 ["sequence", "config", *MASK_SCORES.values()], rows, decimals=3)


def _timing_mean(record: RunRecord, stage: str) -> float | None:
    value = record.stats.get("timings_ms", {}).get(stage, {}).get("mean")
    return float(value) if value is not None else None


def cost_table(records: list[RunRecord]) -> Table:
    """Per sequence and config, means over repeats: tracking, segmentation and total ms per frame, CPU, memory, wall."""
    sequences, configs = _columns(records)
    measures = {
        "tracking ms": lambda r: _timing_mean(r, "tracking"),
        "segmentation ms": lambda r: _timing_mean(r, "segmentation"),
        "total ms/frame": lambda r: _timing_mean(r, "total"),
        "CPU %": lambda r: 100.0 * r.job["cpu_utilisation"] if "cpu_utilisation" in r.job else None,
        "peak MB": lambda r: r.job.get("peak_memory_mb"),
        "wall s": lambda r: r.job.get("wall_s"),
    }
    rows: list[list[Cell]] = []
    for seq in sequences:
        for cfg in configs:
            group = [r for r in records if r.sequence == seq and r.config == cfg and r.status == "ok"]
            if not group:
                continue
            frames = group[0].stats.get("frames_in", "n/a")
            stats = [Stat.of([f(r) for r in group]) for f in measures.values()]
            rows.append([seq, cfg, frames, *(s if s.n else "n/a" for s in stats)])
    return Table("cost", "Cost per run (means over repeats)", ["sequence", "config", "frames", *measures], rows,
                 timing=set(measures), decimals=1)


def failures_table(records: list[RunRecord]) -> Table:
    """The runs that failed or are missing, with the reason."""
    rows: list[list[Cell]] = [[r.sequence, r.config, r.repeat, r.status, r.error or "-"]
                              for r in records if r.status in ("failed", "missing")]
    return Table("failures", "Failed and missing runs", ["sequence", "config", "run", "status", "error"], rows)


def benchmark_tables(records: list[RunRecord]) -> list[Table]:
    """The report's tables, in order."""
    return [
        metric_table(records, "ape"),
        metric_table(records, "rpe_trans"),
        metric_table(records, "rpe_trans_per_second"),
        statistics_table(records, "ape"),
        statistics_table(records, "rpe_trans"),
        mask_table(records),
        cost_table([r for r in records if r.status != "external"]),
        failures_table(records),
    ]
