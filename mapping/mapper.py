"""The mapping stage as the system sees it: map views in, map.ply / mesh.ply / map_preview.png out.

A map view is a tracked frame whose depth enters the map: one every
``mapping.view_interval`` seconds (or every keyframe). Taking views on a clock rather
than at the tracker's keyframes keeps the map's evidence the same whichever frames
movers made keyframes, so a run with movers and one without are cleaned alike.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from osslam.config import MappingConfig
from osslam.types import CameraIntrinsics

from .backproject import BackProjector
from .carving import FreeSpaceViews
from .fusion import DenseMap, FusedCloud

log = logging.getLogger(__name__)

MAP_FILE = "map.ply"
MESH_FILE = "mesh.ply"
PREVIEW_FILE = "map_preview.png"
MAP_VIEWS_FILE = "map_views.txt"


@dataclass
class MapStats:
    """Counts and cost of the dense map; the cleaning counts are filled in when the map is saved."""

    views: int = 0
    points_backprojected: int = 0
    points_stored: int = 0
    store_mb: float = 0.0
    ms_per_view: float = 0.0
    points_fused: int | None = None
    removed_free_space: int | None = None
    removed_sor: int | None = None
    removed_residue: int | None = None
    points_final: int | None = None
    save_s: float | None = None


@dataclass
class _Waiting:
    """A view held back until the masks of the frames after it have been joined to its own."""

    view_id: int
    pose: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray | None
    frames_left: int
    fresh: bool = True

    def join(self, mask: np.ndarray | None) -> None:
        """Join one later frame's mask."""
        if mask is not None:
            self.mask = mask.copy() if self.mask is None else (self.mask | mask)
        self.frames_left -= 1


def write_ply(path: str | Path, cloud: FusedCloud) -> Path:
    """Write a coloured point cloud as binary PLY with Open3D."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
    pcd.colors = o3d.utility.Vector3dVector(cloud.colors.astype(np.float64) / 255.0)
    if not o3d.io.write_point_cloud(str(path), pcd):
        raise OSError(f"{path}: could not write the map")
    return Path(path)


class DenseMapper:
    """Back-projects each map view, keeps it on the voxel grid, and builds the cleaned map on save."""

    def __init__(self, cfg: MappingConfig, intrinsics: CameraIntrinsics):
        if cfg.mask_frames < 0:
            raise ValueError(f"mapping.mask_frames must be 0 or more, got {cfg.mask_frames}")
        if cfg.mask_frames_after < 0:
            raise ValueError(f"mapping.mask_frames_after must be 0 or more, got {cfg.mask_frames_after}")
        if not cfg.view_interval >= 0:
            raise ValueError(f"mapping.view_interval must be 0 or more seconds, got {cfg.view_interval}")
        self.cfg = cfg
        self._recent_masks: deque[np.ndarray | None] = deque(maxlen=cfg.mask_frames)
        self._waiting: list[_Waiting] = []
        self.project = BackProjector(intrinsics, cfg.stride, cfg.min_depth, cfg.max_depth, cfg.mask_dilation,
                                     cfg.image_border, cfg.depth_edge, cfg.depth_edge_radius,
                                     cfg.residue_mask_radius)
        self.map = DenseMap(cfg.voxel_size, cfg.support_voxel)
        self.free_space = None
        if cfg.free_space_views > 0:
            self.free_space = FreeSpaceViews(intrinsics, cfg.stride, cfg.min_depth, cfg.max_depth,
                                             cfg.free_space_margin, cfg.free_space_max_views)
        self.tsdf = None
        if cfg.tsdf:
            from .tsdf import TsdfStore

            self.tsdf = TsdfStore(intrinsics, cfg.tsdf_voxel, cfg.tsdf_trunc, cfg.max_depth)
        self._ms_total = 0.0
        self._last_view: float | None = None
        self._saved: MapStats | None = None

    def wants_view(self, timestamp: float, is_keyframe: bool) -> bool:
        """Whether a tracked frame at ``timestamp`` should be the next map view.

        With ``mapping.view_interval`` > 0: the first frame, then each frame at least that
        many seconds after the last view; with 0: every keyframe.
        """
        if self.cfg.view_interval == 0:
            return is_keyframe
        return self._last_view is None or timestamp - self._last_view >= self.cfg.view_interval

    def add_view(self, view_id: int, timestamp: float, T_world_camera: np.ndarray, rgb: np.ndarray,
                 depth: np.ndarray, mask: np.ndarray | None = None) -> int:
        """Add a view's static points (``mask`` True = dynamic); returns how many new voxels it filled.

        ``view_id`` names the view's pose in :meth:`build`. The mask is joined with those of
        the last ``mapping.mask_frames`` frames given to :meth:`remember_mask`. With
        ``mapping.mask_frames_after``, the view waits for the masks of that many frames after
        it (0 voxels are returned then; it enters the map when the last of them is
        remembered, or when the map is built).
        """
        self._last_view = timestamp
        joined = self._joined(mask)
        if self.cfg.mask_frames_after:
            self._waiting.append(_Waiting(view_id, T_world_camera, rgb.copy(), depth.copy(), joined,
                                          self.cfg.mask_frames_after))
            self._saved = None
            return 0
        return self._insert(view_id, T_world_camera, rgb, depth, joined)

    def _insert(self, view_id: int, T_world_camera: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
                mask: np.ndarray | None) -> int:
        start = time.perf_counter()
        drop = self.project.left_out(mask)
        kept = self.map.add(view_id, T_world_camera, self.project(depth, rgb, drop, mask))
        if self.free_space is not None:
            self.free_space.add(view_id, depth, drop)
        if self.tsdf is not None:
            self.tsdf.add(view_id, rgb, depth, drop)
        self._ms_total += (time.perf_counter() - start) * 1e3
        self._saved = None
        return kept

    def remember_mask(self, mask: np.ndarray | None) -> None:
        """Take a frame's dynamic mask (after any view of that frame was added) for the views around it."""
        if self.cfg.mask_frames:
            self._recent_masks.append(None if mask is None else mask.copy())  # the caller may reuse its buffer
        still = []
        for waiting in self._waiting:
            if waiting.fresh:  # the view's own frame
                waiting.fresh = False
                still.append(waiting)
                continue
            waiting.join(mask)
            if waiting.frames_left:
                still.append(waiting)
            else:
                self._insert(waiting.view_id, waiting.pose, waiting.rgb, waiting.depth, waiting.mask)
        self._waiting = still

    def _flush(self) -> None:
        """Insert the views still waiting for later masks, with the masks that came."""
        for waiting in self._waiting:
            self._insert(waiting.view_id, waiting.pose, waiting.rgb, waiting.depth, waiting.mask)
        self._waiting = []

    def _joined(self, mask: np.ndarray | None) -> np.ndarray | None:
        """``mask`` joined with the kept masks of the frames before it; None when there is none."""
        masks = [m for m in (*self._recent_masks, mask) if m is not None]
        return np.logical_or.reduce(masks) if masks else None

    def build(self, poses: dict[int, np.ndarray]) -> tuple[FusedCloud, MapStats]:
        """Fuse the views at ``poses`` (id -> T_world_camera), drop what views saw through, and clean."""
        from .cleaning import clean

        self._flush()
        fused = self.map.fuse(poses)
        free = np.ones(len(fused), bool)
        if self.free_space is not None:
            free = self.free_space.occupied(fused.points, poses, self.cfg.free_space_views)
        cleaned, report = clean(fused.select(free), self.cfg)
        stats = self.stats()
        stats.points_fused = len(fused)
        stats.removed_free_space = int((~free).sum())
        stats.removed_sor = report.removed_sor
        stats.removed_residue = report.removed_residue
        stats.points_final = len(cleaned)
        return cleaned, stats

    def save(self, out_dir: str | Path, poses: dict[int, np.ndarray]) -> MapStats:
        """Write map.ply, mesh.ply (TSDF on) and map_preview.png (preview on) built at ``poses``."""
        start = time.perf_counter()
        out = Path(out_dir)
        cloud, stats = self.build(poses)
        write_ply(out / MAP_FILE, cloud)
        if self.tsdf is not None:
            import open3d as o3d

            o3d.io.write_triangle_mesh(str(out / MESH_FILE), self.tsdf.mesh(poses))
        if self.cfg.preview and len(cloud):
            from .preview import render_preview

            render_preview(cloud.points, cloud.colors, out / PREVIEW_FILE, self.cfg.preview_points)
        stats.save_s = round(time.perf_counter() - start, 3)
        log.info("map: %d points fused, %d removed as seen through, %d by SOR, %d as residue, %d written to %s",
                 stats.points_fused, stats.removed_free_space, stats.removed_sor, stats.removed_residue,
                 stats.points_final, out / MAP_FILE)
        self._saved = stats
        return stats

    def stats(self) -> MapStats:
        """The latest saved figures, or the running counts before any save."""
        if self._saved is not None:
            return self._saved
        n = len(self.map.clouds)
        held = self.map.nbytes + (self.free_space.nbytes if self.free_space else 0)
        return MapStats(views=n, points_backprojected=self.map.points_in, points_stored=self.map.stored_points,
                        store_mb=round(held / 2**20, 3), ms_per_view=round(self._ms_total / n, 3) if n else 0.0)

    def stats_dict(self) -> dict:
        """:meth:`stats` as a plain dictionary for stats.json."""
        return asdict(self.stats())
