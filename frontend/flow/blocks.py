"""Building blocks of the flow network: residual units, ConvGRUs, modulated deformable convolution, convex upsampling."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def norm_layer(kind: str, channels: int) -> nn.Module:
    """A normalisation layer by name: ``instance``, ``batch`` or ``none``."""
    if kind == "instance":  # as group norm with one channel per group: InstanceNorm2d's values, a faster CPU kernel
        return nn.GroupNorm(channels, channels, affine=False)
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    if kind == "none":
        return nn.Identity()
    raise ValueError(f"normalisation '{kind}' unknown (instance, batch, none)")


class ResidualUnit(nn.Module):
    """ResNet basic unit: two 3x3 convolutions plus a (projected when the shape changes) skip connection."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1, norm: str = "instance"):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1)
        self.norm1, self.norm2 = norm_layer(norm, c_out), norm_layer(norm, c_out)
        self.skip = (nn.Identity() if stride == 1 and c_in == c_out
                     else nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride=stride), norm_layer(norm, c_out)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        y = self.norm2(self.conv2(y))
        return F.relu(y + self.skip(x))


def tanh(x: torch.Tensor) -> torch.Tensor:
    """tanh as 2 sigmoid(2x) - 1 (within 2e-7): on the CPU torch's sigmoid is about five times faster than its tanh."""
    return 2 * torch.sigmoid(2 * x) - 1


class ConvGRU(nn.Module):
    """Convolutional GRU with 3x3 gates at a given dilation (RAFT's update, paper eq. for z, r, h~, h)."""

    def __init__(self, hidden: int, inputs: int, dilation: int = 1):
        super().__init__()
        args = {"kernel_size": 3, "padding": dilation, "dilation": dilation}
        self.convzr = nn.Conv2d(hidden + inputs, 2 * hidden, **args)  # update and reset gates in one convolution
        self.convq = nn.Conv2d(hidden + inputs, hidden, **args)

    def forward(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        z, r = torch.sigmoid(self.convzr(torch.cat([h, x], dim=1))).chunk(2, dim=1)
        q = tanh(self.convq(torch.cat([r * h, x], dim=1)))
        return torch.lerp(h, q, z)


def modulated_deform_conv3x3(x: torch.Tensor, offset: torch.Tensor, mask: torch.Tensor, weight: torch.Tensor,
                             bias: torch.Tensor | None) -> torch.Tensor:
    """Modulated deformable 3x3 convolution (DCNv2), stride 1, padding 1.

    ``offset`` is (B, 18, H, W): per kernel tap k (row-major over the 3x3 window) the (dy, dx)
    added to its sampling position; ``mask`` is (B, 9, H, W), the modulation of each tap.
    With zero offsets and unit masks this equals ``F.conv2d(x, weight, bias, padding=1)``.
    """
    b, c, h, w = x.shape
    taps = torch.arange(-1, 2, dtype=x.dtype, device=x.device)
    ky, kx = taps.repeat_interleave(3).view(1, 9, 1, 1), taps.repeat(3).view(1, 9, 1, 1)
    ys = torch.arange(h, dtype=x.dtype, device=x.device).view(1, 1, h, 1)
    xs = torch.arange(w, dtype=x.dtype, device=x.device).view(1, 1, 1, w)
    offset = offset.view(b, 9, 2, h, w)
    py = (ys + ky + offset[:, :, 0]) * (2 / max(h - 1, 1)) - 1
    px = (xs + kx + offset[:, :, 1]) * (2 / max(w - 1, 1)) - 1
    grid = torch.stack([px, py], dim=-1).view(b, 9 * h, w, 2)  # the nine taps stacked along y
    sampled = F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    modulated = sampled.view(b, c, 9, h, w).mul_(mask.view(b, 1, 9, h, w)).view(b, c * 9, h, w)
    return F.conv2d(modulated, weight.reshape(weight.shape[0], c * 9, 1, 1), bias)


class ModulatedDeformConv(nn.Module):
    """3x3 modulated deformable convolution whose offsets and masks are predicted from a guide tensor."""

    def __init__(self, channels: int, guide: int):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(channels, channels, 3, 3))
        self.bias = nn.Parameter(torch.zeros(channels))
        nn.init.kaiming_uniform_(self.weight, a=5 ** 0.5)
        self.offset_mask = nn.Conv2d(guide, 27, 3, padding=1)
        nn.init.zeros_(self.offset_mask.weight)
        nn.init.zeros_(self.offset_mask.bias)

    def forward(self, x: torch.Tensor, guide: torch.Tensor) -> torch.Tensor:
        om = self.offset_mask(guide)
        mask = torch.sigmoid(om[:, 18:].contiguous())  # contiguous whatever om's layout: broadcast over channels below
        return modulated_deform_conv3x3(x, om[:, :18], mask, self.weight, self.bias)


def convex_upsample(flow: torch.Tensor, mask: torch.Tensor, factor: int) -> torch.Tensor:
    """Flow (B, 2, H, W) upsampled ``factor`` times as convex combinations of 3x3 neighbours.

    ``mask`` is (B, 9 * factor**2, H, W) logits; the flow values are scaled by ``factor``.
    """
    b, _, h, w = flow.shape
    mask = torch.softmax(mask.reshape(b, 1, 9, factor * factor * h * w), dim=2)
    neigh = F.unfold(factor * flow, 3, padding=1).view(b, 2, 9, 1, h * w)
    mask = mask.view(b, 1, 9, factor * factor, h * w)
    up = neigh[:, :, 0] * mask[:, :, 0]
    for k in range(1, 9):  # one neighbour at a time: no (B, 2, 9, factor^2, H*W) temporary
        up.addcmul_(neigh[:, :, k], mask[:, :, k])
    return up.view(b, 2, factor, factor, h, w).permute(0, 1, 4, 2, 5, 3).reshape(b, 2, factor * h, factor * w)


def coords_grid(b: int, h: int, w: int, device: torch.device, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Pixel coordinates (B, 2, H, W), x first."""
    ys, xs = torch.meshgrid(torch.arange(h, device=device, dtype=dtype), torch.arange(w, device=device, dtype=dtype),
                            indexing="ij")
    return torch.stack([xs, ys]).unsqueeze(0).expand(b, -1, -1, -1)
