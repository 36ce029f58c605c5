"""The learned flow backend: the multi-scale network at a working resolution, forwards and backwards in one batch."""

from __future__ import annotations

import ctypes
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

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


#: glibc ``mallopt`` parameters: the size from which blocks are mapped afresh, and the free top of the heap kept.
M_MMAP_THRESHOLD, M_TRIM_THRESHOLD = -3, -1


def keep_freed_memory() -> None:
    """Have glibc keep freed blocks of up to 32 MB for reuse rather than unmapping them (elsewhere: nothing).

    The network allocates and frees many tensors of a few megabytes per pair; glibc's defaults
    map them afresh each time, and the page faults cost about a sixth of a pair's time on a
    small CPU. The process keeps up to 512 MB of freed memory instead of returning it.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    mallopt(M_MMAP_THRESHOLD, 32 << 20)
    mallopt(M_TRIM_THRESHOLD, 512 << 20)


def grey_input(conv: nn.Conv2d) -> nn.Conv2d:
    """``conv`` for a one-channel image: equal to ``conv`` on that image replicated to all its input channels."""
    grey = nn.Conv2d(1, conv.out_channels, conv.kernel_size, conv.stride, conv.padding, bias=conv.bias is not None)
    with torch.no_grad():
        grey.weight.copy_(conv.weight.sum(dim=1, keepdim=True))
        if conv.bias is not None:
            grey.bias.copy_(conv.bias)
    return grey


@dataclass
class Encoded:
    """A working-size grey image and its encoder outputs per stride (a batch of one)."""

    image: np.ndarray
    features: dict[int, torch.Tensor]
    context: dict[int, torch.Tensor]


class LearnedFlow:
    """The trained network, run at ``cfg.working_width`` on ``cfg.threads`` CPU threads, checked like DIS.

    Each image goes through the encoders once: the last two images' encodings are kept, so
    a stream of consecutive pairs encodes one new image per pair. The forward and backward
    flows are refined as one batch of two, and pixels where they disagree by more than
    ``fb_threshold`` or lack texture are marked invalid.
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
        for encoder in (self.net.fnet, self.net.cnet):  # the runtime's images are grey: one channel in
            encoder.stem[0] = grey_input(encoder.stem[0])
        self.net.to(memory_format=torch.channels_last)  # oneDNN convolves channels-last tensors without reorders
        self.recent: list[Encoded] = []
        keep_freed_memory()

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
        with torch.inference_mode():
            first, second = self._encode([a, b])
            pairs = {s: (torch.cat([f, second.features[s]]), torch.cat([second.features[s], f]))
                     for s, f in first.features.items()}
            context = {s: torch.cat([c, second.context[s]]) for s, c in first.context.items()}
            flow = self.net.refine(pairs, context, a.shape, all_steps=False, convex=1)[-1].flow
        out = flow.permute(0, 2, 3, 1).numpy()
        return out[0], out[1]

    def _encode(self, images: list[np.ndarray]) -> list[Encoded]:
        """Encoder outputs of each image: kept ones reused, the others computed as one batch and kept."""
        found = [next((e for e in self.recent if np.array_equal(e.image, im)), None) for im in images]
        new = [i for i, e in enumerate(found) if e is None]
        if new:
            batch = torch.from_numpy(np.stack([to_network(images[i], True)[:1] for i in new]))
            features, context = self.net.fnet(batch), self.net.cnet(batch)
            for k, i in enumerate(new):
                found[i] = Encoded(images[i].copy(), {s: f[k:k + 1] for s, f in features.items()},
                                   {s: c[k:k + 1] for s, c in context.items()})
        self.recent = (self.recent + [found[i] for i in new])[-2:]
        return found
