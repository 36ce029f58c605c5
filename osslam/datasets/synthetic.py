"""A synthetic RGB-D sequence: a textured room with boxes, ray-cast in numpy, exact ground truth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from osslam.trajectory_io import write_tum
from osslam.types import CameraIntrinsics, Frame

from .intrinsics import CAMERA_FILE

_TILE = 1024  # texels per face texture
_ATLAS_TILES = 4  # the atlas is a 4x4 grid of face textures
_TEXEL = 0.006  # metres per texel


@dataclass
class SyntheticConfig:
    """Size, motion, noise and seed of a synthetic sequence."""

    n_frames: int = 150
    fps: float = 30.0
    seed: int = 0
    width: int = 640
    height: int = 480
    fx: float = 525.0
    fy: float = 525.0
    cx: float = 319.5
    cy: float = 239.5
    depth_noise: bool = True
    dropout: float = 0.02
    image_noise: float = 2.0
    max_depth: float = 8.0
    start_time: float = 1000.0


@dataclass(frozen=True)
class _Box:
    lo: np.ndarray
    hi: np.ndarray


# The room (the camera is inside it, looking at +z) and three boxes standing in front of it; y down.
_ROOM = _Box(np.array([-3.0, -1.5, -2.5]), np.array([3.0, 1.5, 2.5]))
_BOXES = (
    _Box(np.array([-1.3, 0.3, 1.5]), np.array([-0.6, 1.5, 2.0])),
    _Box(np.array([0.6, -0.4, 1.7]), np.array([1.2, 1.5, 2.2])),
    _Box(np.array([-0.2, 0.7, 1.2]), np.array([0.5, 1.5, 1.6])),
)


def _rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    Rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def _texture(rng: np.random.Generator) -> np.ndarray:
    """A face texture rich in corners: smooth shading under random rectangles and discs."""
    base = cv2.resize(rng.uniform(60, 190, (8, 8)).astype(np.float32), (_TILE, _TILE), interpolation=cv2.INTER_CUBIC)
    tex = np.clip(base, 0, 255).astype(np.uint8)
    for _ in range(900):
        x, y = (int(v) for v in rng.integers(0, _TILE, 2))
        s = int(rng.integers(6, 40))
        colour = int(rng.integers(0, 256))
        if rng.random() < 0.7:
            cv2.rectangle(tex, (x, y), (x + s, y + int(rng.integers(6, 40))), colour, -1)
        else:
            cv2.circle(tex, (x, y), s // 2, colour, -1)
    return cv2.GaussianBlur(tex, (3, 3), 0.8)


class SyntheticSequence:
    """Frames rendered on access from a seeded scene and camera path, with exact poses."""

    def __init__(self, cfg: SyntheticConfig | None = None):
        self.cfg = cfg = cfg or SyntheticConfig()
        self.name = f"synthetic_room_seed{cfg.seed}"
        self.intrinsics = CameraIntrinsics(cfg.fx, cfg.fy, cfg.cx, cfg.cy, cfg.width, cfg.height)
        self.groundtruth_path: Path | None = None
        rng = np.random.default_rng(cfg.seed)
        n_faces = 6 + 6 * len(_BOXES)
        tiles = [_texture(rng) for _ in range(n_faces)]
        atlas = np.zeros((_TILE * _ATLAS_TILES, _TILE * _ATLAS_TILES * 2), np.uint8)
        for k, tile in enumerate(tiles):
            r, c = divmod(k, _ATLAS_TILES * 2)
            atlas[r * _TILE : (r + 1) * _TILE, c * _TILE : (c + 1) * _TILE] = tile
        self._atlas = atlas
        self._shade = rng.uniform(0.75, 1.1, n_faces).astype(np.float32)
        self._motion = rng.uniform(0, 2 * np.pi, 6), rng.uniform(0.8, 1.2, 6)
        self.timestamps = cfg.start_time + np.arange(cfg.n_frames) / cfg.fps
        u, v = np.meshgrid(np.arange(cfg.width), np.arange(cfg.height))
        self._rays = np.stack([(u - cfg.cx) / cfg.fx, (v - cfg.cy) / cfg.fy, np.ones_like(u, float)]).reshape(3, -1)

    def __len__(self) -> int:
        return self.cfg.n_frames

    def pose(self, t: float) -> np.ndarray:
        """Camera-to-world pose at time ``t`` seconds from the start: smooth sinusoids."""
        phase, speed = self._motion
        w = 2 * np.pi / 6.0 * speed
        T = np.eye(4)
        T[:3, 3] = [0.35 * np.sin(w[0] * t + phase[0]), 0.15 * np.sin(w[1] * t + phase[1]),
                    0.4 + 0.3 * np.sin(w[2] * t + phase[2])]
        T[:3, :3] = _rotation(0.25 * np.sin(w[3] * t + phase[3]), 0.12 * np.sin(w[4] * t + phase[4]),
                              0.05 * np.sin(w[5] * t + phase[5]))
        return T

    def __getitem__(self, i: int) -> Frame:
        if not -len(self) <= i < len(self):
            raise IndexError(i)
        i %= len(self)
        t = float(self.timestamps[i])
        T = self.pose(t - self.cfg.start_time)
        rgb, depth = self._render(T, np.random.default_rng([self.cfg.seed, i]))
        return Frame(i, t, rgb, depth, self.intrinsics, T, source=f"{self.name}[{i}]")

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def _render(self, T: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.cfg
        o = T[:3, 3]
        d = T[:3, :3] @ self._rays  # (3, N) world ray directions, unit depth along the optical axis
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            # leaving the room: the nearest exit plane over the three axes
            exits = [np.maximum((_ROOM.lo[k] - o[k]) * inv[k], (_ROOM.hi[k] - o[k]) * inv[k]) for k in range(3)]
            t_hit = np.minimum(np.minimum(exits[0], exits[1]), exits[2])
            axis = np.where(exits[0] == t_hit, 0, np.where(exits[1] == t_hit, 1, 2))
            face = axis * 2 + (np.take_along_axis(d, axis[None], 0)[0] > 0)
            for b, box in enumerate(_BOXES):
                lo = [(box.lo[k] - o[k]) * inv[k] for k in range(3)]
                hi = [(box.hi[k] - o[k]) * inv[k] for k in range(3)]
                near = [np.minimum(lo[k], hi[k]) for k in range(3)]
                t_near = np.maximum(np.maximum(near[0], near[1]), near[2])
                t_far = np.minimum(np.minimum(np.maximum(lo[0], hi[0]), np.maximum(lo[1], hi[1])),
                                   np.maximum(lo[2], hi[2]))
                hit = (t_near < t_far) & (t_near > 0) & (t_near < t_hit)
                ax = np.where(near[0][hit] == t_near[hit], 0, np.where(near[1][hit] == t_near[hit], 1, 2))
                t_hit[hit] = t_near[hit]
                face[hit] = 6 + 6 * b + ax * 2 + (d[ax, np.flatnonzero(hit)] < 0)
                axis[hit] = ax
        p = o[:, None] + d * t_hit
        # texture coordinates: the two world axes spanning the hit face
        p -= _ROOM.lo[:, None]  # non-negative inside the room, so one face never wraps
        a = np.where(axis == 0, p[2], p[0]) / _TEXEL % _TILE
        b = np.where(axis == 1, p[2], p[1]) / _TEXEL % _TILE
        r, c = np.divmod(face, _ATLAS_TILES * 2)
        map_x = (c * _TILE + a).astype(np.float32).reshape(cfg.height, cfg.width)
        map_y = (r * _TILE + b).astype(np.float32).reshape(cfg.height, cfg.width)
        gray = cv2.remap(self._atlas, map_x, map_y, cv2.INTER_LINEAR).astype(np.float32)
        gray *= self._shade[face].reshape(cfg.height, cfg.width)
        if cfg.image_noise > 0:
            gray += rng.standard_normal(gray.shape, dtype=np.float32) * cfg.image_noise
        gray = np.clip(gray, 0, 255).astype(np.uint8)
        rgb = np.repeat(gray[:, :, None], 3, axis=2)
        depth = t_hit.reshape(cfg.height, cfg.width).astype(np.float32)
        if cfg.depth_noise:
            sigma = 0.0012 + 0.0019 * (depth - 0.4) ** 2
            depth += rng.standard_normal(depth.shape, dtype=np.float32) * sigma
        if cfg.dropout > 0:
            depth[rng.random(depth.shape, dtype=np.float32) < cfg.dropout] = 0.0
        depth[(depth > cfg.max_depth) | ~np.isfinite(depth)] = 0.0
        return rgb, depth

    def write_tum(self, out_dir: str | Path) -> Path:
        """Write the sequence as a TUM folder (PNG images, lists, groundtruth.txt, camera.yaml)."""
        out = Path(out_dir)
        (out / "rgb").mkdir(parents=True, exist_ok=True)
        (out / "depth").mkdir(exist_ok=True)
        rgb_lines, depth_lines = ["# color images"], ["# depth maps"]
        for frame in self:
            stamp = f"{frame.timestamp:.6f}"
            cv2.imwrite(str(out / "rgb" / f"{stamp}.png"), cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR))
            cv2.imwrite(str(out / "depth" / f"{stamp}.png"), np.round(frame.depth * 5000).astype(np.uint16))
            rgb_lines.append(f"{stamp} rgb/{stamp}.png")
            depth_lines.append(f"{stamp} depth/{stamp}.png")
        write_tum(out / "groundtruth.txt", self.timestamps, [self.pose(t - self.cfg.start_time) for t in self.timestamps])
        for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines)):
            (out / name).write_text("\n".join(lines) + "\n")
        intr = self.intrinsics
        camera = {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy, "width": intr.width,
                  "height": intr.height, "dist": list(intr.dist)}
        (out / CAMERA_FILE).write_text(yaml.safe_dump(camera, sort_keys=False))
        return out
