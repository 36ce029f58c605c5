"""PNG plots of an evaluation: trajectory top and side views, APE over time.

Figures are drawn on matplotlib's Agg canvas directly, without pyplot, so no display is
needed and the process-wide backend is left alone.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from osslam.eval.metrics import TrajectoryErrors

log = logging.getLogger(__name__)

DPI = 100
PLOT_FILES = {"trajectory_top": "trajectory_xy.png", "trajectory_side": "trajectory_xz.png", "ape": "ape_over_time.png"}
PLANES = {"xy": (0, 1), "xz": (0, 2)}


def _save(fig: Figure, path: Path) -> Path:
    """Render a figure to a PNG file on the Agg canvas."""
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI)
    return path


def plot_trajectory(reference_xyz: np.ndarray, estimate_xyz: np.ndarray, path: str | Path,
                    plane: str = "xy") -> Path:
    """Plot ground-truth and (aligned) estimated positions projected on ``plane`` ("xy" or "xz")."""
    i, j = PLANES[plane]
    fig = Figure(figsize=(6.0, 5.0))
    ax = fig.add_subplot()
    ax.plot(reference_xyz[:, i], reference_xyz[:, j], "--", color="0.4", label="ground truth")
    ax.plot(estimate_xyz[:, i], estimate_xyz[:, j], "-", color="tab:blue", label="estimate (aligned)")
    ax.plot(*reference_xyz[0, [i, j]], "o", color="0.4", markersize=4)
    ax.set_xlabel(f"{plane[0]} (m)")
    ax.set_ylabel(f"{plane[1]} (m)")
    ax.set_title(f"Trajectory, {'top' if plane == 'xy' else 'side'} view ({plane[0]}-{plane[1]})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_ape(timestamps: np.ndarray, errors: np.ndarray, path: str | Path, stats: dict[str, float]) -> Path:
    """Plot the APE of every pose against seconds from the first one, with RMSE, mean and median lines."""
    fig = Figure(figsize=(7.0, 3.5))
    ax = fig.add_subplot()
    ax.plot(timestamps - timestamps[0], errors, "-", color="0.3", linewidth=1.0, label="APE")
    for name, color in (("rmse", "tab:blue"), ("mean", "tab:green"), ("median", "tab:orange")):
        ax.axhline(stats[name], color=color, linewidth=1.0, label=f"{name} {stats[name]:.4f} m")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("APE (m)")
    ax.set_title("Absolute pose error (translation) over time")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left")
    fig.tight_layout()
    return _save(fig, Path(path))


def write_plots(errors: TrajectoryErrors, out_dir: str | Path) -> dict[str, Path]:
    """Write the three plots of :data:`PLOT_FILES` into ``out_dir``; returns their paths by key."""
    out = Path(out_dir)
    ref = errors.reference.positions_xyz
    est = errors.aligned_estimate.positions_xyz
    paths = {
        "trajectory_top": plot_trajectory(ref, est, out / PLOT_FILES["trajectory_top"], "xy"),
        "trajectory_side": plot_trajectory(ref, est, out / PLOT_FILES["trajectory_side"], "xz"),
        "ape": plot_ape(errors.timestamps, errors.ape_errors, out / PLOT_FILES["ape"], errors.stats["ape"]),
    }
    log.debug("wrote plots %s", ", ".join(str(p) for p in paths.values()))
    return paths
