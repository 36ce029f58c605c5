"""ORB keypoints spread over an image grid, with undistorted coordinates and depth."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from osslam.config import CameraConfig, FeaturesConfig
from osslam.imaging import values_at
from osslam.types import CameraIntrinsics


@dataclass
class Features:
    """Keypoints of one frame; every array has one row per keypoint."""

    pixels: np.ndarray  # (N, 2) raw (distorted) pixel coordinates
    uv: np.ndarray  # (N, 2) undistorted pixel coordinates
    depth: np.ndarray  # (N,) metres, 0 where missing or out of range
    octave: np.ndarray  # (N,) pyramid level
    descriptors: np.ndarray  # (N, 32) uint8

    def __len__(self) -> int:
        return len(self.uv)

    def subset(self, keep: np.ndarray) -> "Features":
        """The keypoints selected by an index or boolean array."""
        return Features(self.pixels[keep], self.uv[keep], self.depth[keep], self.octave[keep], self.descriptors[keep])


class FeatureExtractor:
    """Detects ORB keypoints evenly over the image, ignoring masked pixels.

    Candidates come from one detection at a low FAST threshold that keeps many times the
    features wanted, and each grid cell then takes its strongest: a crisp, densely textured
    object filling part of the view cannot take every candidate from a blurred background.
    """

    def __init__(self, cfg: FeaturesConfig, camera: CameraConfig, intrinsics: CameraIntrinsics):
        if cfg.candidates < 1:
            raise ValueError(f"features.candidates must be 1 or more, not {cfg.candidates}")
        self.cfg = cfg
        self.intrinsics = intrinsics
        self.min_depth = camera.min_depth
        self.max_depth = camera.max_depth
        common = dict(
            scaleFactor=cfg.scale_factor,
            nlevels=cfg.n_levels,
            edgeThreshold=19,
            patchSize=31,
            scoreType=cv2.ORB_FAST_SCORE,
        )
        self._orb = cv2.ORB_create(nfeatures=cfg.candidates * cfg.n_features, fastThreshold=cfg.fast_threshold,
                                   **common)
        self.scale_sigma2 = cfg.scale_factor ** (2.0 * np.arange(cfg.n_levels))

    def extract(self, gray: np.ndarray, depth: np.ndarray, ignore: np.ndarray | None = None) -> Features:
        """ORB features of a grayscale image; ``ignore`` marks pixels (True) to leave out."""
        h, w = gray.shape
        allowed = None
        if ignore is not None:
            # 255 where features may lie; built from a view, as np.where would make an int64 image first
            allowed = np.logical_not(ignore).view(np.uint8) * np.uint8(255)
        kps = self._distribute(self._orb.detect(gray, allowed), w, h)
        kps, desc = self._orb.compute(gray, kps)
        if desc is None or len(kps) == 0:
            return _empty()
        pixels = _points(kps)
        octave = np.array([k.octave for k in kps], dtype=np.int32)
        return Features(pixels, self.intrinsics.undistort(pixels), self._lookup_depth(depth, pixels), octave, desc)

    def _distribute(self, kps: tuple, w: int, h: int) -> list:
        """Keep the strongest keypoints per grid cell so that features cover the image."""
        if len(kps) == 0:
            return []
        cfg = self.cfg
        pts = _points(kps)
        resp = np.array([k.response for k in kps])
        margin = cfg.edge_margin
        inside = (pts[:, 0] >= margin) & (pts[:, 0] < w - margin) & (pts[:, 1] >= margin) & (pts[:, 1] < h - margin)
        idx = np.flatnonzero(inside)
        if len(idx) == 0:
            return []
        col = np.minimum((pts[idx, 0] * cfg.grid_cols / w).astype(int), cfg.grid_cols - 1)
        row = np.minimum((pts[idx, 1] * cfg.grid_rows / h).astype(int), cfg.grid_rows - 1)
        cell = row * cfg.grid_cols + col
        order = np.lexsort((-resp[idx], cell))
        idx, cell = idx[order], cell[order]
        first = np.searchsorted(cell, cell, side="left")
        rank = np.arange(len(idx)) - first
        quota = max(1, cfg.n_features // (cfg.grid_rows * cfg.grid_cols))
        chosen = idx[rank < quota]
        if len(chosen) < cfg.n_features:
            rest = idx[rank >= quota]
            rest = rest[np.argsort(-resp[rest], kind="stable")][: cfg.n_features - len(chosen)]
            chosen = np.concatenate([chosen, rest])
        return [kps[i] for i in np.sort(chosen)]

    def _lookup_depth(self, depth: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        d = values_at(depth, pixels).astype(np.float64)
        d[~np.isfinite(d) | (d < self.min_depth) | (d > self.max_depth)] = 0.0
        return d


def _points(kps) -> np.ndarray:
    """The keypoints' (x, y) as an (N, 2) float64 array, converted in OpenCV rather than point by point."""
    if len(kps) == 0:
        return np.zeros((0, 2))
    return cv2.KeyPoint_convert(kps).reshape(-1, 2).astype(np.float64)


def _empty() -> Features:
    return Features(
        np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int32), np.zeros((0, 32), np.uint8)
    )
