"""Optional mesh: views integrated into Open3D's hashed (scalable) TSDF with their final poses.

View images are kept undistorted at half resolution (depth in millimetres) so that the
mesh, like the cloud, is built from the optimised poses when the map is saved.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from osslam.geometry import invert
from osslam.types import CameraIntrinsics


@dataclass
class _ViewImages:
    rgb: np.ndarray  # (h, w, 3) uint8
    depth_mm: np.ndarray  # (h, w) uint16, 0 = missing or masked


class TsdfStore:
    """Half-resolution undistorted view images, integrated into a TSDF volume on demand."""

    SCALE = 2
    MIN_WEIGHT = 1.0

    def __init__(self, intrinsics: CameraIntrinsics, voxel: float, trunc: float, max_depth: float):
        self.voxel, self.trunc, self.max_depth = voxel, trunc, max_depth
        w, h = intrinsics.width, intrinsics.height
        self._maps = cv2.initUndistortRectifyMap(intrinsics.K, intrinsics.dist_coeffs, None, intrinsics.K, (w, h),
                                                 cv2.CV_32FC1)
        s = self.SCALE
        self.size = (w // s, h // s)
        self.K = (intrinsics.fx / s, intrinsics.fy / s, (intrinsics.cx + 0.5) / s - 0.5,
                  (intrinsics.cy + 0.5) / s - 0.5)
        self.frames: dict[int, _ViewImages] = {}

    def add(self, view_id: int, rgb: np.ndarray, depth: np.ndarray, drop: np.ndarray | None) -> None:
        """Keep one view's images; ``drop`` (True = dynamic, already grown) pixels lose their depth."""
        d = np.nan_to_num(depth.astype(np.float32))
        if drop is not None:
            d = np.where(drop, 0.0, d)
        d = cv2.remap(d, *self._maps, cv2.INTER_NEAREST)
        c = cv2.remap(rgb, *self._maps, cv2.INTER_LINEAR)
        s = self.SCALE
        depth_mm = np.clip(np.rint(d[::s, ::s] * 1000.0), 0, 65535).astype(np.uint16)
        self.frames[view_id] = _ViewImages(np.ascontiguousarray(c[::s, ::s]), depth_mm)

    def mesh(self, poses: dict[int, np.ndarray]):
        """Integrate every kept view at its pose in ``poses``; returns an Open3D (legacy) triangle mesh.

        Uses Open3D's hashed voxel-block TSDF (``t.geometry.VoxelBlockGrid``, the tensor
        version of the scalable TSDF volume; the legacy ``ScalableTSDFVolume`` of the
        Open3D 0.20 wheel extracted empty meshes here). Surfaces integrated fewer than
        ``MIN_WEIGHT`` times are left out.
        """
        import open3d as o3d
        import open3d.core as o3c

        cpu = o3c.Device("CPU:0")
        grid = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)), voxel_size=self.voxel, block_resolution=16, block_count=50000,
            device=cpu)
        fx, fy, cx, cy = self.K
        K = o3c.Tensor(np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), o3c.float64)
        for view_id, images in self.frames.items():
            if view_id not in poses:
                continue
            extrinsic = o3c.Tensor(invert(poses[view_id]), o3c.float64)
            depth = o3d.t.geometry.Image(o3c.Tensor(images.depth_mm))
            color = o3d.t.geometry.Image(o3c.Tensor(images.rgb))
            trunc = self.trunc / self.voxel
            blocks = grid.compute_unique_block_coordinates(depth, K, extrinsic, 1000.0, self.max_depth, trunc)
            grid.integrate(blocks, depth, color, K, extrinsic, 1000.0, self.max_depth, trunc)
        mesh = grid.extract_triangle_mesh(weight_threshold=self.MIN_WEIGHT).to_legacy()
        colors = np.asarray(mesh.vertex_colors)
        if len(colors) and colors.max() > 1.0:
            mesh.vertex_colors = o3d.utility.Vector3dVector(colors / 255.0)
        return mesh
