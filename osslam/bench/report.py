"""The benchmark report of a suite's output folder: tables as Markdown, CSV and LaTeX, charts, report.md."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

from .collect import collect_records
from .plots import bar_chart, trajectory_grid
from .render import to_csv, to_latex, to_markdown
from .suite import Suite
from .tables import Table, benchmark_tables

log = logging.getLogger(__name__)

REPORT_FILE = "report.md"
OPTIONAL_TABLES = ("masks", "failures")  # left out of report.md when empty
CHARTS = {"ape_rmse": "APE RMSE (m)", "rpe_trans_rmse": "RPE trans. RMSE (m)"}


@dataclass
class BenchReport:
    """The tables of a report and where its files went."""

    report_path: Path
    tables: list[Table]
    images: list[Path]


def write_report(suite: Suite, out_dir: str | Path, report_dir: str | Path | None = None,
                 plots: bool = True) -> BenchReport:
    """Collect the results of ``suite`` in ``out_dir`` and write the report into ``report_dir`` (``out_dir/report``).

    Writes ``report.md`` and ``tables/<name>.md|.csv|.tex`` for every table, and with
    ``plots`` a bar chart per accuracy table and ``trajectories.png``.
    """
    out = Path(out_dir)
    target = Path(report_dir) if report_dir else out / "report"
    (target / "tables").mkdir(parents=True, exist_ok=True)
    records = collect_records(suite, out)
    tables = benchmark_tables(records)
    for table in tables:
        for suffix, render in ((".md", to_markdown), (".csv", to_csv), (".tex", to_latex)):
            (target / "tables" / f"{table.name}{suffix}").write_text(render(table))
    images = []
    if plots:
        images = [bar_chart(t, target / f"{t.name}.png", CHARTS[t.name]) for t in tables if t.name in CHARTS]
        images.append(trajectory_grid(records, target / "trajectories.png"))
    ok = sum(r.status == "ok" for r in records)
    failed = sum(r.status == "failed" for r in records)
    lines = [f"# Benchmark: {suite.name}", ""]
    if suite.description:
        lines += [suite.description.strip(), ""]
    lines += [
        f"{len(suite.sequences)} sequence(s) x {len(suite.configs)} config(s) x {suite.repeats} repeat(s): "
        f"{ok} run(s) ok, {failed} failed"
        + (f"; external estimates: {', '.join(name for name, _ in suite.external)}" if suite.external else "") + ".",
        "Values are mean ± std over repeats (repeat k runs with `run.seed` + k). "
        "Tables also as CSV and LaTeX in `tables/`.",
        "",
    ]
    for table in tables:
        if table.name in OPTIONAL_TABLES and not table.rows:
            continue
        lines += [to_markdown(table)]
    if images:
        lines += ["## Figures", ""]
        lines += [f"![{p.stem}]({Path(os.path.relpath(p, target)).as_posix()})\n" for p in images]
    report_path = target / REPORT_FILE
    report_path.write_text("\n".join(lines))
    log.info("report written to %s", report_path)
    return BenchReport(report_path, tables, images)
