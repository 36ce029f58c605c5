"""Ground-truth camera poses of a sequence, interpolated at frame timestamps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from osslam.trajectory_io import read_tum

#: Ground truth is interpolated only between neighbouring stamps at most this far apart (seconds).
GT_MAX_GAP = 0.05


class GroundTruth:
    """Camera-to-world poses at increasing timestamps, as arrays, interpolated on request.

    ``timestamps`` is (N,) and ``poses`` (N, 4, 4). :meth:`pose_at` interpolates linearly
    in translation and by slerp in rotation.
    """

    def __init__(self, timestamps: np.ndarray, poses: np.ndarray, max_gap: float = GT_MAX_GAP):
        self.timestamps = np.asarray(timestamps, dtype=np.float64)
        self.poses = np.asarray(poses, dtype=np.float64)
        if self.poses.shape != (len(self.timestamps), 4, 4):
            raise ValueError(f"{len(self.timestamps)} timestamps need poses of shape (N, 4, 4), got {self.poses.shape}")
        if len(self.timestamps) == 0:
            raise ValueError("ground truth needs at least one pose")
        if np.any(np.diff(self.timestamps) <= 0):
            raise ValueError("ground-truth timestamps must increase")
        self.max_gap = max_gap
        rotations = Rotation.from_matrix(self.poses[:, :3, :3])
        self._slerp = Slerp(self.timestamps, rotations) if len(self.timestamps) > 1 else None

    @classmethod
    def from_file(cls, path: str | Path) -> GroundTruth:
        """Read and validate a TUM ``groundtruth.txt``; bad lines raise InputError naming file and line."""
        trajectory = read_tum(path)
        return cls(trajectory.timestamps, trajectory.poses)

    def __len__(self) -> int:
        """Number of poses."""
        return len(self.timestamps)

    def pose_at(self, t: float) -> np.ndarray | None:
        """Camera-to-world pose at time ``t``.

        None outside the covered time range, or where the two stamps around ``t`` are
        more than ``max_gap`` seconds apart. A time equal to a stamp gives that pose.
        """
        ts = self.timestamps
        if t < ts[0] or t > ts[-1]:
            return None
        j = int(np.searchsorted(ts, t))
        if ts[j] == t:
            return self.poses[j].copy()
        if ts[j] - ts[j - 1] > self.max_gap:
            return None
        a = (t - ts[j - 1]) / (ts[j] - ts[j - 1])
        pose = np.eye(4)
        pose[:3, :3] = self._slerp([t]).as_matrix()[0]
        pose[:3, 3] = (1 - a) * self.poses[j - 1, :3, 3] + a * self.poses[j, :3, 3]
        return pose
