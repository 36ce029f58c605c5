"""Descriptor matching: projection search in a radius and brute-force search, both one-to-one."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances between broadcastable arrays of 32-byte ORB descriptors."""
    bits = np.ascontiguousarray(np.bitwise_xor(a, b)).view(np.uint64)
    return np.bitwise_count(bits).sum(axis=-1, dtype=np.int32)


@dataclass
class Matches:
    """Pairs of (query row, feature row) with their descriptor distances."""

    query: np.ndarray
    feature: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.query)


def _one_to_one(query: np.ndarray, feature: np.ndarray, distance: np.ndarray) -> Matches:
    """Keep, for each feature, only its closest query."""
    order = np.lexsort((query, distance, feature))
    query, feature, distance = query[order], feature[order], distance[order]
    first = np.ones(len(feature), dtype=bool)
    first[1:] = feature[1:] != feature[:-1]
    return Matches(query[first], feature[first], distance[first])


def match_by_projection(
    projected: np.ndarray,
    query_desc: np.ndarray,
    feature_uv: np.ndarray,
    feature_desc: np.ndarray,
    radius: float | np.ndarray,
    max_distance: int,
    ratio: float,
    tree: cKDTree | None = None,
    candidates: int = 8,
) -> Matches:
    """Match projected points to the features within ``radius`` pixels of them.

    A match needs a descriptor distance of at most ``max_distance`` and, when a second
    candidate exists, a best distance below ``ratio`` times the second best.
    """
    if len(projected) == 0 or len(feature_uv) == 0:
        return Matches(np.zeros(0, int), np.zeros(0, int), np.zeros(0, np.int32))
    tree = tree if tree is not None else cKDTree(feature_uv)
    k = min(candidates, len(feature_uv))
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(projected),))
    dist_px, idx = tree.query(projected, k=k, distance_upper_bound=float(r.max()))
    dist_px = dist_px.reshape(len(projected), k)
    idx = idx.reshape(len(projected), k)
    valid = np.isfinite(dist_px) & (dist_px <= r[:, None])
    none = np.iinfo(np.int32).max
    d = np.full(valid.shape, none, np.int32)
    pr, pc = np.nonzero(valid)  # only pairs within the radius are compared
    d[pr, pc] = hamming(query_desc[pr], feature_desc[idx[pr, pc]])
    rows = np.arange(len(projected))
    first = np.argmin(d, axis=1)  # the first of equal distances, as a stable sort would give
    best = d[rows, first]
    second = np.partition(d, 1, axis=1)[:, 1] if k > 1 else np.full(len(projected), none)
    ok = (best <= max_distance) & ((second == none) | (best < ratio * second))
    q = rows[ok]
    return _one_to_one(q, idx[q, first[q]], best[ok])


def match_brute_force(query_desc: np.ndarray, feature_desc: np.ndarray, max_distance: int, ratio: float) -> Matches:
    """Match every query descriptor against all features with a ratio test."""
    if len(query_desc) < 2 or len(feature_desc) < 2:
        return Matches(np.zeros(0, int), np.zeros(0, int), np.zeros(0, np.int32))
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    pairs = matcher.knnMatch(query_desc, feature_desc, k=2)
    q, f, dist = [], [], []
    for pair in pairs:
        if len(pair) == 2 and pair[0].distance <= max_distance and pair[0].distance < ratio * pair[1].distance:
            q.append(pair[0].queryIdx)
            f.append(pair[0].trainIdx)
            dist.append(int(pair[0].distance))
    return _one_to_one(np.array(q, dtype=int), np.array(f, dtype=int), np.array(dist, dtype=np.int32))
