"""A PNG preview of the map without a display: top and oblique orthographic views on matplotlib's Agg canvas.

Views use the camera convention of the first keyframe (x right, y down, z forward), so
"up" is -y: the top view looks down the y axis, the oblique one from above and to the side.
Points are drawn far to near, coloured by their own colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

DPI = 100
VIEWS = {"top view": (90.0, -90.0), "oblique view": (35.0, -60.0)}  # (elevation, azimuth) in degrees


def project(points: np.ndarray, elevation_deg: float, azimuth_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Orthographic screen coordinates (N, 2) and depth towards the viewer (N,) of camera-convention points."""
    up_frame = np.column_stack([points[:, 0], points[:, 2], -points[:, 1]])  # x right, z forward, -y up
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    eye = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    right = np.array([-np.sin(az), np.cos(az), 0.0])
    up = np.cross(eye, right)
    return np.column_stack([up_frame @ right, up_frame @ up]), up_frame @ eye


def render_preview(points: np.ndarray, colors: np.ndarray, path: str | Path, max_points: int = 60000,
                   seed: int = 0) -> Path:
    """Write a two-panel PNG (top and oblique views) of a random subsample of at most ``max_points``."""
    if len(points) > max_points:
        pick = np.random.default_rng(seed).choice(len(points), max_points, replace=False)
        points, colors = points[pick], colors[pick]
    rgb = np.asarray(colors, np.float64) / 255.0
    fig = Figure(figsize=(11.0, 5.0))
    for k, (title, (el, az)) in enumerate(VIEWS.items()):
        ax = fig.add_subplot(1, 2, k + 1)
        xy, depth = project(points, el, az)
        order = np.argsort(depth)
        ax.scatter(xy[order, 0], xy[order, 1], c=rgb[order], s=0.6, linewidths=0, rasterized=True)
        ax.set_title(f"Static map, {title} ({len(points)} points)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("m")
        ax.set_ylabel("m")
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    FigureCanvasAgg(fig)
    path = Path(path)
    fig.savefig(path, dpi=DPI)
    return path
