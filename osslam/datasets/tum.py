"""A TUM RGB-D sequence folder read lazily as :class:`osslam.types.Frame` objects."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from osslam.config import CameraConfig, ConfigError, DatasetConfig
from osslam.errors import InputError
from osslam.types import CameraIntrinsics, Frame

from .association import associate, read_file_list
from .groundtruth import GroundTruth
from .intrinsics import select_intrinsics
from .sequence import FrameSequence

log = logging.getLogger(__name__)

#: Optional list of ground-truth masks of moving objects (``timestamp masks/NAME.png``), as ``osslam synth`` writes.
MASKS_LIST = "masks.txt"
#: A depth image whose median valid depth (metres) lies outside this range has a wrong depth scale.
PLAUSIBLE_DEPTH = (0.05, 20.0)


class TumSequence(FrameSequence):
    """Associated colour/depth frames of a TUM sequence folder, images read on access.

    Reads ``rgb.txt``, ``depth.txt`` and, if present, ``groundtruth.txt``; pairs colour
    and depth by nearest timestamp within ``dataset.max_time_diff``; keeps the frames
    that ``dataset.start_frame``, ``stride`` and ``max_frames`` select. Each frame's
    ``gt_pose`` is the ground truth interpolated at its colour timestamp, or None.
    """

    def __init__(self, path: str | Path, dataset: DatasetConfig, camera: CameraConfig):
        _check_selection(dataset)
        self.path = Path(path)
        if not self.path.is_dir():
            raise InputError(self.path, "sequence folder not found")
        self.name = self.path.resolve().name
        self.depth_scale = dataset.depth_scale
        rgb = read_file_list(self.path / "rgb.txt")
        depth = read_file_list(self.path / "depth.txt")
        pairs = associate(rgb.timestamps, depth.timestamps, dataset.max_time_diff)
        if not pairs:
            raise InputError(self.path, f"no colour frame in rgb.txt has a depth frame in depth.txt within "
                                        f"{dataset.max_time_diff} s (dataset.max_time_diff)")
        n_associated = len(pairs)
        pairs = pairs[dataset.start_frame :: dataset.stride]
        if dataset.max_frames > 0:
            pairs = pairs[: dataset.max_frames]
        if not pairs:
            raise InputError(self.path, f"no frames left: dataset.start_frame={dataset.start_frame} but only "
                                        f"{n_associated} associated frames")
        self.timestamps = np.array([rgb.timestamps[i] for i, _ in pairs])
        self._rgb_files = [self.path / rgb.files[i] for i, _ in pairs]
        self._depth_files = [self.path / depth.files[j] for _, j in pairs]
        gt_file = self.path / "groundtruth.txt"
        self.groundtruth_path: Path | None = gt_file if gt_file.is_file() else None
        self.groundtruth: GroundTruth | None = GroundTruth.from_file(gt_file) if self.groundtruth_path else None
        self.intrinsics: CameraIntrinsics = select_intrinsics(self.path, camera)
        self._mask_files = self._masks(dataset.max_time_diff)
        log.info("%s: %d of %d colour frames associated, %d selected", self.name, n_associated,
                 len(rgb.timestamps), len(pairs))

    def _masks(self, max_time_diff: float) -> list[Path | None] | None:
        """Ground-truth masks of moving objects from ``masks.txt`` (written by ``osslam synth``), per frame."""
        listing = self.path / MASKS_LIST
        if not listing.is_file():
            return None
        masks = read_file_list(listing)
        by_frame: list[Path | None] = [None] * len(self.timestamps)
        for i, j in associate(self.timestamps, masks.timestamps, max_time_diff):
            by_frame[i] = self.path / masks.files[j]
        return by_frame

    def _load(self, i: int) -> Frame:
        """Read, convert and check frame ``i``'s images; attach its interpolated ground truth."""
        t = float(self.timestamps[i])
        rgb_file, depth_file = self._rgb_files[i], self._depth_files[i]
        rgb = _read_rgb(rgb_file)
        size = (self.intrinsics.height, self.intrinsics.width)
        if rgb.shape[:2] != size:
            raise InputError(rgb_file, f"image is {rgb.shape[1]}x{rgb.shape[0]} but the camera is {size[1]}x{size[0]}; "
                                       f"set camera.model (custom, with camera.width/height) to match")
        depth = _read_depth(depth_file, self.depth_scale)
        if depth.shape != size:
            raise InputError(depth_file, f"depth image is {depth.shape[1]}x{depth.shape[0]}, "
                                         f"colour image is {size[1]}x{size[0]}")
        gt = self.groundtruth.pose_at(t) if self.groundtruth is not None else None
        mask = None
        if self._mask_files is not None and self._mask_files[i] is not None:
            raw = cv2.imread(str(self._mask_files[i]), cv2.IMREAD_GRAYSCALE)
            if raw is None or raw.shape != size:
                raise InputError(self._mask_files[i], "missing, unreadable or wrongly sized mask image")
            mask = raw > 0
        return Frame(i, t, rgb, depth, self.intrinsics, gt, source=str(rgb_file), gt_mask=mask)


def _check_selection(dataset: DatasetConfig) -> None:
    """ConfigError for a frame selection or depth scale that cannot be used."""
    if dataset.start_frame < 0 or dataset.stride < 1 or dataset.max_frames < 0:
        raise ConfigError(f"dataset.start_frame ({dataset.start_frame}) and dataset.max_frames "
                          f"({dataset.max_frames}) must be >= 0 and dataset.stride ({dataset.stride}) >= 1")
    if not dataset.depth_scale > 0:
        raise ConfigError(f"dataset.depth_scale must be positive, got {dataset.depth_scale}")


def _read_rgb(path: Path) -> np.ndarray:
    """A colour image as (H, W, 3) uint8 RGB; InputError naming the file if it cannot be read."""
    if not path.is_file():
        raise InputError(path, "colour image listed in rgb.txt not found")
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(path, "cannot decode colour image (corrupt or not an image)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _read_depth(path: Path, depth_scale: float) -> np.ndarray:
    """A 16-bit depth PNG as float32 metres; InputError if unreadable, not uint16, or implausibly scaled."""
    if not path.is_file():
        raise InputError(path, "depth image listed in depth.txt not found")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise InputError(path, "cannot decode depth image (corrupt or not an image)")
    if raw.dtype != np.uint16 or raw.ndim != 2:
        channels = 1 if raw.ndim == 2 else raw.shape[2]
        raise InputError(path, f"depth must be a single-channel 16-bit image, got {channels} channel(s) of {raw.dtype}")
    sample = raw[::4, ::4]
    valid = sample[sample > 0]
    if valid.size:
        median = float(np.median(valid)) / depth_scale
        if not PLAUSIBLE_DEPTH[0] <= median <= PLAUSIBLE_DEPTH[1]:
            raise InputError(path, f"median depth {median:.3g} m is implausible; check dataset.depth_scale "
                                   f"(now {depth_scale:g}; TUM uses 5000, millimetre PNGs 1000)")
    return raw.astype(np.float32) / np.float32(depth_scale)
