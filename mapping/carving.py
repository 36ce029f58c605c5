"""Free-space evidence against map points: views that saw through a point's place.

A map point left by an object that later moved away lies in space that other views
found empty: their depth along the point's line of sight reaches beyond it. A static
point is instead confirmed (the depth there agrees) or hidden (something lies in front).
Only the static part of a view's depth is kept as evidence: a mover masked in one
view would otherwise confirm the residue of the same mover that another view
missed, and hide the space it passed through.
Each view's depth is kept on a coarse grid (a few tens of kilobytes); past a set
number, every second one kept is let go and from then on only every second view is
taken, so memory and the cost of the test stay bounded on long runs while the views kept
stay spread evenly over the whole run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from osslam.imaging import depth_grid, grid_index, nearest_depth, on_grid
from osslam.types import CameraIntrinsics, kinect_depth_sigma

CHUNK = 200_000  # points transformed at a time


@dataclass
class ViewEvidence:
    """Per map point: how many views saw through its place, and how many saw it there."""

    through: np.ndarray  # (N,) int32
    confirmed: np.ndarray  # (N,) int32


class FreeSpaceViews:
    """View depth grids and the free-space evidence they give against world points.

    A view sees through a point when the nearest depth within one grid cell of the
    point's projection lies more than ``margin`` plus three standard deviations of depth
    noise beyond the point (so depth edges of the scene do not count), and confirms it
    when its depth there lies within that band. At most ``max_views`` views are kept.
    """

    def __init__(self, intrinsics: CameraIntrinsics, stride: int, min_depth: float, max_depth: float,
                 margin: float, max_views: int = 256):
        if max_views < 2:
            raise ValueError(f"max_views must be at least 2, got {max_views}")
        self.intrinsics = intrinsics
        self.max_views = max_views
        self.stride = max(1, stride)
        self.min_depth = min_depth
        self.max_depth = max_depth
        self.margin = margin
        self.grids: dict[int, np.ndarray] = {}
        self._order: dict[int, int] = {}  # view id -> its place among the views added
        self._arrivals = 0
        self._step = 1  # every how many views one is kept

    def add(self, view_id: int, depth: np.ndarray, drop: np.ndarray | None = None) -> None:
        """Keep a view's depth (metres, 0 or NaN where missing) on the grid, as float16, if its turn has come.

        ``drop`` (True = dynamic, as the map leaves it out) marks depth that is no evidence.
        """
        arrival, self._arrivals = self._arrivals, self._arrivals + 1
        if arrival % self._step:
            return
        grid = depth_grid(depth, self.stride)
        grid[(grid < self.min_depth) | (grid > self.max_depth)] = 0.0
        if drop is not None:
            grid[on_grid(drop, self.stride)] = 0.0
        self.grids[view_id] = grid.astype(np.float16)
        self._order[view_id] = arrival
        if len(self.grids) > self.max_views:  # keep every second one of those kept, and from now on
            self._step *= 2
            self.grids = {k: g for k, g in self.grids.items() if self._order[k] % self._step == 0}
            self._order = {k: self._order[k] for k in self.grids}

    @property
    def nbytes(self) -> int:
        """Memory held by the depth grids."""
        return sum(g.nbytes for g in self.grids.values())

    def occupied(self, points: np.ndarray, poses: dict[int, np.ndarray], min_views: int) -> np.ndarray:
        """Keep-mask: False for points at least ``min_views`` views saw through, more than saw them there."""
        seen = self.evidence(points, poses)
        return ~((seen.through >= min_views) & (seen.through > seen.confirmed))

    def evidence(self, points: np.ndarray, poses: dict[int, np.ndarray]) -> ViewEvidence:
        """How many views with a pose in ``poses`` (id -> T_world_camera) see through or confirm each point."""
        through = np.zeros(len(points), np.int32)
        confirmed = np.zeros(len(points), np.int32)
        for view_id, grid in self.grids.items():
            if view_id not in poses:
                continue
            depth = grid.astype(np.float32)
            nearest = nearest_depth(depth)
            R, t = poses[view_id][:3, :3], poses[view_id][:3, 3]
            for start in range(0, len(points), CHUNK):
                part = slice(start, start + CHUNK)
                seen_through, seen_there = self._compare((points[part] - t) @ R, depth, nearest)
                through[part] += seen_through
                confirmed[part] += seen_there
        return ViewEvidence(through, confirmed)

    def _compare(self, local: np.ndarray, depth: np.ndarray, nearest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whether one view's ``depth`` grid (``nearest``: its 3x3 minimum) sees through or confirms ``local``."""
        through = np.zeros(len(local), bool)
        there = np.zeros(len(local), bool)
        front = np.flatnonzero(local[:, 2] > self.min_depth)
        if not len(front):
            return through, there
        row, col, inside = grid_index(self.intrinsics.project(local[front]), self.stride, depth.shape)
        idx, row, col = front[inside], row[inside], col[inside]
        z = local[idx, 2]
        band = self.margin + 3.0 * kinect_depth_sigma(z)
        beyond = nearest[row, col]
        through[idx] = np.isfinite(beyond) & (beyond > z + band)
        measured = depth[row, col]
        there[idx] = (measured > 0) & (np.abs(measured - z) <= band)
        return through, there
