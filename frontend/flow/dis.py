"""Classical dense flow with OpenCV's DIS at a configurable working resolution."""

from __future__ import annotations

import cv2
import numpy as np

from osslam.config import FlowConfig

from .base import FlowField, checked_flow

_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


class DisFlow:
    """DIS optical flow, computed forwards and backwards at ``cfg.working_width`` and checked.

    ``cfg.dis_iterations`` and ``cfg.dis_patch_stride``, when above 0, replace the preset's,
    and ``cfg.dis_refinement``, when 0 or more, its variational refinement iterations. The
    backward flow only checks the forward flow: ``cfg.dis_check_refinement``, when 0 or more,
    and ``cfg.dis_check_patch_stride``, when above 0, replace the forward flow's there.
    """

    def __init__(self, cfg: FlowConfig):
        if cfg.dis_preset not in _PRESETS:
            raise ValueError(f"flow.dis_preset '{cfg.dis_preset}' unknown ({', '.join(_PRESETS)})")
        if min(cfg.dis_iterations, cfg.dis_patch_stride, cfg.dis_check_patch_stride) < 0:
            raise ValueError(f"flow.dis_iterations ({cfg.dis_iterations}), flow.dis_patch_stride "
                             f"({cfg.dis_patch_stride}) and flow.dis_check_patch_stride "
                             f"({cfg.dis_check_patch_stride}) must be 0 (the preset's or the forward flow's) or more")
        self.cfg = cfg
        self._dis = _make_dis(cfg, cfg.dis_patch_stride, cfg.dis_refinement, "dis_patch_stride")
        self._check = self._dis
        if cfg.dis_check_refinement >= 0 or cfg.dis_check_patch_stride:
            self._check = _make_dis(cfg, cfg.dis_check_patch_stride or cfg.dis_patch_stride,
                                    cfg.dis_check_refinement if cfg.dis_check_refinement >= 0 else cfg.dis_refinement,
                                    "dis_check_patch_stride" if cfg.dis_check_patch_stride else "dis_patch_stride")

    def compute(self, source: np.ndarray, target: np.ndarray) -> FlowField:
        """Flow from ``source`` to ``target`` (grayscale uint8 of equal size), at full resolution."""
        h, w = source.shape
        scale = min(1.0, self.cfg.working_width / w)
        size = (max(8, round(w * scale)), max(8, round(h * scale))) if scale < 1 else (w, h)
        return checked_flow(source, target, size, self._both_ways, self.cfg)

    def _both_ways(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._dis.calc(a, b, None), self._check.calc(b, a, None)


def _make_dis(cfg: FlowConfig, patch_stride: int, refinement: int, setting: str) -> cv2.DISOpticalFlow:
    """A DIS instance with the preset of ``cfg`` and its iterations, ``patch_stride`` and ``refinement`` over it.

    ``patch_stride`` 0 and ``refinement`` below 0 keep the preset's; ``setting`` names the
    ``flow.*`` entry the patch stride comes from, for the error when it is too large.
    """
    dis = cv2.DISOpticalFlow_create(_PRESETS[cfg.dis_preset])
    if cfg.dis_iterations:
        dis.setGradientDescentIterations(cfg.dis_iterations)
    if patch_stride:
        if patch_stride > dis.getPatchSize():
            raise ValueError(f"flow.{setting} {patch_stride} exceeds the preset's patch size {dis.getPatchSize()}")
        dis.setPatchStride(patch_stride)
    if refinement >= 0:
        dis.setVariationalRefinementIterations(refinement)
    return dis
