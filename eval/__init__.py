"""Evaluation on evo: APE/RPE metrics, plots and reports read from trajectory files."""

from osslam.eval.metrics import EvaluationError, TrajectoryErrors, compute_metrics, to_evo
from osslam.eval.plots import write_plots
from osslam.eval.report import EvalReport, evaluate_files, write_markdown, write_metrics_json

__all__ = [
    "EvalReport",
    "EvaluationError",
    "TrajectoryErrors",
    "compute_metrics",
    "to_evo",
    "evaluate_files",
    "write_markdown",
    "write_metrics_json",
    "write_plots",
]
