"""The flow interface: a dense flow field with a validity mask, and forward-backward checking."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np


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


def forward_backward_valid(forward: np.ndarray, backward: np.ndarray, threshold: float) -> np.ndarray:
    """Pixels whose forward flow, followed by the backward flow at its end, returns within ``threshold`` px."""
    h, w = forward.shape[:2]
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    map_x = xs + forward[..., 0]
    map_y = ys + forward[..., 1]
    back = cv2.remap(backward, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    err = np.linalg.norm(forward + back, axis=2)
    inside = (map_x >= 0) & (map_x <= w - 1) & (map_y >= 0) & (map_y <= h - 1)
    return inside & (err < threshold)
