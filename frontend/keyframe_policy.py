"""Keyframe selection by tracked ratio, motion and elapsed frames."""

from __future__ import annotations

import numpy as np

from osslam.config import KeyframeConfig
from osslam.geometry import rotation_angle_deg


class KeyframePolicy:
    """Decides whether the current frame becomes a keyframe."""

    def __init__(self, cfg: KeyframeConfig):
        self.cfg = cfg

    def is_keyframe(self, frames_since: int, n_tracked: int, n_reference: int, T_ref_cur: np.ndarray) -> bool:
        """True when tracking thins out relative to the reference keyframe, or the camera moved enough.

        ``n_tracked`` landmarks were tracked in this frame, ``n_reference`` in the first frame
        after the reference keyframe, and ``T_ref_cur`` is the pose of this frame in that keyframe.
        """
        cfg = self.cfg
        if frames_since < cfg.min_interval:
            return False
        if frames_since >= cfg.max_interval:
            return True
        if n_reference > 0 and n_tracked < cfg.min_tracked_ratio * n_reference:
            return True
        moved = float(np.linalg.norm(T_ref_cur[:3, 3]))
        return moved > cfg.min_translation or rotation_angle_deg(T_ref_cur) > cfg.min_rotation_deg
