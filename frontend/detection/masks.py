"""Detector boxes turned into pixel masks: the dominant depth layer inside each box."""

from __future__ import annotations

import numpy as np

from .yolo import Box


def box_mask(box: Box, depth: np.ndarray, layer: float, bin_width: float = 0.1) -> np.ndarray:
    """Pixels of ``box`` on its dominant depth layer (within ``layer`` metres of the most common depth).

    The object fills most of its box, so the most populated depth bin is the object; pixels
    much nearer or farther are background or occluders. Pixels without depth inside the box
    count as the object (movers' edges often lack depth).
    """
    h, w = depth.shape
    x0, y0 = max(0, int(box.x0)), max(0, int(box.y0))
    x1, y1 = min(w, int(np.ceil(box.x1))), min(h, int(np.ceil(box.y1)))
    mask = np.zeros((h, w), bool)
    if x1 <= x0 or y1 <= y0:
        return mask
    patch = depth[y0:y1, x0:x1]
    valid = patch[(patch > 0) & np.isfinite(patch)]
    if valid.size == 0:
        mask[y0:y1, x0:x1] = True
        return mask
    bins = np.arange(valid.min(), valid.max() + bin_width, bin_width)
    counts, edges = np.histogram(valid, bins=bins if len(bins) > 1 else 1)
    mode = 0.5 * (edges[np.argmax(counts)] + edges[np.argmax(counts) + 1])
    mask[y0:y1, x0:x1] = (patch <= 0) | ~np.isfinite(patch) | (np.abs(patch - mode) <= layer)
    return mask
