"""Small image operations the stages share: reading an image at keypoints, growing a mask, image grids,
depth edges."""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np


def pixel_indices(pixels: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Column and row of the pixel nearest each (x, y) in ``pixels`` (N, 2), clipped into an image of ``shape``."""
    u = np.clip(np.rint(pixels[:, 0]).astype(int), 0, shape[1] - 1)
    v = np.clip(np.rint(pixels[:, 1]).astype(int), 0, shape[0] - 1)
    return u, v


def values_at(image: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """The image's values at the pixels nearest each (x, y) in ``pixels`` (N, 2), clipped into the image."""
    u, v = pixel_indices(pixels, image.shape)
    return image[v, u]


@lru_cache(maxsize=8)
def _disc(radius: int) -> np.ndarray:
    size = 2 * radius + 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def grow(mask: np.ndarray, radius: int) -> np.ndarray:
    """A boolean mask grown by a disc of ``radius`` pixels (unchanged for radius 0)."""
    if radius <= 0:
        return mask.astype(bool)
    marked = mask.astype(np.uint8)
    x, y, w, h = cv2.boundingRect(marked)  # only the marked pixels' box, widened by the radius, can change
    out = np.zeros(mask.shape, bool)
    if w == 0:
        return out
    rows = slice(max(0, y - radius), min(mask.shape[0], y + h + radius))
    cols = slice(max(0, x - radius), min(mask.shape[1], x + w + radius))
    out[rows, cols] = cv2.dilate(marked[rows, cols], _disc(radius)).astype(bool)
    return out


def grow_square(mask: np.ndarray, radius: int) -> np.ndarray:
    """A boolean mask grown by a square of ``2 * radius + 1`` pixels a side (unchanged for radius 0).

    Every pixel within ``radius`` of the mask in both x and y; for a large radius a tenth of
    :func:`grow`'s cost (the square's dilation is separable).
    """
    if radius <= 0:
        return mask.astype(bool)
    return cv2.dilate(mask.astype(np.uint8), np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)).astype(bool)


def grow_in_blocks(mask: np.ndarray, radius: int, block: int) -> np.ndarray:
    """``mask`` grown by ``radius`` pixels give or take a block, on blocks of ``block`` x ``block`` pixels.

    For large radii, at a fraction of :func:`grow`'s cost: every block holding a marked pixel
    is marked and the blocks grow by ``radius`` / ``block``. The result holds every pixel
    within ``radius - block`` of the mask and none beyond ``radius + 2 * block``.
    """
    h, w = mask.shape
    blocks = cv2.resize(mask.astype(np.uint8) * 255, (-(-w // block), -(-h // block)), interpolation=cv2.INTER_AREA)
    grown = grow(blocks > 0, round(radius / block))
    return cv2.resize(grown.view(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).view(bool)


def large_regions(mask: np.ndarray, min_area: int) -> np.ndarray:
    """The pixels of a mask's 8-connected regions of at least ``min_area`` pixels."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
    return keep[labels]


def opened(mask: np.ndarray, radius: int) -> np.ndarray:
    """A boolean mask without its parts that a disc of ``radius`` pixels does not fit in (unchanged for radius 0)."""
    if radius <= 0:
        return mask.astype(bool)
    return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, _disc(radius)).astype(bool)


def grid_cells(pixels: np.ndarray, size: tuple[int, int], grid: tuple[int, int]) -> np.ndarray:
    """Index of the cell of a ``grid`` (columns, rows) over an image of ``size`` (width, height) holding each pixel."""
    (w, h), (cols, rows) = size, grid
    return (np.minimum(pixels[:, 1] * rows // h, rows - 1) * cols
            + np.minimum(pixels[:, 0] * cols // w, cols - 1)).astype(int)


def rank_in_cells(cell: np.ndarray) -> np.ndarray:
    """Each point's place among the points of its cell, in the given order (0 for the first)."""
    order = np.argsort(cell, kind="stable")
    sorted_cells = cell[order]
    rank = np.empty(len(cell), int)
    rank[order] = np.arange(len(order)) - np.searchsorted(sorted_cells, sorted_cells)
    return rank


def on_grid(image: np.ndarray, stride: int) -> np.ndarray:
    """Every ``stride``-th pixel of ``image`` from ``stride // 2``, in rows and columns (a view)."""
    return image[stride // 2 :: stride, stride // 2 :: stride]


def depth_grid(depth: np.ndarray, stride: int) -> np.ndarray:
    """Every ``stride``-th depth (metres, float32) from ``stride // 2``, 0 where not finite."""
    grid = on_grid(depth, stride).astype(np.float32)
    return np.where(np.isfinite(grid), grid, 0.0).astype(np.float32)


def grid_index(pixels: np.ndarray, stride: int, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row and column of the point of a :func:`depth_grid` of ``shape`` nearest each (x, y), and whether inside."""
    col = np.rint((pixels[:, 0] - stride // 2) / stride).astype(int)
    row = np.rint((pixels[:, 1] - stride // 2) / stride).astype(int)
    inside = (col >= 0) & (col < shape[1]) & (row >= 0) & (row < shape[0])
    return row, col, inside


def nearest_depth(grid: np.ndarray, radius: int = 1) -> np.ndarray:
    """The nearest depth within ``radius`` cells of each point of a depth grid (0 = missing), inf where none is known."""
    known = np.where(grid > 0, grid, np.inf).astype(np.float32)
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    # replicated, not constant, border: OpenCV's default border for erode is FLT_MAX, a finite "depth"
    return cv2.erode(known, kernel, borderType=cv2.BORDER_REPLICATE)


def depth_edges(depth: np.ndarray, step: float, radius: int) -> np.ndarray:
    """Pixels whose depth differs by more than ``step`` times their own from a depth within ``radius`` pixels.

    At a silhouette the sensor mixes foreground and background into depths that lie on
    neither; missing depth (0 or NaN) is no neighbour and is never an edge.
    """
    z = np.nan_to_num(depth.astype(np.float32), nan=0.0, posinf=0.0)
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    farthest = cv2.dilate(z, kernel, borderType=cv2.BORDER_REPLICATE)
    return (z > 0) & ((farthest - z > step * z) | (z - nearest_depth(z, radius) > step * z))
