"""The multi-scale RAFT-style flow network of paper §3.2 and its typed size configuration."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from .blocks import convex_upsample, coords_grid, tanh
from .correlation import CorrPyramid
from .encoder import STRIDES, MultiScaleEncoder
from .update import MaskHead, MultiScaleUpdate, StandardUpdate


@dataclass
class FlowNetConfig:
    """Sizes and structure of the network.

    ``scales`` lists the strides refined coarse to fine (each of 4, 8, 16), with
    ``iterations`` update steps at each; ``levels`` and ``radius`` shape the correlation
    look-up; ``unet`` picks the U-Net-style encoder over the standard one, ``update``
    the ``multiscale`` or ``standard`` update operator.
    """

    stem: int = 64
    widths: list[int] = field(default_factory=lambda: [64, 96, 128])
    feature_dim: int = 128
    hidden: int = 96
    context: int = 64
    motion_dim: int = 96
    scales: list[int] = field(default_factory=lambda: [16, 8, 4])
    iterations: list[int] = field(default_factory=lambda: [4, 4, 4])
    levels: int = 2
    radius: int = 4
    unet: bool = True
    update: str = "multiscale"

    def __post_init__(self):
        if not self.scales or any(s not in STRIDES for s in self.scales) or list(self.scales) != sorted(self.scales,
                                                                                                       reverse=True):
            raise ValueError(f"model.scales {self.scales}: strides from {STRIDES}, coarsest first")
        if len(self.iterations) != len(self.scales) or min(self.iterations) < 1:
            raise ValueError(f"model.iterations {self.iterations}: one count >= 1 per scale {self.scales}")
        if self.update not in ("multiscale", "standard"):
            raise ValueError(f"model.update '{self.update}' unknown (multiscale, standard)")
        if len(self.widths) != 3:
            raise ValueError(f"model.widths {self.widths}: three channel counts, for 1/4, 1/8, 1/16")


@dataclass
class FlowPrediction:
    """One refinement step's flow at full input resolution, and the stride it was estimated at."""

    stride: int
    flow: torch.Tensor  # (B, 2, H, W)


class MultiScaleFlowNet(nn.Module):
    """Two images (B, 3, H, W) in [-1, 1] -> flow from the first to the second, refined coarse to fine.

    H and W must be multiples of the coarsest stride. At each scale an update operator
    (shared by all scales) refines the flow against that scale's correlation pyramid; the
    flow moves to the next finer scale by x2 convex upsampling and leaves the finest scale
    by convex upsampling to full resolution.
    """

    def __init__(self, cfg: FlowNetConfig):
        super().__init__()
        self.cfg = cfg
        strides = tuple(cfg.scales)
        self.fnet = MultiScaleEncoder(cfg.stem, tuple(cfg.widths), cfg.feature_dim, strides, cfg.unet, "instance")
        self.cnet = MultiScaleEncoder(cfg.stem, tuple(cfg.widths), cfg.hidden + cfg.context, strides, cfg.unet, "none")
        corr_channels = cfg.levels * (2 * cfg.radius + 1) ** 2
        update = MultiScaleUpdate if cfg.update == "multiscale" else StandardUpdate
        self.update = update(cfg.hidden, cfg.context, corr_channels, cfg.motion_dim)
        self.up2 = MaskHead(cfg.hidden, 2 * cfg.hidden, 2) if len(cfg.scales) > 1 else None
        self.up_final = MaskHead(cfg.hidden, 2 * cfg.hidden, cfg.scales[-1])

    def forward(self, image1: torch.Tensor, image2: torch.Tensor, all_steps: bool = False) -> list[FlowPrediction]:
        """Full-resolution flow after the last step, or after every step with ``all_steps`` (for the loss)."""
        b = image1.shape[0]
        features = self.fnet(torch.cat([image1, image2], dim=0))
        context = self.cnet(image1)
        pairs = {s: (f[:b], f[b:]) for s, f in features.items()}
        return self.refine(pairs, context, image1.shape[-2:], all_steps)

    def refine(self, pairs: dict[int, tuple[torch.Tensor, torch.Tensor]], context: dict[int, torch.Tensor],
               size: tuple[int, int], all_steps: bool, convex: int | None = None) -> list[FlowPrediction]:
        """Coarse-to-fine refinement from encoder outputs: per stride the (source, target) features and context.

        With ``convex`` set, only the batch's first ``convex`` flows leave the finest scale by
        convex upsampling; the others are resized bilinearly (cheaper, for a consistency check).
        The flow follows the memory format of ``context`` (channels-last or contiguous).
        """
        cfg = self.cfg
        flow = features = None
        out: list[FlowPrediction] = []
        for k, (stride, n_iter) in enumerate(zip(cfg.scales, cfg.iterations)):
            f1, f2 = pairs[stride]
            corr = CorrPyramid(f1, f2, cfg.levels, cfg.radius)
            hidden, ctx = torch.split(context[stride], [cfg.hidden, cfg.context], dim=1)
            hidden, ctx = tanh(hidden), F.relu(ctx)
            b, _, h, w = f1.shape
            coords0 = coords_grid(b, h, w, f1.device, f1.dtype)
            flow = torch.zeros_like(coords0) if flow is None else convex_upsample(flow, self.up2(features), 2)
            flow = flow.contiguous(memory_format=_layout(context[stride]))
            last_scale = k == len(cfg.scales) - 1
            for i in range(n_iter):
                step = self.update(hidden, ctx, corr((coords0 + flow).detach()), flow)
                hidden, features = step.hidden, step.features
                flow = flow + step.delta
                if last_scale and i == n_iter - 1:
                    out.append(FlowPrediction(stride, self._upsample_final(flow, features, stride, convex)))
                elif all_steps:
                    full = F.interpolate(flow, size=tuple(size), mode="bilinear", align_corners=False) * stride
                    out.append(FlowPrediction(stride, full))
        return out

    def _upsample_final(self, flow: torch.Tensor, features: torch.Tensor, stride: int,
                        convex: int | None) -> torch.Tensor:
        """The finest scale's flow at full resolution: convex upsampling for the first ``convex`` items (all: None)."""
        if convex is None or convex >= flow.shape[0]:
            return convex_upsample(flow, self.up_final(features), stride)
        up = convex_upsample(flow[:convex], self.up_final(features[:convex]), stride)
        rest = F.interpolate(flow[convex:], scale_factor=stride, mode="bilinear", align_corners=False) * stride
        return torch.cat([up, rest])


def _layout(x: torch.Tensor) -> torch.memory_format:
    """The memory format ``x`` (B, C, H, W) is laid out in: channels-last or contiguous."""
    return torch.channels_last if x.is_contiguous(memory_format=torch.channels_last) else torch.contiguous_format


def count_parameters(net: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)
