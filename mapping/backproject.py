"""View depth to coloured points in the camera frame: strided, undistorted, range- and mask-gated."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from osslam.imaging import depth_edges, grow
from osslam.types import CameraIntrinsics


@dataclass(frozen=True)
class CameraPoints:
    """Points in the camera frame (float32, metres), their RGB colour (uint8), and which lie near a dynamic mask.

    ``near_dynamic`` (bool per point; None: none does) marks points back-projected close to
    the frame's dynamic mask, where residue of a mover the mask missed lies.
    """

    points: np.ndarray
    colors: np.ndarray
    near_dynamic: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)


class BackProjector:
    """Back-projects every ``stride``-th pixel along its undistorted ray.

    Depths outside ``[min_depth, max_depth]`` (and NaN) are dropped, as are pixels inside
    the dynamic mask grown by ``mask_dilation`` pixels (depth at a mover's silhouette mixes
    foreground and background, so its edge is removed with it) and pixels within ``border``
    of the image's edge (where depth is least reliable and a mover entering the frame is
    cut off, which the dynamic gate segments worst). With ``edge_step`` > 0, pixels on a
    depth edge (a depth within ``edge_radius`` pixels differs by more than ``edge_step``
    times their own) go too: their depth mixes the two sides, and at a mover's silhouette
    it is the residue the mask most often misses. Points within ``near_radius`` pixels of
    the dynamic mask are marked (on the sampling grid, so to the nearest ``stride``); with
    ``near_radius`` 0 every point is.
    """

    def __init__(self, intrinsics: CameraIntrinsics, stride: int, min_depth: float, max_depth: float,
                 mask_dilation: int = 0, border: int = 0, edge_step: float = 0.0, edge_radius: int = 2,
                 near_radius: int = 0):
        if stride < 1:
            raise ValueError(f"stride must be at least 1, got {stride}")
        if border < 0 or 2 * border >= min(intrinsics.width, intrinsics.height):
            raise ValueError(f"border must be 0 or more and leave part of the image, got {border}")
        if edge_step > 0 and edge_radius < 1:
            raise ValueError(f"edge_radius must be at least 1, got {edge_radius}")
        self.stride = stride
        self.min_depth = min_depth
        self.max_depth = max_depth
        self._start = stride // 2
        v, u = np.mgrid[self._start : intrinsics.height : stride, self._start : intrinsics.width : stride]
        self.grid_shape = u.shape
        pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
        self._rays = intrinsics.normalized(pixels).astype(np.float32)
        self.mask_dilation = mask_dilation
        self.edge_step = edge_step
        self.edge_radius = edge_radius
        self.near_radius = near_radius
        self.border = None
        if border:
            self.border = np.ones((intrinsics.height, intrinsics.width), bool)
            self.border[border:-border, border:-border] = False

    def _sample(self, image: np.ndarray) -> np.ndarray:
        s, o = self.stride, self._start
        return image[o::s, o::s]

    def left_out(self, mask: np.ndarray | None) -> np.ndarray | None:
        """Pixels to leave out: the dynamic mask (True = dynamic) grown by ``mask_dilation``, and the border.

        None when that is nothing.
        """
        grown = grow(mask, self.mask_dilation) if mask is not None and mask.any() else None
        if self.border is None:
            return grown
        return self.border.copy() if grown is None else (grown | self.border)

    def __call__(self, depth: np.ndarray, rgb: np.ndarray, drop: np.ndarray | None = None,
                 dynamic: np.ndarray | None = None) -> CameraPoints:
        """Points of one frame: ``depth`` (H, W) metres, ``rgb`` (H, W, 3) uint8, ``drop`` True = leave out.

        ``drop`` is what :meth:`left_out` gives; ``dynamic`` is the frame's dynamic mask, from
        which the points near it are marked.
        """
        z = self._sample(depth).reshape(-1).astype(np.float32)
        with np.errstate(invalid="ignore"):
            keep = (z >= self.min_depth) & (z <= self.max_depth)
        if drop is not None:
            keep &= ~self._sample(drop).reshape(-1)
        if self.edge_step > 0:
            keep &= ~self._sample(depth_edges(depth, self.edge_step, self.edge_radius)).reshape(-1)
        z = z[keep]
        points = np.empty((len(z), 3), np.float32)
        points[:, :2] = self._rays[keep] * z[:, None]
        points[:, 2] = z
        colors = self._sample(rgb).reshape(-1, 3)[keep]
        return CameraPoints(points, np.ascontiguousarray(colors), self._near(dynamic, keep))

    def _near(self, dynamic: np.ndarray | None, keep: np.ndarray) -> np.ndarray | None:
        """Which of the kept samples lie within ``near_radius`` of ``dynamic`` (None: none does)."""
        if self.near_radius <= 0:
            return np.ones(int(keep.sum()), bool)
        if dynamic is None or not dynamic.any():
            return None
        radius = -(-self.near_radius // self.stride)
        return grow(self._sample(dynamic), radius).reshape(-1)[keep]
