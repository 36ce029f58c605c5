"""Detections of potentially dynamic objects as pixel masks, from the configured Yolo-Fastest model."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from osslam import models
from osslam.config import DetectionConfig

from ..fusion import Detection
from .masks import box_mask
from .yolo import CLASS_NAMES, YoloFastest

log = logging.getLogger(__name__)


class ObjectDetector:
    """Yolo-Fastest boxes of every class, each turned into a mask; classes in the config are dynamic."""

    def __init__(self, cfg: DetectionConfig, files: dict[str, Path]):
        self.cfg = cfg
        names = CLASS_NAMES[cfg.model]
        self.yolo = YoloFastest(files["cfg"], files["weights"], names, cfg.threads)
        self.dynamic = set(cfg.classes)

    def detect(self, rgb: np.ndarray, depth: np.ndarray) -> list[Detection]:
        """Masks of the objects found in one frame."""
        return [Detection(box_mask(b, depth, self.cfg.depth_layer), b.label, b.score, b.label in self.dynamic)
                for b in self.yolo.detect(rgb, self.cfg.score)]


def make_detector(cfg: DetectionConfig, models_dir: Path) -> ObjectDetector | None:
    """The detector, or None (logged once) when it is off or its verified files are not in ``models_dir``."""
    if not cfg.enabled:
        return None
    if cfg.model not in CLASS_NAMES:
        raise ValueError(f"detection.model '{cfg.model}' unknown ({', '.join(CLASS_NAMES)})")
    files = {}
    for st in models.status(models.select([cfg.model])[0], models_dir):
        if not st.verified:
            log.warning("no verified %s in %s (%s): gating runs on flow and geometry only; "
                        "`osslam models download %s` fetches it", cfg.model, models_dir,
                        "missing" if not st.present else "checksum mismatch", cfg.model)
            return None
        files[st.path.suffix.lstrip(".")] = st.path
    return ObjectDetector(cfg, files)
