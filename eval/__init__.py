"""Evaluation on evo: APE/RPE metrics, plots and reports read from trajectory files."""

from osslam.eval.metrics import EvaluationError, TrajectoryErrors, compute_metrics
from osslam.eval.plots import write_plots
from osslam.eval.report import EvalReport, evaluate_files, write_markdown, write_metrics_json
from osslam.eval.trajectory_io import TumTrajectory, read_tum, write_tum

__all__ = [
    "EvalReport",
    "EvaluationError",
    "TrajectoryErrors",
    "TumTrajectory",
    "compute_metrics",
    "evaluate_files",
    "read_tum",
    "write_markdown",
    "write_metrics_json",
    "write_plots",
    "write_tum",
]
