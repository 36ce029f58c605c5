"""The learned flow backend: the multi-scale network at a working resolution, forwards and backwards in one batch."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from osslam.config import FlowConfig
from osslam.errors import OsslamError

from .base import FlowField, checked_flow
from .data.mix import to_network
from .network import FlowNetConfig
from .weights import BUNDLED, load_weights


def weights_path(cfg: FlowConfig) -> Path:
    """``flow.weights`` when set, else the bundled weights of ``flow.learned_preset``."""
    if cfg.weights:
        return Path(cfg.weights).expanduser()
    path = BUNDLED.with_name(f"{cfg.learned_preset}.pt")
    if not path.is_file():
        raise OsslamError(f"{path}: no bundled flow weights for flow.learned_preset '{cfg.learned_preset}'")
    return path


class LearnedFlow:
    """The trained network, run at ``cfg.working_width`` on ``cfg.threads`` CPU threads, checked like DIS.

    Both images go through the encoders once; the forward and backward flows are refined
    as one batch of two, and pixels where they disagree by more than ``fb_threshold`` or
    lack texture are marked invalid.
    """

    def __init__(self, cfg: FlowConfig):
        self.cfg = cfg
        self.net, self.meta = load_weights(weights_path(cfg))
        if cfg.iterations:
            try:
                self.net.cfg = dataclasses.replace(self.net.cfg, iterations=list(cfg.iterations))
            except ValueError as exc:
                raise OsslamError(f"flow.iterations: {exc}") from None
        self.multiple = self.net.cfg.scales[0]

    @property
    def model(self) -> FlowNetConfig:
        """The network's configuration (with ``flow.iterations`` applied)."""
        return self.net.cfg

    def compute(self, source: np.ndarray, target: np.ndarray) -> FlowField:
        """Flow from ``source`` to ``target`` (grayscale uint8 of equal size), at full resolution."""
        h, w = source.shape
        scale = min(1.0, self.cfg.working_width / w)
        size = (max(self.multiple, round(w * scale / self.multiple) * self.multiple),
                max(self.multiple, round(h * scale / self.multiple) * self.multiple))
        return checked_flow(source, target, size, self._both_ways, self.cfg)

    def _both_ways(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flow a -> b and b -> a at the given size, (H, W, 2) each."""
        torch.set_num_threads(self.cfg.threads)
        images = torch.from_numpy(np.stack([to_network(a, True), to_network(b, True)]))
        with torch.inference_mode():
            features = self.net.fnet(images)
            context = self.net.cnet(images)
            pairs = {s: (f, f.flip(0)) for s, f in features.items()}
            flow = self.net.refine(pairs, context, images.shape[-2:], all_steps=False)[-1].flow
        out = flow.permute(0, 2, 3, 1).numpy()
        return out[0], out[1]
