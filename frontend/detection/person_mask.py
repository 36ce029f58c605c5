"""Person masks from MediaPipe's selfie segmentation (TFLite, run by OpenCV's DNN module)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from osslam.errors import InputError

INPUT_SIZE = 256


class PersonSegmenter:
    """Per-pixel person probability of an RGB image or crop, from the 256x256 selfie model."""

    def __init__(self, model_path: Path):
        try:
            self.net = cv2.dnn.readNetFromTFLite(str(model_path))
        except cv2.error:
            raise InputError(model_path, "cannot load the person segmentation model") from None

    def probability(self, rgb: np.ndarray) -> np.ndarray:
        """Person probability in [0, 1] for each pixel of ``rgb`` (H, W, 3 uint8)."""
        blob = (cv2.resize(rgb, (INPUT_SIZE, INPUT_SIZE)).astype(np.float32) / 255.0).transpose(2, 0, 1)[None]
        self.net.setInput(blob)
        out = self.net.forward().reshape(INPUT_SIZE, INPUT_SIZE)
        return cv2.resize(out, (rgb.shape[1], rgb.shape[0]), interpolation=cv2.INTER_LINEAR)

    def mask_in_box(self, rgb: np.ndarray, box: tuple[int, int, int, int], threshold: float = 0.5,
                    margin: float = 0.1) -> np.ndarray:
        """Full-image mask of the person inside ``box`` (x0, y0, x1, y1), segmented on the box grown by ``margin``."""
        h, w = rgb.shape[:2]
        x0, y0, x1, y1 = box
        mx, my = int(margin * (x1 - x0)), int(margin * (y1 - y0))
        cx0, cy0, cx1, cy1 = max(0, x0 - mx), max(0, y0 - my), min(w, x1 + mx), min(h, y1 + my)
        mask = np.zeros((h, w), bool)
        if cx1 - cx0 < 8 or cy1 - cy0 < 8:
            return mask
        prob = self.probability(np.ascontiguousarray(rgb[cy0:cy1, cx0:cx1]))
        mask[cy0:cy1, cx0:cx1] = prob > threshold
        inside = np.zeros((h, w), bool)
        inside[y0:y1, x0:x1] = True
        return mask & inside
