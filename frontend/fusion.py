"""Joint segmentation fusion (paper Algorithm 1): motion masks refined by detector masks."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from osslam.config import FusionConfig
from osslam.imaging import grow, grow_in_blocks, large_regions, opened

from .motion import MovingObject


MOTION_SUPPORT = 0.05  # fraction of a detection's pixels in the motion masks that shows it moving
NEAR_BLOCK = 4  # pixels: the blocks on which the motion masks grow by ``detection_motion_radius``


@dataclass
class Detection:
    """One detected object as a pixel mask; ``dynamic`` when its class moves by default (a person)."""

    mask: np.ndarray  # (H, W) bool
    label: str
    score: float
    dynamic: bool


@dataclass
class FusedMask:
    """The mask the tracker ignores, and how Algorithm 1 arrived at it."""

    mask: np.ndarray  # (H, W) bool, dilated
    replaced: list[tuple[int, int]] = field(default_factory=list)  # (moving object, detection) pairs
    inclusion_rates: dict[tuple[int, int], float] = field(default_factory=dict)


def nearest_marked(mask: np.ndarray, start: tuple[float, float], reach: float | None = None) -> tuple[int, int] | None:
    """The marked pixel a breadth-first search from ``start`` reaches first, as (x, y); None if none.

    BFS over the 4-connected pixel grid visits pixels in order of L1 distance from the
    start, so its first marked pixel is the marked pixel nearest in L1 distance (ties go
    to the smaller row, then column); that is computed directly instead of queueing pixels.
    With ``reach``, a search that stops there: None when no marked pixel lies within that
    L1 distance of the start rounded to a pixel, and only the pixels within it are looked at.
    """
    if reach is None:
        return _nearest(*np.nonzero(mask), start)
    cx, cy, r = round(start[0]), round(start[1]), int(np.floor(reach))
    x0, y0 = max(0, cx - r), max(0, cy - r)
    # the square around the reach: its pixels in row-major order, as over the whole image
    ys, xs = np.nonzero(mask[y0:max(0, cy + r + 1), x0:max(0, cx + r + 1)])
    hit = _nearest(ys + y0, xs + x0, start)
    return hit if hit is not None and abs(hit[0] - cx) + abs(hit[1] - cy) <= r else None


def _nearest(ys: np.ndarray, xs: np.ndarray, start: tuple[float, float]) -> tuple[int, int] | None:
    """:func:`nearest_marked` over the marked pixels' rows and columns, in row-major order."""
    if len(xs) == 0:
        return None
    d = np.abs(xs - round(start[0])) + np.abs(ys - round(start[1]))
    k = int(np.argmin(d))  # row-major order, so argmin breaks ties by row, then column
    return int(xs[k]), int(ys[k])


def _box_distance(box: tuple[int, int, int, int], point: tuple[float, float]) -> float:
    """L1 distance from ``point`` (x, y) to the nearest pixel of ``box`` (x, y, w, h); inf for an empty box."""
    x, y, w, h = box
    if w == 0:
        return np.inf
    return max(x - point[0], 0.0, point[0] - (x + w - 1)) + max(y - point[1], 0.0, point[1] - (y + h - 1))


def fuse(objects: list[MovingObject], detections: list[Detection], cfg: FusionConfig,
         shape: tuple[int, int]) -> FusedMask:
    """Algorithm 1 and the union that follows.

    For each moving object, search from its predicted centre to the nearest marked pixel of
    each detector mask; when that pixel is within ``cfg.max_centre_distance`` and the
    inclusion rate R = |M_R ∩ M_Y| / |M_Y| exceeds ``cfg.inclusion_rate``, the detector mask
    replaces the motion mask. What the detection leaves of the motion mask beyond
    ``cfg.remainder_margin`` pixels stays when it is a region of at least
    ``cfg.remainder_area`` pixels: a box moving beside the person joins its motion mask,
    and the detection does not explain it. Motion masks without such a detection stay
    (moving chairs, boxes); detector masks of dynamic classes stay, those overlapping the
    motion masks only within about ``cfg.detection_motion_radius`` of them (give or take
    ``NEAR_BLOCK`` pixels; see :func:`_seen_moving`). The motion masks are dilated by
    ``cfg.dilation``, the detector masks, drawn per pixel, by ``cfg.detection_dilation``.
    """
    moving = np.zeros(shape, bool)
    detected = np.zeros(shape, bool)
    result = FusedMask(moving)
    boxes = [cv2.boundingRect(np.ascontiguousarray(det.mask).view(np.uint8)) for det in detections] if objects else []
    areas: dict[int, int] = {}
    for j, obj in enumerate(objects):
        chosen = None
        for k, box in enumerate(boxes):
            if _box_distance(box, obj.centre) > cfg.max_centre_distance:
                continue  # no marked pixel of the detection can be near enough
            # the rounded centre is within 1 px (L1) of the centre, so no farther pixel can be near enough
            hit = nearest_marked(detections[k].mask, obj.centre, cfg.max_centre_distance + 1)
            if hit is None or abs(hit[0] - obj.centre[0]) + abs(hit[1] - obj.centre[1]) > cfg.max_centre_distance:
                continue
            x, y, w, h = box
            inside = detections[k].mask[y:y + h, x:x + w]
            if k not in areas:
                areas[k] = np.count_nonzero(inside)
            rate = np.count_nonzero(obj.mask[y:y + h, x:x + w] & inside) / areas[k]
            result.inclusion_rates[(j, k)] = rate
            if rate > cfg.inclusion_rate and chosen is None:
                chosen = k
        if chosen is None:
            moving |= obj.mask
        else:
            detected |= detections[chosen].mask
            moving |= _unexplained(obj.mask, detections[chosen].mask, cfg)
            result.replaced.append((j, chosen))
    dynamic = [det.mask for det in detections if det.dynamic]
    trim = bool(dynamic and objects and cfg.detection_motion_radius)
    motion = np.logical_or.reduce([obj.mask for obj in objects]) if trim else None
    near_motion = None
    for mask in dynamic:
        if motion is not None and _seen_moving(mask, motion):
            if near_motion is None:
                near_motion = grow_in_blocks(motion, cfg.detection_motion_radius, NEAR_BLOCK)
            mask = mask & near_motion
        detected |= mask
    result.mask = grow(moving, cfg.dilation) | grow(detected, cfg.detection_dilation)
    return result


def _seen_moving(detection: np.ndarray, motion: np.ndarray) -> bool:
    """Whether more than ``MOTION_SUPPORT`` of a detector mask lies in the motion masks.

    A detection seen moving keeps only its pixels near the motion: the rest is its
    segmentation spilling onto the static scene or onto a still person beside it. One not
    seen moving (a person standing still) is dynamic by its class and stays whole.
    """
    return np.count_nonzero(detection & motion) > MOTION_SUPPORT * np.count_nonzero(detection)


def _unexplained(motion: np.ndarray, detection: np.ndarray, cfg: FusionConfig) -> np.ndarray:
    """The regions of a motion mask that lie beyond ``cfg.remainder_margin`` of the detection replacing it.

    Strips narrower than twice the margin (flow leaking past the silhouette) are opened
    away; regions smaller than ``cfg.remainder_area`` pixels are dropped.
    """
    return large_regions(opened(motion & ~grow(detection, cfg.remainder_margin), cfg.remainder_margin),
                         cfg.remainder_area)
