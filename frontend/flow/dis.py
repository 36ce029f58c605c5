"""Classical dense flow with OpenCV's DIS at a configurable working resolution."""

from __future__ import annotations

import cv2
import numpy as np

from osslam.config import FlowConfig

from .base import FlowField, forward_backward_valid, textured

_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


class DisFlow:
    """DIS optical flow, computed forwards and backwards at ``cfg.working_width`` and checked."""

    def __init__(self, cfg: FlowConfig):
        if cfg.dis_preset not in _PRESETS:
            raise ValueError(f"flow.dis_preset '{cfg.dis_preset}' unknown ({', '.join(_PRESETS)})")
        self.cfg = cfg
        self._dis = cv2.DISOpticalFlow_create(_PRESETS[cfg.dis_preset])

    def compute(self, source: np.ndarray, target: np.ndarray) -> FlowField:
        """Flow from ``source`` to ``target`` (grayscale uint8 of equal size), at full resolution."""
        h, w = source.shape
        scale = min(1.0, self.cfg.working_width / w)
        size = (max(8, round(w * scale)), max(8, round(h * scale)))
        src = cv2.resize(source, size, interpolation=cv2.INTER_AREA) if scale < 1 else source
        tgt = cv2.resize(target, size, interpolation=cv2.INTER_AREA) if scale < 1 else target
        fwd = self._dis.calc(src, tgt, None)
        bwd = self._dis.calc(tgt, src, None)
        valid = forward_backward_valid(fwd, bwd, self.cfg.fb_threshold) & textured(src, self.cfg.min_texture)
        if scale < 1:
            fwd = cv2.resize(fwd, (w, h), interpolation=cv2.INTER_LINEAR) / scale
            valid = cv2.resize(valid.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
        return FlowField(fwd.astype(np.float32), valid)
