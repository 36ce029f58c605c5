"""Dynamic gating: the per-frame mask of moving pixels from flow, motion segmentation and fusion."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from osslam.config import Config
from osslam.types import CameraIntrinsics

from osslam.models import models_dir

from .detection.detector import make_detector
from .flow import make_flow_estimator
from .fusion import Detection, FusedMask, fuse
from .motion import MotionSegmentation, segment_motion


@dataclass
class GateResult:
    """The mask of one frame (True = dynamic, ignored by tracking and mapping) and how it was made."""

    mask: np.ndarray
    segmentation: MotionSegmentation | None
    fused: FusedMask | None
    timings_ms: dict[str, float] = field(default_factory=dict)


class DynamicGate:
    """Computes each frame's dynamic mask from the frame before it (paper §3.1, §3.3)."""

    def __init__(self, cfg: Config, intrinsics: CameraIntrinsics):
        self.cfg = cfg
        self.intrinsics = intrinsics
        self.flow = make_flow_estimator(cfg.flow) if cfg.motion.enabled else None
        self.detector = make_detector(cfg.detection, models_dir(cfg.models.dir))
        self._previous: np.ndarray | None = None

    def process(self, rgb: np.ndarray, gray: np.ndarray, depth: np.ndarray) -> GateResult:
        """The dynamic mask of this frame; the first frame, with no predecessor, gets detections only."""
        previous, self._previous = self._previous, gray
        shape = gray.shape
        timings: dict[str, float] = {}
        detections: list[Detection] = []
        if self.detector is not None:
            t0 = time.perf_counter()
            detections = self.detector.detect(rgb, depth)
            timings["detection"] = (time.perf_counter() - t0) * 1e3
        segmentation = None
        objects = []
        if previous is not None and self.cfg.motion.enabled:
            t0 = time.perf_counter()
            field_ = self.flow.compute(gray, previous)
            t1 = time.perf_counter()
            segmentation = segment_motion(field_, depth, self.intrinsics, self.cfg.motion)
            objects = segmentation.objects
            t2 = time.perf_counter()
            timings.update(flow=(t1 - t0) * 1e3, motion=(t2 - t1) * 1e3)
        t3 = time.perf_counter()
        fused = fuse(objects, detections, self.cfg.fusion, shape)
        timings["fusion"] = (time.perf_counter() - t3) * 1e3
        return GateResult(fused.mask, segmentation, fused, timings)
