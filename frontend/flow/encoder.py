"""The multi-scale feature (and context) encoder of paper §3.2.1: ResNet units, U-Net-like top-down fusion."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .blocks import ResidualUnit, norm_layer

#: Strides of the three feature scales the encoder produces.
STRIDES = (4, 8, 16)


class MultiScaleEncoder(nn.Module):
    """Image (B, 3, H, W) -> features at 1/4, 1/8 and 1/16 resolution, ``out_dim`` channels each.

    A 7x7 stem (3 -> ``stem`` channels, stride 2) and strided residual units give
    intermediate features at 1/4, 1/8, 1/16. With ``unet`` the deepest scale is upsampled,
    projected, added to the next shallower one and fused by a residual unit, down to 1/4;
    without it (the "standard" encoder of the ablation) each scale keeps its bottom-up
    features. A 1x1 head per requested stride gives the output. Parts that the requested
    strides never read are not built.
    """

    def __init__(self, stem: int, widths: tuple[int, int, int], out_dim: int, strides: tuple[int, ...],
                 unet: bool = True, norm: str = "instance"):
        super().__init__()
        self.strides = tuple(strides)
        c4, c8, c16 = widths
        finest, deepest = min(self.strides), 16 if unet else max(self.strides)
        self.stem = nn.Sequential(nn.Conv2d(3, stem, 7, stride=2, padding=3), norm_layer(norm, stem), nn.ReLU())
        self.down4 = ResidualUnit(stem, c4, stride=2, norm=norm)
        self.down8 = ResidualUnit(c4, c8, stride=2, norm=norm) if deepest >= 8 else None
        self.down16 = ResidualUnit(c8, c16, stride=2, norm=norm) if deepest >= 16 else None
        self.lateral8 = nn.Conv2d(c16, c8, 1) if unet and finest <= 8 else None
        self.fuse8 = ResidualUnit(c8, c8, norm=norm) if self.lateral8 is not None else None
        self.lateral4 = nn.Conv2d(c8, c4, 1) if unet and finest <= 4 else None
        self.fuse4 = ResidualUnit(c4, c4, norm=norm) if self.lateral4 is not None else None
        width = dict(zip(STRIDES, widths))
        self.heads = nn.ModuleDict({str(s): nn.Conv2d(width[s], out_dim, 1) for s in self.strides})

    def forward(self, image: torch.Tensor) -> dict[int, torch.Tensor]:
        x4 = self.down4(self.stem(image))
        x8 = self.down8(x4) if self.down8 is not None else None
        x16 = self.down16(x8) if self.down16 is not None else None
        if self.fuse8 is not None:
            x8 = self.fuse8(x8 + self.lateral8(_up(x16, x8)))
        if self.fuse4 is not None:
            x4 = self.fuse4(x4 + self.lateral4(_up(x8, x4)))
        features = {4: x4, 8: x8, 16: x16}
        return {s: self.heads[str(s)](features[s]) for s in self.strides}


def _up(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """``x`` bilinearly resized to the spatial size of ``like``."""
    return F.interpolate(x, size=like.shape[-2:], mode="bilinear", align_corners=False)
