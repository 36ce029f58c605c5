"""View clouds kept in their own camera frames and fused on a voxel grid with their final poses.

Each view stores only the voxels no earlier view filled (found on the world grid at
the poses known when it arrives), so revisiting a place adds nothing and memory grows with
the explored volume, not with time. A coarser grid counts how many views saw each
region (the support the residue step uses); a voxel is near a dynamic mask when any of
its points was. Points stay in their view's camera frame, so fusing with the final,
optimised poses re-anchors them: the map follows the trajectory.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from osslam.geometry import transform_points

from .backproject import CameraPoints
from .voxels import VoxelCounter, voxel_downsample, voxel_keys

log = logging.getLogger(__name__)


@dataclass
class FusedCloud:
    """A world-frame cloud: per point its position (float64), RGB colour (uint8), view support and mask nearness.

    ``near_dynamic`` marks the points back-projected near a view's dynamic mask.
    """

    points: np.ndarray
    colors: np.ndarray
    support: np.ndarray
    near_dynamic: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def select(self, keep: np.ndarray) -> "FusedCloud":
        """The points where ``keep`` is True."""
        return FusedCloud(self.points[keep], self.colors[keep], self.support[keep], self.near_dynamic[keep])


class DenseMap:
    """Per-view voxelised clouds, fused on demand with whatever poses are current."""

    def __init__(self, voxel_size: float, support_voxel: float):
        self.voxel_size = voxel_size
        self.support_voxel = support_voxel
        self.clouds: dict[int, CameraPoints] = {}
        self._occupied = VoxelCounter()
        self._support = VoxelCounter()
        self.points_in = 0

    def add(self, view_id: int, T_world_camera: np.ndarray, cam: CameraPoints) -> int:
        """Add one view's points (camera frame) seen from ``T_world_camera``; returns how many were kept."""
        self.points_in += len(cam)
        if len(cam) == 0:
            self.clouds[view_id] = cam
            return 0
        world = transform_points(T_world_camera, cam.points.astype(np.float64))
        self._support.add(np.unique(voxel_keys(world, self.support_voxel)))
        pts, cols, keys, inverse = voxel_downsample(world, cam.colors, self.voxel_size)
        new = ~self._occupied.add(keys)
        R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
        local = ((pts[new] - t) @ R).astype(np.float32)
        near = None if cam.near_dynamic is None else _any_per_voxel(cam.near_dynamic, inverse, len(pts))[new]
        self.clouds[view_id] = CameraPoints(local, cols[new], near)
        return int(new.sum())

    def fuse(self, poses: dict[int, np.ndarray]) -> FusedCloud:
        """All view clouds moved by ``poses`` (id -> T_world_camera), voxel down-sampled together."""
        parts, colors, near = [], [], []
        for view_id, cloud in self.clouds.items():
            if view_id not in poses:
                log.warning("view %d has no pose; its %d map points are left out", view_id, len(cloud))
                continue
            parts.append(transform_points(poses[view_id], cloud.points.astype(np.float64)))
            colors.append(cloud.colors)
            near.append(np.zeros(len(cloud), bool) if cloud.near_dynamic is None else cloud.near_dynamic)
        if not parts:
            return FusedCloud(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.int32), np.zeros(0, bool))
        pts, cols, _, inverse = voxel_downsample(np.concatenate(parts), np.concatenate(colors), self.voxel_size)
        support = np.maximum(self._support.count(voxel_keys(pts, self.support_voxel)), 1)
        return FusedCloud(pts, cols, support, _any_per_voxel(np.concatenate(near), inverse, len(pts)))

    @property
    def stored_points(self) -> int:
        """Points held over all views."""
        return sum(len(c) for c in self.clouds.values())

    @property
    def nbytes(self) -> int:
        """Memory held by the view clouds and the voxel indices."""
        clouds = sum(c.points.nbytes + c.colors.nbytes + (0 if c.near_dynamic is None else c.near_dynamic.nbytes)
                     for c in self.clouds.values())
        return clouds + self._occupied.nbytes + self._support.nbytes


def _any_per_voxel(flags: np.ndarray, inverse: np.ndarray, n_voxels: int) -> np.ndarray:
    """Per voxel, whether any of its points (``inverse``: each point's voxel) has its flag set."""
    return np.bincount(inverse, flags, n_voxels) > 0
