"""Comparing clouds: distance of each point to a reference cloud, and the share farther than a threshold."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def distances_to(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Each point's distance to its nearest reference point."""
    if len(reference) == 0:
        return np.full(len(points), np.inf)
    dist, _ = cKDTree(reference).query(points, k=1, workers=-1)
    return dist


def fraction_farther(points: np.ndarray, reference: np.ndarray, threshold: float) -> float:
    """Share of ``points`` farther than ``threshold`` from every reference point (ghost points, for instance)."""
    if len(points) == 0:
        return 0.0
    return float((distances_to(points, reference) > threshold).mean())
