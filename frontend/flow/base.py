"""The flow interface: a dense flow field with a validity mask, and forward-backward checking."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Protocol

import cv2
import numpy as np

from osslam.config import FlowConfig


@dataclass
class FlowField:
    """Flow from one image to another: ``flow[y, x]`` is the (dx, dy) of pixel (x, y), in pixels.

    ``valid`` marks pixels whose forward and backward flow agree; both arrays are at the
    full image resolution.
    """

    flow: np.ndarray  # (H, W, 2) float32
    valid: np.ndarray  # (H, W) bool


class FlowEstimator(Protocol):
    """Anything that computes dense flow from ``source`` to ``target`` grayscale images."""

    def compute(self, source: np.ndarray, target: np.ndarray) -> FlowField: ...


def textured(gray: np.ndarray, min_eigenvalue: float) -> np.ndarray:
    """Pixels with enough texture for flow to be determined (no aperture problem)."""
    eig = cv2.cornerMinEigenVal(gray, blockSize=5, ksize=3)
    return eig > min_eigenvalue


@lru_cache(maxsize=4)
def _pixel_grid(h: int, w: int) -> np.ndarray:
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)), axis=-1)
    grid.setflags(write=False)
    return grid


def flow_targets(flow: np.ndarray, box: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """Where each pixel's flow ends: an (H, W, 2) map of (x, y), float32, for ``cv2.remap``.

    With ``box`` (x0, y0, x1, y1), only its pixels' targets, the same values as the whole map's.
    """
    grid = _pixel_grid(*flow.shape[:2])
    if box is not None:
        x0, y0, x1, y1 = box
        grid, flow = grid[y0:y1, x0:x1], flow[y0:y1, x0:x1]
    return grid + flow.astype(np.float32, copy=False)


def checked_flow(source: np.ndarray, target: np.ndarray, size: tuple[int, int],
                 both_ways: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
                 cfg: FlowConfig) -> FlowField:
    """Flow from ``source`` to ``target`` computed by ``both_ways`` at ``size`` (width, height), at full resolution.

    ``both_ways`` gives the forward and backward flow of two images; pixels where they
    disagree by more than ``cfg.fb_threshold`` or lack texture (``cfg.min_texture``) are
    invalid.
    """
    h, w = source.shape
    resized = size != (w, h)
    src = cv2.resize(source, size, interpolation=cv2.INTER_AREA) if resized else source
    tgt = cv2.resize(target, size, interpolation=cv2.INTER_AREA) if resized else target
    fwd, bwd = both_ways(src, tgt)
    valid = forward_backward_valid(fwd, bwd, cfg.fb_threshold) & textured(src, cfg.min_texture)
    if resized:
        # scaled before resizing, on a quarter of the pixels: exact where the scales are powers of two
        sx, sy = np.float32(w / size[0]), np.float32(h / size[1])
        fwd = cv2.resize(fwd * sx if sx == sy else fwd * np.array([sx, sy], np.float32), (w, h),
                         interpolation=cv2.INTER_LINEAR)
        valid = cv2.resize(valid.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).view(bool)
    return FlowField(np.ascontiguousarray(fwd, dtype=np.float32), valid)


def forward_backward_valid(forward: np.ndarray, backward: np.ndarray, threshold: float) -> np.ndarray:
    """Pixels whose forward flow, followed by the backward flow at its end, returns within ``threshold`` px."""
    h, w = forward.shape[:2]
    targets = flow_targets(forward)
    back = cv2.remap(backward, targets, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    err = forward + back
    err = cv2.magnitude(err[..., 0], err[..., 1])
    inside = cv2.inRange(targets, (0.0, 0.0), (w - 1.0, h - 1.0)) > 0
    return inside & (err < threshold)
