"""Synthetic movers composited into a real RGB-D sequence, with ground-truth masks.

Textured boxes (and optionally a person cut out of a photo) are placed in world
coordinates in front of the first camera, move along smooth paths, and are ray-cast into
every frame with the sequence's ground-truth camera pose and a z-test against the real
depth (where the sensor measured none, against the nearest pixel where it did: a mover
behind the monitor must not show through its screen's missing depth). The static scene,
its sensor noise and its poses stay real; only the movers are rendered, into colour, depth
and a mask of the pixels they cover.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from osslam.errors import InputError
from osslam.folders import folder_aside
from osslam.progress import Progress
from osslam.types import CameraIntrinsics

from .intrinsics import write_camera_file
from .synthetic_scene import face_texture
from .tum import MASKS_LIST, TumSequence

log = logging.getLogger(__name__)

MASKS_DIR = "masks"
INFO_FILE = "synth.yaml"  # what a composite was made from and of; marks a folder as one
DEPTH_SCALE = 5000.0


@dataclass
class CompositeConfig:
    """How many movers, how big, how far and how fast; everything follows from ``seed``."""

    seed: int = 0
    n_boxes: int = 2
    box_size: tuple[float, float] = (0.08, 0.18)  # half extent range, metres
    distance: tuple[float, float] = (0.8, 1.4)  # boxes' distance from the first camera, metres
    person_distance: tuple[float, float] = (1.1, 1.5)  # in front of the desk, as someone walking past
    amplitude: tuple[float, float] = (0.25, 0.5)  # sideways travel, metres
    period: tuple[float, float] = (3.0, 6.0)  # seconds per back-and-forth
    person_height: float = 1.7
    max_frames: int = 0


@dataclass
class Mover:
    """A textured box or a person billboard moving on a sinusoid in world coordinates."""

    kind: str  # "box" or "person"
    half_extent: np.ndarray  # (3,) box half sizes; for a person (half width, half height, 0)
    centre: np.ndarray  # (3,) world position at the sequence start
    axis: np.ndarray  # (3,) unit direction of travel
    amplitude: float
    period: float
    phase: float
    R: np.ndarray  # (3, 3) world-from-object rotation
    texture: np.ndarray  # (S, S, 3) uint8 RGB
    alpha: np.ndarray | None = None  # (S, S) bool for a person cut-out

    def position(self, t: float) -> np.ndarray:
        """World position of the mover's centre ``t`` seconds after the start."""
        return self.centre + self.axis * self.amplitude * np.sin(2 * np.pi * t / self.period + self.phase)


def person_cutout(image_path: Path, model_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """RGB and mask of the person in a photo, from MediaPipe's selfie segmentation (TFLite)."""
    from osslam.frontend.detection.person_mask import PersonSegmenter

    image = cv2.imread(str(image_path))
    if image is None:
        raise InputError(image_path, "missing or unreadable image")
    rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    mask = PersonSegmenter(model_path).probability(rgb) > 0.5
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8))
    if n < 2:
        raise InputError(image_path, "no person found in the image")
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h = stats[k, :4]
    return rgb[y : y + h, x : x + w].copy(), labels[y : y + h, x : x + w] == k


def make_movers(first_pose: np.ndarray, cfg: CompositeConfig,
                person: tuple[np.ndarray, np.ndarray] | None) -> list[Mover]:
    """Movers placed in front of the first camera, travelling across its view."""
    rng = np.random.default_rng(cfg.seed)
    R0, p0 = first_pose[:3, :3], first_pose[:3, 3]
    movers = []
    kinds = ["box"] * cfg.n_boxes + (["person"] if person is not None else [])
    for kind in kinds:
        distance = cfg.distance if kind == "box" else cfg.person_distance
        local = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.1, 0.2), rng.uniform(*distance)])
        axis = R0 @ np.array([1.0, 0.0, rng.uniform(-0.3, 0.3)])
        yaw = rng.uniform(-0.5, 0.5)
        R_obj = R0 @ np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        common = dict(centre=p0 + R0 @ local, axis=axis / np.linalg.norm(axis), amplitude=rng.uniform(*cfg.amplitude),
                      period=rng.uniform(*cfg.period), phase=rng.uniform(0, 2 * np.pi), R=R_obj)
        if kind == "box":
            half = rng.uniform(*cfg.box_size, 3)
            tex = face_texture(rng, 512)
            tex = np.repeat(tex[:, :, None], 3, axis=2) if tex.ndim == 2 else tex
            tint = rng.uniform(0.6, 1.2, 3)
            movers.append(Mover("box", half, texture=np.clip(tex * tint, 0, 255).astype(np.uint8), **common))
        else:
            rgb, alpha = person
            scale = cfg.person_height / rgb.shape[0]
            half = np.array([rgb.shape[1] * scale / 2, cfg.person_height / 2, 0.0])
            movers.append(Mover("person", half, texture=rgb, alpha=alpha, **common))
    return movers


def _hit(mover: Mover, t: float, T_wc: np.ndarray, rays: np.ndarray):
    """Depth along the optical axis (inf where missed) and texture colour of one mover."""
    R_ow = mover.R.T
    o = R_ow @ (T_wc[:3, 3] - mover.position(t))
    d = R_ow @ (T_wc[:3, :3] @ rays)
    n = rays.shape[1]
    depth = np.full(n, np.inf)
    colour = np.zeros((n, 3), np.uint8)
    with np.errstate(divide="ignore", invalid="ignore"):
        if mover.kind == "box":
            inv = 1.0 / d
            lo = (-mover.half_extent[:, None] - o[:, None]) * inv
            hi = (mover.half_extent[:, None] - o[:, None]) * inv
            near = np.minimum(lo, hi)
            t_near = near.max(axis=0)
            t_far = np.maximum(lo, hi).min(axis=0)
            hit = (t_near < t_far) & (t_near > 0)
            axis = near[:, hit].argmax(axis=0)
            p = o[:, None] + d[:, hit] * t_near[hit]
            uv_axes = np.array([[1, 2], [0, 2], [0, 1]])[axis]
            cols = np.arange(p.shape[1])
            a = p[uv_axes[:, 0], cols] / (2 * mover.half_extent[uv_axes[:, 0]]) + 0.5
            b = p[uv_axes[:, 1], cols] / (2 * mover.half_extent[uv_axes[:, 1]]) + 0.5
            t_hit = t_near[hit]
        else:
            t_plane = -o[2] / d[2]
            p = o[:, None] + d * t_plane
            a = p[0] / (2 * mover.half_extent[0]) + 0.5
            b = p[1] / (2 * mover.half_extent[1]) + 0.5
            hit = (t_plane > 0) & (a >= 0) & (a < 1) & (b >= 0) & (b < 1)
            a, b, t_hit = a[hit], b[hit], t_plane[hit]
    size = mover.texture.shape
    ti = np.clip((b * size[0]).astype(int), 0, size[0] - 1)
    tj = np.clip((a * size[1]).astype(int), 0, size[1] - 1)
    idx = np.flatnonzero(hit)
    if mover.alpha is not None:
        keep = mover.alpha[ti, tj]
        idx, ti, tj, t_hit = idx[keep], ti[keep], tj[keep], t_hit[keep]
    depth[idx] = t_hit  # rays have unit z, so the ray parameter is the depth
    colour[idx] = mover.texture[ti, tj]
    return depth, colour


def filled_depth(depth: np.ndarray) -> np.ndarray:
    """``depth`` with each pixel without a measurement (0) given the depth of the nearest measured pixel.

    Where nothing was measured at all, everything is infinitely far.
    """
    missing = depth <= 0
    if not missing.any():
        return depth
    if missing.all():
        return np.full(depth.shape, np.inf)
    _, nearest = cv2.distanceTransformWithLabels(missing.astype(np.uint8), cv2.DIST_L2, 5,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
    return depth[~missing][nearest - 1]  # labels number the measured pixels in row-major order, from 1


class Compositor:
    """Renders movers into frames of one camera."""

    def __init__(self, intrinsics: CameraIntrinsics, movers: list[Mover]):
        self.movers = movers
        h, w = intrinsics.height, intrinsics.width
        v, u = np.mgrid[0:h, 0:w]
        pix = np.column_stack([u.ravel(), v.ravel()]).astype(np.float64)
        norm = intrinsics.normalized(pix)
        self.rays = np.vstack([norm.T, np.ones(len(norm))])
        self.shape = (h, w)

    def render(self, rgb: np.ndarray, depth: np.ndarray, T_wc: np.ndarray, t: float):
        """Colour, depth (metres) and mask of a frame with the movers drawn in front of the real scene."""
        best = np.full(self.rays.shape[1], np.inf)
        colour = np.zeros((self.rays.shape[1], 3), np.uint8)
        for mover in self.movers:
            d, c = _hit(mover, t, T_wc, self.rays)
            closer = d < best
            best[closer] = d[closer]
            colour[closer] = c[closer]
        real = depth.ravel()
        visible = np.isfinite(best) & (best < filled_depth(depth).ravel())
        out_rgb = rgb.reshape(-1, 3).copy()
        out_depth = real.copy()
        out_rgb[visible] = colour[visible]
        out_depth[visible] = best[visible]
        h, w = self.shape
        return out_rgb.reshape(h, w, 3), out_depth.reshape(h, w), visible.reshape(h, w)


def composite_sequence(source: TumSequence, out_dir: str | Path, cfg: CompositeConfig,
                       person: tuple[np.ndarray, np.ndarray] | None = None, progress: bool | None = False) -> Path:
    """Write a TUM folder: ``source`` with movers composited in, plus ``masks/`` and ``masks.txt``.

    ``out_dir`` must be new or empty, so that no frame of something else stays beside the composite's.
    ``progress`` draws a progress bar (None: on a terminal).
    """
    out = Path(out_dir)
    if _occupied(out):
        raise InputError(out, "exists and is not an empty folder; a composite is written into a new one")
    if source.groundtruth is None:
        raise InputError(source.path, "compositing needs groundtruth.txt (movers are placed with the true poses)")
    poses = [source.groundtruth.pose_at(t) for t in source.timestamps]
    valid = [i for i, p in enumerate(poses) if p is not None]
    if not valid:
        raise InputError(source.path, "no frame has a ground-truth pose")
    n = len(source) if cfg.max_frames <= 0 else min(cfg.max_frames, len(source))
    movers = make_movers(poses[valid[0]], cfg, person)
    comp = Compositor(source.intrinsics, movers)
    for sub in ("rgb", "depth", MASKS_DIR):
        (out / sub).mkdir(parents=True, exist_ok=True)
    t0 = float(source.timestamps[0])
    rgb_lines, depth_lines, mask_lines = ["# color images"], ["# depth maps"], ["# timestamp mask"]
    coverage = []
    bar = Progress(n, label=f"synth {out.name}", enabled=progress)
    for i in range(n):
        frame = source[i]
        pose = poses[i] if poses[i] is not None else poses[min(valid, key=lambda j: abs(j - i))]
        rgb, depth, mask = comp.render(frame.rgb, frame.depth, pose, frame.timestamp - t0)
        stamp = f"{frame.timestamp:.6f}"
        cv2.imwrite(str(out / "rgb" / f"{stamp}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(out / "depth" / f"{stamp}.png"), np.round(depth * DEPTH_SCALE).astype(np.uint16))
        cv2.imwrite(str(out / MASKS_DIR / f"{stamp}.png"), mask.astype(np.uint8) * 255)
        rgb_lines.append(f"{stamp} rgb/{stamp}.png")
        depth_lines.append(f"{stamp} depth/{stamp}.png")
        mask_lines.append(f"{stamp} {MASKS_DIR}/{stamp}.png")
        coverage.append(float(mask.mean()))
        bar.update(i + 1)
    for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines), (MASKS_LIST, mask_lines)):
        (out / name).write_text("\n".join(lines) + "\n")
    shutil.copyfile(source.groundtruth_path, out / "groundtruth.txt")
    write_camera_file(out, source.intrinsics)
    cov = np.array(coverage)
    info = {"source": str(source.path), "frames": n, "movers": [m.kind for m in movers], "config": asdict(cfg),
            "coverage": {"mean": float(cov.mean()), "max": float(cov.max()),
                         "frames_with_movers": int((cov > 0).sum())}}
    (out / INFO_FILE).write_text(yaml.safe_dump(info, sort_keys=False))
    log.info("composite of %d frames written to %s (mean coverage %.1f %%)", n, out, 100 * cov.mean())
    return out


def write_composite(source: TumSequence, out_dir: str | Path, cfg: CompositeConfig,
                    person: tuple[np.ndarray, np.ndarray] | None = None, overwrite: bool = False,
                    progress: bool | None = None) -> Path:
    """:func:`composite_sequence` into ``out_dir`` whole or not at all.

    A folder that is there and not empty is replaced only with ``overwrite`` and only when it
    is an earlier composite (it holds ``synth.yaml``), and only once the new one is complete;
    the source sequence, and a folder holding it, are never written to.
    """
    out = Path(out_dir).resolve()  # its name and parent are real ones even when given as "." or through a link
    src = Path(source.path).resolve()
    if out == src or out in src.parents:
        raise InputError(out, f"is or holds the source sequence {src}; write the composite to another folder")
    replace = _occupied(out)
    if replace and not overwrite:
        raise InputError(out, "exists and is not empty; pass --overwrite (overwrite=True) to replace a composite "
                              "there")
    if replace and not (out / INFO_FILE).is_file():
        raise InputError(out, f"holds no {INFO_FILE}, so it is not a composite written by osslam synth; "
                              "not replacing it")
    with folder_aside(out) as tmp:
        composite_sequence(source, tmp, cfg, person, progress)
        if replace:
            old = tmp.with_suffix(".old")
            out.rename(old)
            tmp.rename(out)
            shutil.rmtree(old)
        else:
            tmp.rename(out)  # over an empty folder, or where there was none
    return out


def _occupied(path: Path) -> bool:
    """Whether ``path`` is taken: a file, or a folder with something in it."""
    return path.exists() and (not path.is_dir() or any(path.iterdir()))
