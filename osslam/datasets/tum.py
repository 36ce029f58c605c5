"""A TUM RGB-D sequence folder read lazily as :class:`osslam.types.Frame` objects."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from osslam.config import CameraConfig, DatasetConfig
from osslam.errors import InputError
from osslam.trajectory_io import read_tum
from osslam.types import CameraIntrinsics, Frame

from .association import associate, read_file_list
from .intrinsics import select_intrinsics

log = logging.getLogger(__name__)

#: Ground truth is interpolated only between stamps at most this far apart (seconds).
GT_MAX_GAP = 0.05
#: Median valid depth (metres) outside this range means a wrong depth scale.
PLAUSIBLE_DEPTH = (0.05, 20.0)


class GroundTruth:
    """A TUM ``groundtruth.txt``, validated, interpolated at any time inside its range."""

    def __init__(self, path: Path):
        self.path = path
        trajectory = read_tum(path)
        self.timestamps = trajectory.timestamps
        self.positions = trajectory.positions
        rotations = Rotation.from_quat(trajectory.quaternions)
        self._slerp = Slerp(self.timestamps, rotations) if len(trajectory) > 1 else None

    def pose_at(self, t: float) -> np.ndarray | None:
        """Camera-to-world pose at time ``t``, or None outside the covered range or across a gap."""
        ts = self.timestamps
        if self._slerp is None or t < ts[0] or t > ts[-1]:
            return None
        j = int(np.clip(np.searchsorted(ts, t), 1, len(ts) - 1))
        if ts[j] - ts[j - 1] > GT_MAX_GAP:
            return None
        a = (t - ts[j - 1]) / (ts[j] - ts[j - 1])
        T = np.eye(4)
        T[:3, :3] = self._slerp([t]).as_matrix()[0]
        T[:3, 3] = (1 - a) * self.positions[j - 1] + a * self.positions[j]
        return T


class TumSequence:
    """Associated colour/depth frames of a TUM sequence folder, images loaded on access."""

    def __init__(self, path: str | Path, dataset: DatasetConfig, camera: CameraConfig):
        self.path = Path(path)
        if not self.path.is_dir():
            raise InputError(self.path, "sequence folder not found")
        self.name = self.path.resolve().name
        self.cfg = dataset
        rgb = read_file_list(self.path / "rgb.txt")
        depth = read_file_list(self.path / "depth.txt")
        pairs = associate(rgb.timestamps, depth.timestamps, dataset.max_time_diff)
        if not pairs:
            raise InputError(self.path, f"no colour frame in rgb.txt has a depth frame in depth.txt within "
                                        f"{dataset.max_time_diff} s (dataset.max_time_diff)")
        pairs = pairs[dataset.start_frame :: max(1, dataset.stride)]
        if dataset.max_frames > 0:
            pairs = pairs[: dataset.max_frames]
        if not pairs:
            raise InputError(self.path, "no frames left after dataset.start_frame/stride/max_frames")
        self.timestamps = np.array([rgb.timestamps[i] for i, _ in pairs])
        self._rgb_files = [self.path / rgb.files[i] for i, _ in pairs]
        self._depth_files = [self.path / depth.files[j] for _, j in pairs]
        gt_file = self.path / "groundtruth.txt"
        self.groundtruth_path: Path | None = gt_file if gt_file.is_file() else None
        self.groundtruth = GroundTruth(gt_file) if self.groundtruth_path else None
        self.intrinsics: CameraIntrinsics = select_intrinsics(self.path, camera)
        log.info("%s: %d associated frames", self.name, len(pairs))

    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, i: int) -> Frame:
        if not -len(self) <= i < len(self):
            raise IndexError(i)
        i %= len(self)
        t = float(self.timestamps[i])
        rgb = self._read_rgb(self._rgb_files[i])
        depth = self._read_depth(self._depth_files[i])
        if rgb.shape[:2] != depth.shape:
            raise InputError(self._depth_files[i], f"depth size {depth.shape} differs from colour {rgb.shape[:2]}")
        gt = self.groundtruth.pose_at(t) if self.groundtruth is not None else None
        return Frame(i, t, rgb, depth, self.intrinsics, gt, source=str(self._rgb_files[i]))

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def _read_rgb(self, path: Path) -> np.ndarray:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(path, "missing or unreadable colour image")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)

    def _read_depth(self, path: Path) -> np.ndarray:
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise InputError(path, "missing or unreadable depth image")
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise InputError(path, f"depth must be a single-channel 16-bit PNG, got {raw.dtype} with shape {raw.shape}")
        depth = raw.astype(np.float32) / self.cfg.depth_scale
        valid = depth[depth > 0]
        if valid.size:
            median = float(np.median(valid))
            if not PLAUSIBLE_DEPTH[0] <= median <= PLAUSIBLE_DEPTH[1]:
                raise InputError(path, f"median depth {median:.3g} m is implausible; check dataset.depth_scale "
                                       f"(now {self.cfg.depth_scale:g}, TUM uses 5000)")
        return depth
