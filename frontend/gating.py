"""Dynamic gating: the per-frame mask of moving pixels from flow, motion segmentation and fusion.

A frame's flow, detection, motion segmentation and fusion run on a worker thread while the
tracker estimates the frame's pose (paper Figure 1; the detector runs on every
``detection.interval``-th frame, its masks follow the flow in between, and people are
segmented on every ``detection.person_interval``-th detection, their last masks following the
flow in between). The segmentation there starts from a prediction of the ego-motion
(``motion.predict``; the last frame's anchored tracked one); the tracked pose, when anchored,
then checks it, and where the two disagree, or no anchored pose checks it, the segmentation and
fusion are redone with what tracking gives, before the tracker applies the mask and commits
the frame. What the next frame needs of the finished one (its moving cells, depth and prior) is
kept on the worker after the mask is returned.
"""

from __future__ import annotations

import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from osslam.config import Config
from osslam.geometry import invert
from osslam.imaging import depth_grid, grow, grow_square
from osslam.models import models_dir
from osslam.types import CameraIntrinsics

from .detection.detector import PERSON, make_detector
from .flow import FlowField, make_flow_estimator
from .flow.base import flow_targets
from .fusion import Detection, FusedMask, fuse
from .motion import (DepthReference, MotionGrid, MotionSegmentation, motion_grid, segment_motion, turned_to_the_flow,
                     unexplained_share)
from .motion_memory import MotionMemory

STAGES = ("detection", "flow", "motion", "fusion")  # the timings that add up to the gate's cost, on either thread


def gate_cost(timings_ms: dict[str, float]) -> float:
    """The gate's time for a frame on both threads: its :data:`STAGES` in ``timings_ms`` together."""
    return sum(timings_ms.get(stage, 0.0) for stage in STAGES)


@dataclass
class GateResult:
    """The mask of one frame (True = dynamic, ignored by tracking and mapping) and how it was made."""

    mask: np.ndarray
    segmentation: MotionSegmentation | None
    fused: FusedMask | None
    timings_ms: dict[str, float] = field(default_factory=dict)
    dilation: int = 0  # pixels the fusion grew the mask by
    predicted: bool = False  # segmented beside tracking with the predicted ego-motion, which tracking confirmed

    @property
    def map_mask(self) -> np.ndarray:
        """The mask the dense map leaves out: :attr:`mask` and the partly moving surfaces left to the map.

        Those surfaces (see ``motion.map_*``) are not masked for tracking; they are grown by
        the fusion's ``dilation`` as the mask is.
        """
        seg = self.segmentation
        if seg is None or seg.map_only_cells is None or not seg.map_only_cells.any():
            return self.mask
        return self.mask | grow(seg.map_only_mask, self.dilation)

    @property
    def cost_ms(self) -> float:
        """The gate's time for the frame on both threads: its :data:`STAGES` together."""
        return gate_cost(self.timings_ms)

    @property
    def segmented(self) -> bool:
        """Whether the frame's motion was segmented (not the first frame, not detections alone)."""
        return self.segmentation is not None

    @property
    def moving_now(self) -> np.ndarray | None:
        """Pixels whose own flow shows motion in this frame (no memory, detection or dilation), if segmented."""
        return None if self.segmentation is None else self.segmentation.moving_mask


@dataclass
class _Observed:
    """What the worker thread computes for one frame: flow, the motion segmentation's inputs, detections.

    ``ahead`` is the segmentation and fusion with the predicted ego-motion, when one was known.
    """

    depth: np.ndarray
    flow: FlowField | None
    grid: MotionGrid | None
    remembered: np.ndarray | None
    detections: list[Detection]
    timings_ms: dict[str, float]
    ahead: tuple[MotionSegmentation, FusedMask] | None = None


class DynamicGate:
    """Computes each frame's dynamic mask from the frame before it (paper §3.1, §3.3).

    Call :meth:`start` with a frame, track it, then :meth:`finish` with the tracked
    ego-motion; :meth:`process` does both for callers without a tracker.
    """

    def __init__(self, cfg: Config, intrinsics: CameraIntrinsics):
        self.cfg = cfg
        self.intrinsics = intrinsics
        self.flow = make_flow_estimator(cfg.flow) if cfg.motion.enabled else None
        self.detector = make_detector(cfg.detection, models_dir(cfg.models.dir))
        self.memory = MotionMemory(cfg.motion.memory_frames, cfg.motion.stride, cfg.motion.memory_per_move)
        self._history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=max(1, cfg.motion.free_space_frames))
        self._ego: np.ndarray | None = None  # the last frame's ego-motion: the next one's prediction
        self._previous: np.ndarray | None = None
        self._prior: np.ndarray | None = None
        self._detections: list[Detection] = []
        self._since_detection = 0
        self._since_people = 0
        self._pending: Future | None = None
        self._to_keep: tuple | None = None  # the last finished frame's bookkeeping, not yet on the worker
        self._kept: Future | None = None  # that bookkeeping, on the worker
        self._kept_ms = 0.0
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="osslam-gate")

    @property
    def wants_colour(self) -> bool:
        """Whether the next frame :meth:`start` is given runs the detector, the only stage that reads its colour image.

        Known once the last started frame is finished; until then (and before the first) True.
        """
        return self.detector is not None and (self._pending is not None or self._detects(self._previous))

    def _detects(self, previous: np.ndarray | None) -> bool:
        """Whether the frame after ``previous`` (None: the first) runs the detector rather than carrying its detections."""
        return previous is None or self.flow is None or self._since_detection + 1 >= self.cfg.detection.interval

    def start(self, rgb: np.ndarray | None, gray: np.ndarray, depth: np.ndarray) -> None:
        """Begin flow and detection of a new frame on the worker thread.

        ``rgb`` may be None when :attr:`wants_colour` is False.
        """
        if rgb is None and self.wants_colour:
            raise ValueError("DynamicGate.start needs the colour image of a frame it detects in")
        if self._pending is not None:
            raise RuntimeError("DynamicGate.start called twice without finish")
        self.keep()
        previous, self._previous = self._previous, gray
        self._pending = self._worker.submit(self._observe, rgb, gray, previous, depth)

    def finish(self, ego_motion: np.ndarray | None = None, guess: np.ndarray | None = None,
               pose: np.ndarray | None = None, defer_keep: bool = False) -> GateResult:
        """The dynamic mask of the started frame.

        ``ego_motion`` is T_previous_current of the camera when tracking knows it; without
        it the motion segmentation fits it to the flow, with ``guess`` (an untrusted
        tracked motion) as one candidate. The segmentation made beside tracking with the
        predicted ego-motion stands where ``ego_motion`` agrees with it.
        ``pose`` (T_world_camera from tracking, None when lost) is kept with the frame's
        depth: ``motion.free_space_frames`` frames later, that frame is placed against it.
        The first frame, with no predecessor, gets detections only. What the next frame
        needs of this one is kept on the worker afterwards; with ``defer_keep`` that waits for
        :meth:`keep`, so that a caller still busy with the result does not share the
        interpreter with it.
        """
        if self._pending is None:
            raise RuntimeError("DynamicGate.finish called before start")
        t0 = time.perf_counter()
        observed: _Observed = self._pending.result()
        self._pending = None
        self._wait_kept()  # done before this frame's flow; a failure there is raised here, not lost
        timings = {**observed.timings_ms, "wait": (time.perf_counter() - t0) * 1e3}
        t1 = time.perf_counter()
        predicted = self._confirmed(observed, ego_motion)
        if observed.grid is not None:
            timings["motion"] += (time.perf_counter() - t1) * 1e3
        if predicted:
            segmentation, fused = observed.ahead
        else:
            segmentation, fused = self._segment(observed, ego_motion, guess, timings)
        timings["finish"] = (time.perf_counter() - t1) * 1e3
        self._to_keep = (observed.depth, segmentation, fused.mask, ego_motion, pose)
        if not defer_keep:
            self.keep()
        return GateResult(fused.mask, segmentation, fused, timings, self.cfg.fusion.dilation, predicted)

    def keep(self) -> None:
        """Begin keeping, on the worker, what the next frame needs of the last finished one, unless begun already.

        :meth:`start` and :meth:`prior` call it too.
        """
        if self._to_keep is not None:
            self._kept = self._worker.submit(self._keep, *self._to_keep)
            self._to_keep = None

    def _keep(self, depth: np.ndarray, segmentation: MotionSegmentation | None, mask: np.ndarray,
              ego_motion: np.ndarray | None, pose: np.ndarray | None) -> None:
        """What the next frame needs of a finished one: its moving cells, depth and pose, its ego-motion and prior.

        Runs on the worker after :meth:`finish` returns, before the next frame's flow; its time
        counts in the next frame's ``motion``.
        """
        t0 = time.perf_counter()
        if segmentation is not None:
            self.memory.store(segmentation.moving_cells, depth)
        self._ego = self._velocity(ego_motion, segmentation)
        self._remember_depth(depth, pose)
        self._prior = grow_square(mask, self.cfg.gating.prior_margin) if mask.any() else None
        self._kept_ms = (time.perf_counter() - t0) * 1e3

    @staticmethod
    def _velocity(ego_motion: np.ndarray | None, segmentation: MotionSegmentation | None) -> np.ndarray | None:
        """The next frame's predicted ego-motion: this frame's anchored tracked one, else the segmentation's.

        The anchored pose comes from the map's mature landmarks, not the flow, so a prediction
        that a large mover pulled towards its own motion does not pass that pull on to the next
        frame's; an unanchored pose may follow a mover itself.
        """
        if ego_motion is not None:
            return ego_motion
        return segmentation.ego_motion if segmentation is not None and segmentation.ok else None

    def _confirmed(self, observed: _Observed, ego_motion: np.ndarray | None) -> bool:
        """Whether the worker's segmentation with the predicted ego-motion stands: the tracked one agrees with it.

        It agrees when it moves at most ``motion.predict_check`` of the background that
        segmentation found. Only an anchored pose confirms it: one that is not may follow a
        mover, and so may a prediction it agrees with.
        """
        if observed.ahead is None or ego_motion is None:
            return False
        share = unexplained_share(observed.ahead[0], observed.grid, ego_motion, self.intrinsics, self.cfg.motion)
        return share <= self.cfg.motion.predict_check

    def _segment(self, observed: _Observed, ego_motion: np.ndarray | None, guess: np.ndarray | None,
                 timings: dict[str, float]) -> tuple[MotionSegmentation | None, FusedMask]:
        """Motion segmentation with ``ego_motion`` (see :func:`segment_motion`) and fusion; adds to their timings."""
        segmentation = None
        objects = []
        if observed.flow is not None:
            t0 = time.perf_counter()
            segmentation = segment_motion(observed.flow, observed.depth, self.intrinsics, self.cfg.motion,
                                          ego_motion, observed.remembered, guess, self._reference(), self._prior,
                                          observed.grid)
            objects = segmentation.objects
            timings["motion"] = timings.get("motion", 0.0) + (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        fused = fuse(objects, observed.detections, self.cfg.fusion, observed.depth.shape)
        timings["fusion"] = timings.get("fusion", 0.0) + (time.perf_counter() - t0) * 1e3
        return segmentation, fused

    def prior(self) -> np.ndarray | None:
        """Where movers may be in the next frame: the last finished frame's mask grown by ``gating.prior_margin``.

        Grown by a square of that half side. None before the first mask and while it is empty.
        The ego-motion fit leaves these pixels out, and the tracker's features of the next frame
        keep out of them.
        """
        self.keep()
        self._wait_kept()
        return self._prior

    def _wait_kept(self) -> None:
        """Wait for the last finished frame's bookkeeping on the worker, raising what it raised."""
        if self._kept is not None:
            self._kept.result()

    def _reference(self) -> DepthReference | None:
        """The oldest kept frame's depth when the last ``motion.free_space_frames`` frames were all tracked."""
        frames = self.cfg.motion.free_space_frames
        if frames <= 0 or len(self._history) < frames:
            return None
        depth, ref_pose = self._history[0]
        return DepthReference(depth, invert(ref_pose) @ self._history[-1][1])

    def _remember_depth(self, depth: np.ndarray, pose: np.ndarray | None) -> None:
        """Keep the frame's depth grid and pose; a frame without a pose breaks the chain."""
        if pose is None:
            self._history.clear()
            return
        self._history.append((depth_grid(depth, max(1, self.cfg.motion.stride)), pose))

    def process(self, rgb: np.ndarray, gray: np.ndarray, depth: np.ndarray,
                ego_motion: np.ndarray | None = None) -> GateResult:
        """:meth:`start` and :meth:`finish` in one call."""
        self.start(rgb, gray, depth)
        return self.finish(ego_motion)

    def close(self) -> None:
        """Stop the worker thread."""
        self._worker.shutdown(wait=True)

    def _observe(self, rgb: np.ndarray | None, gray: np.ndarray, previous: np.ndarray | None,
                 depth: np.ndarray) -> _Observed:
        # the previous frame's bookkeeping ran just before on this worker
        timings: dict[str, float] = {"motion": self._kept_ms} if self._kept_ms else {}
        flow = grid = remembered = None
        if previous is not None and self.flow is not None:
            t0 = time.perf_counter()
            flow = self.flow.compute(gray, previous)
            timings["flow"] = (time.perf_counter() - t0) * 1e3
            t0 = time.perf_counter()
            remembered = self.memory.recall(flow.flow, flow.valid, depth, gray, previous)
            grid = motion_grid(flow, depth, self.intrinsics, self.cfg.motion, self._prior, gray)
            timings["motion"] = timings.get("motion", 0.0) + (time.perf_counter() - t0) * 1e3
        detections: list[Detection] = []
        if self.detector is not None:
            t0 = time.perf_counter()
            if self._detects(previous):
                people = None
                if flow is not None and self._since_people + 1 < self.cfg.detection.person_interval:
                    people = carried_people(self._detections, flow)
                detections = self.detector.detect(rgb, depth, people)
                self._since_detection = 0
                self._since_people = 0 if people is None else self._since_people + 1
            else:
                detections = carried_detections(self._detections, flow)
                self._since_detection += 1
            self._detections = detections
            timings["detection"] = (time.perf_counter() - t0) * 1e3
        observed = _Observed(depth, flow, grid, remembered, detections, timings)
        if grid is not None and self._ego is not None and self.cfg.motion.predict:
            t0 = time.perf_counter()
            predicted = turned_to_the_flow(self._ego, grid, self.intrinsics)
            timings["motion"] += (time.perf_counter() - t0) * 1e3
            observed.ahead = self._segment(observed, predicted, None, timings)
            if observed.ahead[0] is not None:  # its moving pixels, which tracking takes when the prediction stands
                t0 = time.perf_counter()
                observed.ahead[0].moving_mask
                timings["motion"] += (time.perf_counter() - t0) * 1e3
        return observed


def carried_detections(detections: list[Detection], flow: FlowField) -> list[Detection]:
    """The previous frame's detections moved into the current frame by ``flow`` (current to previous)."""
    reach = _reach(flow.flow) if detections else 0
    return [replace(d, mask=_carried(d.mask, flow.flow, reach)) for d in detections]


def carried_people(detections: list[Detection], flow: FlowField) -> np.ndarray | None:
    """The union of the previous frame's person masks moved into the current frame by ``flow``; None without people."""
    people = [d.mask for d in detections if d.label == PERSON]
    if not people:
        return None
    return _carried(np.logical_or.reduce(people), flow.flow, _reach(flow.flow))


def _reach(flow: np.ndarray) -> int:
    """Pixels beyond which no pixel's ``flow`` ends: its longest component, rounded up, and one more."""
    return int(np.ceil(max(float(flow.max()), -float(flow.min())))) + 1


def _carried(mask: np.ndarray, flow: np.ndarray, reach: int) -> np.ndarray:
    """``mask`` (of the previous frame) moved into the current frame by ``flow`` (current to previous).

    Only pixels within ``reach`` of the mask's box can have flow ending in it, so only they
    are warped; the result is the whole image's warp.
    """
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    out = np.zeros_like(mask)
    if w == 0:
        return out
    box = (max(0, x - reach), max(0, y - reach), min(mask.shape[1], x + w + reach), min(mask.shape[0], y + h + reach))
    out[box[1]:box[3], box[0]:box[2]] = cv2.remap(mask.view(np.uint8), flow_targets(flow, box), None,
                                                  cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT) > 0
    return out
