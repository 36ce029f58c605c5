"""Flow accuracy as paper §4.2 scores it: EPE, 1/3/5 px accuracy and the KITTI Fl outlier rate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FlowErrors:
    """Sums over valid pixels, so pairs accumulate; :meth:`summary` gives the averages."""

    pixels: int = 0
    epe_sum: float = 0.0
    within1: int = 0
    within3: int = 0
    within5: int = 0
    outliers: int = 0

    def add(self, flow: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> None:
        """Accumulate one pair: predicted and true flow (H, W, 2), valid ground truth (H, W)."""
        err = np.linalg.norm(flow - gt, axis=2)[valid]
        mag = np.linalg.norm(gt, axis=2)[valid]
        self.pixels += int(err.size)
        self.epe_sum += float(err.sum())
        self.within1 += int((err < 1).sum())
        self.within3 += int((err < 3).sum())
        self.within5 += int((err < 5).sum())
        self.outliers += int(((err > 3) & (err > 0.05 * mag)).sum())

    def summary(self) -> dict[str, float]:
        """EPE (px), the fractions of pixels within 1, 3, 5 px and Fl-all (percent)."""
        n = max(self.pixels, 1)
        return {"epe": self.epe_sum / n, "1px": 100 * self.within1 / n, "3px": 100 * self.within3 / n,
                "5px": 100 * self.within5 / n, "fl_all": 100 * self.outliers / n, "pixels": self.pixels}
