"""Memory of recent motion: cells that moved stay dynamic for a few frames after they stop.

A mover at the turning point of its path, or one that pauses, has no flow of its own
between two frames, yet it is the same object that moved a moment ago. The memory keeps
each grid cell's frames since it last moved, carried into each new frame by the flow.
"""

from __future__ import annotations

import cv2
import numpy as np

from osslam.imaging import depth_grid, on_grid
from osslam.types import kinect_depth_sigma

from .flow.base import flow_targets

NEVER = np.iinfo(np.int32).max // 2
DEPTH_TOLERANCE = 0.05  # metres, on top of three sigma of the depth noise
PHOTOMETRIC_TOLERANCE = 12.0  # mean absolute grey-level difference over a cell
BLUR_RADIUS = 2  # pixels: the Gaussian blur before that difference is 5 x 5


class MotionMemory:
    """Frames since each cell of the motion grid last moved, and its depth, warped into each new frame.

    A cell is remembered for ``frames`` frames, or with ``per_move`` for that many frames
    per frame it was seen moving (at most ``frames``): a flicker of flow is soon forgotten,
    a mover that moved for a while is kept through its pause.
    """

    def __init__(self, frames: int, stride: int, per_move: int = 0):
        self.frames = frames
        self.stride = max(1, stride)
        self.per_move = per_move
        self._age: np.ndarray | None = None
        self._moves: np.ndarray | None = None
        self._depth: np.ndarray | None = None

    def recall(self, flow: np.ndarray, valid: np.ndarray, depth: np.ndarray, gray: np.ndarray,
               previous: np.ndarray) -> np.ndarray | None:
        """Cells of the current frame that moved within the last ``frames`` frames.

        ``flow`` goes from the current frame (``gray``, ``depth``) to the previous one
        (``previous``). A cell inherits the past only where its flow is ``valid``, its depth
        matches the depth of the cell it came from and so does its appearance: background
        uncovered by a mover, or seen where the mover was, is farther away or looks different
        and starts afresh.
        """
        if self._age is None or self.frames <= 0:
            return None
        s = self.stride
        gh, gw = self._age.shape
        targets = flow_targets(on_grid(flow, s)[:gh, :gw] / s)
        age = cv2.remap(self._age.astype(np.float32), targets, None, cv2.INTER_NEAREST,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=float(NEVER))
        before = cv2.remap(self._depth, targets, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=0.0)
        now = depth_grid(depth, s)
        same = (now > 0) & (before > 0) & (np.abs(now - before) < DEPTH_TOLERANCE + 3 * kinect_depth_sigma(now))
        aged = age.astype(np.int32) + 1
        # a cell older than ``frames`` is never recalled again unless it moves anew, so it is forgotten
        # (NEVER) at once, and only the others need the photometric check
        inherit = (aged <= self.frames) & on_grid(valid, s)[:gh, :gw] & same
        inherit &= self._looks_same(flow, gray, previous, inherit)
        self._age = np.where(inherit, aged, NEVER)
        if self.per_move <= 0:
            return self._age <= self.frames
        moves = cv2.remap(self._moves.astype(np.float32), targets, None, cv2.INTER_NEAREST,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0.0).astype(np.int32)
        remembered = self._age <= np.minimum(self.frames, self.per_move * moves)
        self._moves = np.where(remembered, moves, 0)
        return remembered

    def store(self, moving: np.ndarray, depth: np.ndarray) -> None:
        """Record the cells that moved in the current frame, and the frame's depth."""
        if self._age is None or self._age.shape != moving.shape:
            self._age = np.full(moving.shape, NEVER, np.int32)
            self._moves = np.zeros(moving.shape, np.int32)
        self._age[moving] = 0
        self._moves[moving] += 1
        self._depth = depth_grid(depth, self.stride)

    def _looks_same(self, flow: np.ndarray, gray: np.ndarray, previous: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """Cells whose pixels match, on average, the previous image at the end of their flow (both smoothed).

        Only the box around the marked ``cells`` is looked at; cells outside it come back False.
        """
        out = np.zeros(cells.shape, bool)
        c0, r0, n_cols, n_rows = cv2.boundingRect(np.ascontiguousarray(cells).view(np.uint8))
        if n_cols == 0:
            return out
        r1, c1 = r0 + n_rows, c0 + n_cols
        s, (h, w) = self.stride, gray.shape
        # the box's pixels and the blur's reach around them, so that the blur inside is the whole image's
        x0, y0 = max(0, c0 * s - BLUR_RADIUS), max(0, r0 * s - BLUR_RADIUS)
        x1, y1 = min(w, c1 * s + BLUR_RADIUS), min(h, r1 * s + BLUR_RADIUS)
        warped = cv2.remap(previous, flow_targets(flow, (x0, y0, x1, y1)), None, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        blur = (2 * BLUR_RADIUS + 1, 2 * BLUR_RADIUS + 1)
        error = cv2.absdiff(cv2.GaussianBlur(gray[y0:y1, x0:x1], blur, 0), cv2.GaussianBlur(warped, blur, 0))
        error = error[r0 * s - y0 : r1 * s - y0, c0 * s - x0 : c1 * s - x0].astype(np.float32)
        out[r0:r1, c0:c1] = cv2.resize(error, (c1 - c0, r1 - r0), interpolation=cv2.INTER_AREA) < PHOTOMETRIC_TOLERANCE
        return out
