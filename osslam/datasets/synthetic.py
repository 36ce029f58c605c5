"""A synthetic RGB-D sequence: the textured room of :mod:`.synthetic_scene` along a smooth path, exact poses.

Everything is reproducible from ``SyntheticConfig.seed``: the textures, the camera path,
and each frame's sensor noise (seeded by the seed and the frame index, so frames can be
rendered in any order).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from osslam.errors import InputError
from osslam.trajectory_io import write_tum
from osslam.types import CameraIntrinsics, Frame, kinect_depth_sigma

from .groundtruth import GroundTruth
from .intrinsics import write_camera_file
from .sequence import FrameSequence
from .synthetic_scene import RoomRenderer

log = logging.getLogger(__name__)

#: Depth PNGs written by :meth:`SyntheticSequence.write_tum` store metres times this (TUM's scale).
TUM_DEPTH_SCALE = 5000.0
_DEPTH_EDGE = 0.1  # metres; the far side of a larger jump between neighbours loses its depth (holes)

# Camera path: per axis, (amplitude, frequency in Hz) of two sinusoids around a centre.
_CENTRE = np.array([0.0, -0.1, 0.35])
_POSITION_WAVES = (((0.22, 0.12), (0.05, 0.35)), ((0.08, 0.10), (0.03, 0.30)), ((0.20, 0.09), (0.05, 0.30)))
# yaw (about y), pitch (about x), roll (about z), radians.
_ANGLE_WAVES = (((0.30, 0.07), (0.05, 0.25)), ((0.10, 0.10), (0.03, 0.30)), ((0.04, 0.15), (0.0, 0.0)))


@dataclass
class SyntheticConfig:
    """Length, frame rate, seed, image size, intrinsics and sensor noise of a synthetic sequence."""

    n_frames: int = 150
    fps: float = 30.0
    seed: int = 0
    width: int = 640
    height: int = 480
    fx: float = 525.0
    fy: float = 525.0
    cx: float = 319.5
    cy: float = 239.5
    depth_noise: bool = True  # Gaussian, sigma = 0.0012 + 0.0019 (z - 0.4)^2 metres (Kinect-like)
    dropout: float = 0.02  # fraction of depth pixels randomly set to 0
    holes: bool = True  # a few blob-shaped holes per frame and no depth just behind occluding edges
    image_noise: float = 2.0  # standard deviation of grey-level noise added to the colour image
    max_depth: float = 8.0  # depth farther than this reads 0 (no measurement)
    start_time: float = 1000.0  # timestamp of the first frame, seconds

    def __post_init__(self):
        if self.n_frames < 1 or self.fps <= 0 or self.width < 1 or self.height < 1 or self.fx <= 0 or self.fy <= 0:
            raise ValueError("n_frames, fps, width, height, fx and fy must be positive")
        if not 0.0 <= self.dropout < 1.0 or self.image_noise < 0:
            raise ValueError("dropout must be in [0, 1) and image_noise >= 0")
        if not 0 < self.max_depth <= 65535 / TUM_DEPTH_SCALE:
            raise ValueError(f"max_depth must be in (0, {65535 / TUM_DEPTH_SCALE:.4g}] metres")


def camera_path(rng: np.random.Generator, times: np.ndarray) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) at ``times`` (seconds): sums of sinusoids with random phases.

    The camera stays near the middle of the room looking at the far wall (+z) about 2 m
    away, moving at 0.1-0.3 m/s and turning at up to about 15 deg/s, like TUM fr1/xyz.
    Frequencies vary by +-20 % with the seed.
    """

    def waves(spec) -> np.ndarray:
        out = np.zeros((len(times), len(spec)))
        for k, components in enumerate(spec):
            for amplitude, hz in components:
                omega = 2 * np.pi * hz * rng.uniform(0.8, 1.2)
                out[:, k] += amplitude * np.sin(omega * times + rng.uniform(0, 2 * np.pi))
        return out

    positions = _CENTRE + waves(_POSITION_WAVES)
    yaw, pitch, roll = waves(_ANGLE_WAVES).T
    poses = np.tile(np.eye(4), (len(times), 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("YXZ", np.column_stack([yaw, pitch, roll])).as_matrix()
    poses[:, :3, 3] = positions
    return poses


class SyntheticSequence(FrameSequence):
    """Frames of the synthetic room rendered on access, each with its exact ``gt_pose``.

    Offers what :class:`~osslam.datasets.tum.TumSequence` does (``name``, ``intrinsics``,
    ``timestamps``, ``groundtruth`` with (N,) timestamps and (N, 4, 4) poses, indexing,
    iteration) and :meth:`write_tum` to save it as a TUM folder.
    """

    def __init__(self, cfg: SyntheticConfig | None = None):
        self.cfg = cfg = cfg or SyntheticConfig()
        self.name = f"synthetic_room_seed{cfg.seed}"
        self.intrinsics = CameraIntrinsics(cfg.fx, cfg.fy, cfg.cx, cfg.cy, cfg.width, cfg.height)
        scene_seed, path_seed = np.random.SeedSequence(cfg.seed, spawn_key=(0,)).spawn(2)
        self.timestamps = np.round(cfg.start_time + np.arange(cfg.n_frames) / cfg.fps, 6)
        poses = camera_path(np.random.default_rng(path_seed), self.timestamps - cfg.start_time)
        self.groundtruth = GroundTruth(self.timestamps, poses)
        self.groundtruth_path = None
        self._renderer = RoomRenderer(self.intrinsics, np.random.default_rng(scene_seed))

    def _load(self, i: int) -> Frame:
        """Render frame ``i`` and add its seeded sensor noise."""
        cfg = self.cfg
        pose = self.groundtruth.poses[i].copy()
        rgb, depth = self._renderer.render(pose)
        rng = np.random.default_rng(np.random.SeedSequence(cfg.seed, spawn_key=(1, i)))
        if cfg.image_noise > 0:
            noise = rng.standard_normal((cfg.height, cfg.width, 1), dtype=np.float32) * np.float32(cfg.image_noise)
            rgb = np.clip(rgb + noise, 0, 255).astype(np.uint8)
        depth = self._degrade_depth(depth, rng)
        return Frame(i, float(self.timestamps[i]), rgb, depth, self.intrinsics, pose, source=f"{self.name}[{i}]")

    def _degrade_depth(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Exact depth made sensor-like: noise, random dropouts, holes and the range limit, in place."""
        cfg = self.cfg
        lost = np.zeros(depth.shape, np.uint8)
        if cfg.holes:
            far_side = np.zeros(depth.shape, bool)
            jump = depth[:, 1:] - depth[:, :-1]
            far_side[:, 1:] |= jump > _DEPTH_EDGE
            far_side[:, :-1] |= jump < -_DEPTH_EDGE
            lost[far_side] = 1
            for _ in range(rng.poisson(2.0)):
                centre = (int(rng.integers(0, cfg.width)), int(rng.integers(0, cfg.height)))
                axes = (int(rng.integers(3, 25)), int(rng.integers(3, 25)))
                cv2.ellipse(lost, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        if cfg.depth_noise:
            sigma = kinect_depth_sigma(depth)
            depth += rng.standard_normal(depth.shape, dtype=np.float32) * sigma
        if cfg.dropout > 0:
            lost[rng.random(depth.shape, dtype=np.float32) < cfg.dropout] = 1
        depth[(lost > 0) | (depth > cfg.max_depth) | (depth < 0)] = 0.0
        return depth

    def write_tum(self, out_dir: str | Path) -> Path:
        """Write the sequence as a TUM folder and return it.

        Writes ``rgb/*.png``, ``depth/*.png`` (uint16, metres x 5000), ``rgb.txt``,
        ``depth.txt``, ``groundtruth.txt`` and ``camera.yaml`` (the intrinsics, which
        :class:`~osslam.datasets.tum.TumSequence` reads with ``camera.model: auto``).
        """
        out = Path(out_dir)
        (out / "rgb").mkdir(parents=True, exist_ok=True)
        (out / "depth").mkdir(exist_ok=True)
        rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps", "# timestamp filename"]
        for frame in self:
            stamp = f"{frame.timestamp:.6f}"
            depth_png = np.round(frame.depth * TUM_DEPTH_SCALE).astype(np.uint16)
            for name, image in ((f"rgb/{stamp}.png", cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR)),
                                (f"depth/{stamp}.png", depth_png)):
                if not cv2.imwrite(str(out / name), image):
                    raise InputError(out / name, "cannot write image")
            rgb_lines.append(f"{stamp} rgb/{stamp}.png")
            depth_lines.append(f"{stamp} depth/{stamp}.png")
        (out / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
        (out / "depth.txt").write_text("\n".join(depth_lines) + "\n")
        write_tum(out / "groundtruth.txt", self.groundtruth.timestamps, self.groundtruth.poses)
        write_camera_file(out, self.intrinsics)
        log.info("wrote %d synthetic frames to %s", len(self), out)
        return out
