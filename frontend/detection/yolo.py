"""Yolo-Fastest inference: letterbox-free resize, the darknet network (OpenCV DNN or PyTorch), decoding and NMS.

PyTorch is imported only when the network runs in it or its ONNX export is built: reading a
cached export, the usual case, leaves a process without it (measured: 1.8 s and 490 MB less a process).
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from .darknet_cfg import Layout, parse_cfg
from .onnx_export import OnnxExportError, cached_dnn, output_names

if TYPE_CHECKING:
    from .darknet import DarknetNet

log = logging.getLogger(__name__)

#: Where the network runs: its ONNX export in OpenCV's DNN module, or the PyTorch module.
RUNTIMES = ("opencv", "torch")


#: Class names of the models, in output order (COCO as darknet's coco.names; the body model's one class is a person).
CLASS_NAMES = {
    "yolo-fastest-1.1": [
        "person", "bicycle", "car", "motorbike", "aeroplane", "bus", "train", "truck", "boat", "traffic light",
        "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog", "horse", "sheep", "cow",
        "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella", "handbag", "tie", "suitcase", "frisbee",
        "skis", "snowboard", "sports ball", "kite", "baseball bat", "baseball glove", "skateboard", "surfboard",
        "tennis racket", "bottle", "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple",
        "sandwich", "orange", "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "sofa",
        "pottedplant", "bed", "diningtable", "toilet", "tvmonitor", "laptop", "mouse", "remote", "keyboard",
        "cell phone", "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
        "teddy bear", "hair drier", "toothbrush",
    ],
    "yolo-fastest-1.1-body": ["person"],
}


@dataclass
class Box:
    """A detected object: corners in image pixels, class id and name, confidence."""

    x0: float
    y0: float
    x1: float
    y1: float
    class_id: int
    label: str
    score: float


@functools.lru_cache(maxsize=8)
def _cell_grid(gh: int, gw: int) -> np.ndarray:
    """Row and column of every cell of a (gh, gw) output map, as ``np.mgrid`` gives them (read-only)."""
    grid = np.mgrid[0:gh, 0:gw]
    grid.flags.writeable = False
    return grid


def decode(heads: list[np.ndarray], layout: Layout, image_size: tuple[int, int],
           input_size: tuple[int, int] | None = None) -> np.ndarray:
    """Raw ``[yolo]`` maps to rows (x0, y0, x1, y1, objectness * class prob ..) in image pixels.

    Returns an (N, 4 + C) array over every anchor of every cell: darknet's logistic x, y,
    objectness and classes, exp(w, h) times the anchors, scaled from the network input
    (``input_size``, width and height; the cfg's when None) to the image.
    """
    w_img, h_img = image_size
    in_w, in_h = input_size or (layout.width, layout.height)
    rows = []
    for raw, head in zip(heads, layout.outputs):
        gh, gw = raw.shape[-2:]
        a = len(head.anchors)
        p = raw[0].reshape(a, 5 + head.classes, gh, gw).transpose(0, 2, 3, 1)  # (A, gh, gw, 5+C)
        gy, gx = _cell_grid(gh, gw)
        sig = 1.0 / (1.0 + np.exp(-p))
        cx = (sig[..., 0] * head.scale_xy - 0.5 * (head.scale_xy - 1) + gx) / gw
        cy = (sig[..., 1] * head.scale_xy - 0.5 * (head.scale_xy - 1) + gy) / gh
        bw = np.exp(p[..., 2]) * head.anchors[:, 0, None, None] / in_w
        bh = np.exp(p[..., 3]) * head.anchors[:, 1, None, None] / in_h
        scores = sig[..., 4:5] * sig[..., 5:]
        box = np.stack([(cx - bw / 2) * w_img, (cy - bh / 2) * h_img, (cx + bw / 2) * w_img,
                        (cy + bh / 2) * h_img], axis=-1)
        rows.append(np.concatenate([box, scores], axis=-1).reshape(-1, 4 + head.classes))
    return np.concatenate(rows, axis=0)


@functools.cache
def _fall_back_to_torch(reason: str) -> None:
    """Log, once per reason, that the OpenCV runtime is unavailable."""
    log.warning("%s; Yolo-Fastest runs in PyTorch instead of OpenCV's DNN", reason)


class YoloFastest:
    """Yolo-Fastest v1.1 from darknet files, run on the CPU.

    ``runtime`` "opencv" runs the network's cached ONNX export in OpenCV's DNN module, on
    OpenCV's process-wide threads (``cv2.setNumThreads``, which ``run.threads`` sets); it
    falls back to "torch" (logged once) when the export cannot be built or read.
    ``runtime`` "torch" runs the PyTorch module on ``threads`` threads. ``input_size`` (width,
    height, multiples of 32) replaces the cfg's input size: the network is fully
    convolutional, and a smaller input costs less.
    """

    def __init__(self, cfg_path: str | Path, weights_path: str | Path, names: list[str], threads: int = 1,
                 runtime: str = "opencv", input_size: tuple[int, int] | None = None):
        if runtime not in RUNTIMES:
            raise ValueError(f"runtime '{runtime}' unknown ({', '.join(RUNTIMES)})")
        if input_size is not None and (len(input_size) != 2 or any(v < 32 or v % 32 for v in input_size)):
            raise ValueError(f"input size {input_size}: width and height must be multiples of 32")
        self._sections = parse_cfg(cfg_path)
        self._weights_path = Path(weights_path)
        self.layout = Layout.of(self._sections)
        self.input_size = tuple(input_size) if input_size is not None else (self.layout.width, self.layout.height)
        self.names = names
        self.threads = threads
        self.net: DarknetNet | None = None  # the PyTorch module, built by network() when first needed
        self.dnn = self._open_dnn(Path(cfg_path)) if runtime == "opencv" else None
        if self.dnn is None:
            self.network()
        self._outputs = output_names(self.layout)
        self.runtime = "opencv" if self.dnn is not None else "torch"

    def network(self) -> DarknetNet:
        """The PyTorch module with the darknet weights loaded (built, and PyTorch imported, on first call)."""
        if self.net is None:
            from .darknet import DarknetNet, load_weights

            net = DarknetNet(self._sections)
            load_weights(net, self._weights_path)
            self.net = net.eval()
        return self.net

    def _open_dnn(self, cfg_path: Path) -> cv2.dnn.Net | None:
        try:
            return cached_dnn(cfg_path, self._weights_path, self.layout, self.network)
        except OnnxExportError as exc:
            _fall_back_to_torch(str(exc))
            return None

    def raw(self, rgb: np.ndarray) -> list[np.ndarray]:
        """The raw head outputs, each (1, A * (5 + C), gh, gw), of an RGB uint8 image resized to the input size."""
        x = cv2.resize(rgb, self.input_size, interpolation=cv2.INTER_LINEAR)
        blob = np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32) / np.float32(255.0)
        if self.dnn is not None:
            self.dnn.setInput(blob)
            return list(self.dnn.forward(self._outputs))
        import torch

        torch.set_num_threads(self.threads)
        with torch.inference_mode():
            return [h.numpy() for h in self.network()(torch.from_numpy(blob))]

    def detect(self, rgb: np.ndarray, score_threshold: float = 0.3, nms_threshold: float = 0.45) -> list[Box]:
        """Boxes above ``score_threshold`` after per-class non-maximum suppression."""
        h, w = rgb.shape[:2]
        rows = decode(self.raw(rgb), self.layout, (w, h), self.input_size)
        cls = rows[:, 4:].argmax(axis=1)
        score = rows[np.arange(len(rows)), 4 + cls]
        keep = score > score_threshold
        rows, cls, score = rows[keep], cls[keep], score[keep]
        if len(rows) == 0:
            return []
        xywh = np.column_stack([rows[:, 0], rows[:, 1], rows[:, 2] - rows[:, 0], rows[:, 3] - rows[:, 1]])
        idx = cv2.dnn.NMSBoxesBatched(xywh.tolist(), score.tolist(), cls.tolist(), score_threshold, nms_threshold)
        out = []
        for i in np.asarray(idx).ravel():
            x0, y0, x1, y1 = np.clip(rows[i, :4], 0, [w, h, w, h])
            out.append(Box(float(x0), float(y0), float(x1), float(y1), int(cls[i]), self.names[cls[i]],
                           float(score[i])))
        return sorted(out, key=lambda b: -b.score)
