"""Detections of potentially dynamic objects as pixel masks, from the configured Yolo-Fastest model."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from osslam import models
from osslam.config import DetectionConfig

from ..fusion import Detection
from .masks import box_mask
from .person_mask import PersonSegmenter
from .yolo import CLASS_NAMES, RUNTIMES, Box, YoloFastest

log = logging.getLogger(__name__)


PERSON = "person"
SEGMENTATION_MODEL = "mediapipe-selfie-segmentation"
# a person mask filling less of its box than this falls back to the depth layer: the selfie model segments
# a torso cut off by the image's edge poorly (on composites: 5-25 % of the person, against 88-94 %)
MIN_PERSON_FILL = 0.3


class ObjectDetector:
    """Yolo-Fastest boxes of every class, each turned into a mask; classes in the config are dynamic.

    A box's mask is its dominant depth layer; a person's is the person segmentation inside
    the box when ``segmenter`` is given.
    """

    def __init__(self, cfg: DetectionConfig, files: dict[str, Path], segmenter: PersonSegmenter | None = None):
        self.cfg = cfg
        names = CLASS_NAMES[cfg.model]
        self.yolo = YoloFastest(files["cfg"], files["weights"], names, cfg.threads, cfg.runtime,
                                tuple(cfg.input_size) if cfg.input_size else None)
        self.dynamic = set(cfg.classes)
        self.segmenter = segmenter

    def detect(self, rgb: np.ndarray, depth: np.ndarray, people: np.ndarray | None = None) -> list[Detection]:
        """Masks of the objects found in one frame.

        ``people`` (a full-image mask of people known otherwise, such as the last
        segmentation moved by the flow) stands in for the segmentation inside a person's box
        where it fills at least ``MIN_PERSON_FILL`` of the box.
        """
        return [Detection(self._mask(b, rgb, depth, people), b.label, b.score, b.label in self.dynamic)
                for b in self.yolo.detect(rgb, self.cfg.score)]

    def _mask(self, box: Box, rgb: np.ndarray, depth: np.ndarray, people: np.ndarray | None) -> np.ndarray:
        if self.segmenter is not None and box.label == PERSON:
            corners = (max(0, int(box.x0)), max(0, int(box.y0)), int(np.ceil(box.x1)), int(np.ceil(box.y1)))
            area = max(1, (corners[2] - corners[0]) * (corners[3] - corners[1]))
            if people is not None:
                inside = np.s_[corners[1]:corners[3], corners[0]:corners[2]]
                known = np.zeros_like(people)
                known[inside] = people[inside]
                if known.sum() >= MIN_PERSON_FILL * area:
                    return known
            mask = self.segmenter.mask_in_box(rgb, corners)
            if mask.sum() >= MIN_PERSON_FILL * area:
                return mask
        return box_mask(box, depth, self.cfg.depth_layer)


def _verified_files(name: str, folder: Path) -> dict[str, Path] | None:
    """The model's files by suffix when all are present and verified, else None (logged)."""
    files = {}
    for st in models.status(models.select([name])[0], folder):
        if not st.verified:
            log.warning("no verified %s in %s (%s); `osslam models download %s` fetches it", name, folder,
                        "missing" if not st.present else "checksum mismatch", name)
            return None
        files.setdefault(st.path.suffix.lstrip("."), st.path)
    return files


def make_detector(cfg: DetectionConfig, models_dir: Path) -> ObjectDetector | None:
    """The detector, or None (logged once) when it is off or its verified files are not in ``models_dir``.

    With ``cfg.person_segmentation`` and the segmentation model present, people get
    segmentation masks; otherwise depth-layer masks (logged once).
    """
    if not cfg.enabled:
        return None
    if cfg.model not in CLASS_NAMES:
        raise ValueError(f"detection.model '{cfg.model}' unknown ({', '.join(CLASS_NAMES)})")
    for key in ("interval", "person_interval"):
        if getattr(cfg, key) < 1:
            raise ValueError(f"detection.{key} must be 1 or more, not {getattr(cfg, key)}")
    if cfg.runtime not in RUNTIMES:
        raise ValueError(f"detection.runtime '{cfg.runtime}' unknown ({', '.join(RUNTIMES)})")
    unknown = [name for name in cfg.classes if name not in CLASS_NAMES[cfg.model]]
    if unknown:
        raise ValueError(f"detection.classes: {', '.join(map(repr, unknown))} not among {cfg.model}'s classes "
                         f"({', '.join(CLASS_NAMES[cfg.model])})")
    files = _verified_files(cfg.model, models_dir)
    if files is None:
        log.warning("gating runs on flow and geometry only")
        return None
    segmenter = None
    if cfg.person_segmentation:
        seg_files = _verified_files(SEGMENTATION_MODEL, models_dir)
        if seg_files is None:
            log.warning("people are masked by their depth layer only")
        else:
            segmenter = PersonSegmenter(seg_files["tflite"])
    return ObjectDetector(cfg, files, segmenter)
