"""Dynamic-mask quality against ground-truth masks: pixels and ORB keypoints (core, no I/O)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from osslam.imaging import pixel_indices

ORB_PATCH_RADIUS = 15  # pixels: half of ORB's 31-pixel patch at the finest level
FAST_RADIUS = 3.0  # pixels: the circle FAST compares a corner candidate with, at the finest level


@dataclass
class MaskCounts:
    """Confusion counts of a predicted dynamic mask, over pixels and over keypoints."""

    pixels_tp: int = 0
    pixels_fp: int = 0
    pixels_fn: int = 0
    keypoints_moving: int = 0  # keypoints on ground-truth movers
    keypoints_moving_removed: int = 0
    keypoints_static: int = 0
    keypoints_static_removed: int = 0
    keypoints_off_outline: int = 0  # static keypoints whose FAST circle does not reach a mover
    keypoints_off_outline_removed: int = 0
    keypoints_clear: int = 0  # static keypoints whose ORB patch does not reach a mover
    keypoints_clear_removed: int = 0

    def __iadd__(self, other: "MaskCounts") -> "MaskCounts":
        for name in self.__dataclass_fields__:
            setattr(self, name, getattr(self, name) + getattr(other, name))
        return self

    def scores(self) -> dict[str, float | None]:
        """Pixel precision and recall, keypoint recall on movers, fraction of static keypoints removed.

        ``static_keypoints_removed`` counts every keypoint off the movers;
        ``off_outline_keypoints_removed`` only those whose FAST circle reaches no mover pixel
        (a corner within it may be made by the mover's outline, which moves with the mover);
        ``clear_keypoints_removed`` only those farther than an ORB patch radius from any
        mover, whose descriptors see nothing of it.
        """
        def ratio(a: int, b: int) -> float | None:
            return a / b if b else None

        return {
            "pixel_precision": ratio(self.pixels_tp, self.pixels_tp + self.pixels_fp),
            "pixel_recall": ratio(self.pixels_tp, self.pixels_tp + self.pixels_fn),
            "keypoint_recall": ratio(self.keypoints_moving_removed, self.keypoints_moving),
            "static_keypoints_removed": ratio(self.keypoints_static_removed, self.keypoints_static),
            "off_outline_keypoints_removed": ratio(self.keypoints_off_outline_removed, self.keypoints_off_outline),
            "clear_keypoints_removed": ratio(self.keypoints_clear_removed, self.keypoints_clear),
        }


def mask_counts(predicted: np.ndarray | None, truth: np.ndarray, keypoints: np.ndarray,
                fast_radius: np.ndarray | float = FAST_RADIUS) -> MaskCounts:
    """Counts of one frame; ``keypoints`` are (N, 2) pixel positions, ``predicted`` None means nothing masked.

    ``fast_radius`` is each keypoint's FAST circle in pixels of the image (larger on coarser
    pyramid levels), or one radius for all.
    """
    pred = np.zeros_like(truth) if predicted is None else predicted
    u, v = pixel_indices(keypoints, truth.shape)
    on_mover, removed = truth[v, u], pred[v, u]
    off_outline, clear = ~on_mover, ~on_mover
    if truth.any():
        distance = cv2.distanceTransform((~truth).astype(np.uint8), cv2.DIST_L2, 5)[v, u]
        off_outline = off_outline & (distance > fast_radius)
        clear = clear & (distance > ORB_PATCH_RADIUS)
    return MaskCounts(
        int((pred & truth).sum()), int((pred & ~truth).sum()), int((~pred & truth).sum()),
        int(on_mover.sum()), int((on_mover & removed).sum()),
        int((~on_mover).sum()), int((~on_mover & removed).sum()),
        int(off_outline.sum()), int((off_outline & removed).sum()),
        int(clear.sum()), int((clear & removed).sum()),
    )
