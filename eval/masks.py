"""Dynamic-mask quality against ground-truth masks: pixels and ORB keypoints (core, no I/O)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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

    def __iadd__(self, other: "MaskCounts") -> "MaskCounts":
        for name in self.__dataclass_fields__:
            setattr(self, name, getattr(self, name) + getattr(other, name))
        return self

    def scores(self) -> dict[str, float | None]:
        """Pixel precision and recall, keypoint recall on movers, fraction of static keypoints removed."""
        def ratio(a: int, b: int) -> float | None:
            return a / b if b else None

        return {
            "pixel_precision": ratio(self.pixels_tp, self.pixels_tp + self.pixels_fp),
            "pixel_recall": ratio(self.pixels_tp, self.pixels_tp + self.pixels_fn),
            "keypoint_recall": ratio(self.keypoints_moving_removed, self.keypoints_moving),
            "static_keypoints_removed": ratio(self.keypoints_static_removed, self.keypoints_static),
        }


def mask_counts(predicted: np.ndarray | None, truth: np.ndarray, keypoints: np.ndarray) -> MaskCounts:
    """Counts of one frame; ``keypoints`` are (N, 2) pixel positions, ``predicted`` None means nothing masked."""
    pred = np.zeros_like(truth) if predicted is None else predicted
    u = np.clip(np.rint(keypoints[:, 0]).astype(int), 0, truth.shape[1] - 1)
    v = np.clip(np.rint(keypoints[:, 1]).astype(int), 0, truth.shape[0] - 1)
    on_mover, removed = truth[v, u], pred[v, u]
    return MaskCounts(
        int((pred & truth).sum()), int((pred & ~truth).sum()), int((~pred & truth).sum()),
        int(on_mover.sum()), int((on_mover & removed).sum()),
        int((~on_mover).sum()), int((~on_mover & removed).sum()),
    )
