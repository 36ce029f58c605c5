"""Voxel grids: integer keys of points, voxel down-sampling, and a sorted key set with counts."""

from __future__ import annotations

import numpy as np

_BITS = 21
_OFFSET = 1 << (_BITS - 1)
_MASK = (1 << _BITS) - 1


def voxel_keys(points: np.ndarray, size: float) -> np.ndarray:
    """One int64 key per point: its voxel's integer coordinates, 21 bits each (about +-1e6 voxels)."""
    idx = np.floor(np.asarray(points, dtype=np.float64) / size).astype(np.int64) + _OFFSET
    idx &= _MASK
    return (idx[:, 0] << (2 * _BITS)) | (idx[:, 1] << _BITS) | idx[:, 2]


def voxel_downsample(points: np.ndarray, colors: np.ndarray, size: float,
                     keys: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Average points and colours per voxel.

    Returns the voxel centroids, their mean colours (same dtype as ``colors``), the sorted
    unique voxel keys, and for every input point the index of its voxel.
    """
    if keys is None:
        keys = voxel_keys(points, size)
    uniq, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    n = len(uniq)
    mean_pts = np.stack([np.bincount(inverse, points[:, k], n) for k in range(3)], axis=1) / counts[:, None]
    mean_col = np.stack([np.bincount(inverse, colors[:, k], n) for k in range(3)], axis=1) / counts[:, None]
    if np.issubdtype(colors.dtype, np.integer):
        mean_col = np.rint(mean_col)
    return mean_pts.astype(points.dtype), mean_col.astype(colors.dtype), uniq, inverse


class VoxelCounter:
    """A sorted set of voxel keys, each with a count; vectorised lookup and insertion."""

    def __init__(self) -> None:
        self.keys = np.zeros(0, np.int64)
        self.counts = np.zeros(0, np.int32)

    def __len__(self) -> int:
        return len(self.keys)

    def _find(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos = np.searchsorted(self.keys, keys)
        if len(self.keys) == 0:
            return np.zeros(len(keys), bool), pos
        found = self.keys[np.minimum(pos, len(self.keys) - 1)] == keys
        return found, pos

    def add(self, keys: np.ndarray) -> np.ndarray:
        """Count each of the sorted unique ``keys`` once; returns which were already present."""
        found, pos = self._find(keys)
        self.counts[pos[found]] += 1
        new = ~found
        self.keys = np.insert(self.keys, pos[new], keys[new])
        self.counts = np.insert(self.counts, pos[new], 1)
        return found

    def count(self, keys: np.ndarray) -> np.ndarray:
        """The count of each key, 0 for keys never added."""
        found, pos = self._find(keys)
        out = np.zeros(len(keys), np.int32)
        out[found] = self.counts[pos[found]]
        return out

    @property
    def nbytes(self) -> int:
        """Memory held by the key and count arrays."""
        return self.keys.nbytes + self.counts.nbytes
