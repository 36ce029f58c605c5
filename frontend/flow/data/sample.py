"""One image pair with its ground-truth flow."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FlowSample:
    """Two uint8 RGB images (H, W, 3), the flow from the first to the second (H, W, 2) and its validity (H, W).

    ``movers`` marks the first image's pixels on independently moving objects, where known.
    """

    image1: np.ndarray
    image2: np.ndarray
    flow: np.ndarray
    valid: np.ndarray
    movers: np.ndarray | None = None
