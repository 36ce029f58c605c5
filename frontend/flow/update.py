"""Update operators: the multi-scale update of paper §3.2.2 (ConvGRU d=1, ConvGRU d=2, modulated DCN) and RAFT's standard one."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .blocks import ConvGRU, ModulatedDeformConv


@dataclass
class UpdateOutput:
    """One refinement step: the new recurrent state, the flow increment, and the features the mask heads read."""

    hidden: torch.Tensor
    delta: torch.Tensor
    features: torch.Tensor


class MotionEncoder(nn.Module):
    """Correlation look-ups and the current flow -> motion features (RAFT's motion encoder), flow appended."""

    def __init__(self, corr_channels: int, out_dim: int):
        super().__init__()
        self.corr = nn.Conv2d(corr_channels, out_dim, 1)
        self.flow1 = nn.Conv2d(2, out_dim // 2, 7, padding=3)
        self.flow2 = nn.Conv2d(out_dim // 2, out_dim // 4, 3, padding=1)
        self.out = nn.Conv2d(out_dim + out_dim // 4, out_dim - 2, 3, padding=1)

    def forward(self, corr: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
        c = F.relu(self.corr(corr))
        f = F.relu(self.flow2(F.relu(self.flow1(flow))))
        return torch.cat([F.relu(self.out(torch.cat([c, f], dim=1))), flow], dim=1)


class FlowHead(nn.Module):
    """Features -> a 2-channel flow increment."""

    def __init__(self, channels: int, width: int):
        super().__init__()
        self.conv1 = nn.Conv2d(channels, width, 3, padding=1)
        self.conv2 = nn.Conv2d(width, 2, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv2(F.relu(self.conv1(x)))


class MaskHead(nn.Module):
    """Features -> convex upsampling weights for a ``factor`` times larger flow (scaled as in RAFT)."""

    def __init__(self, channels: int, width: int, factor: int):
        super().__init__()
        self.conv1 = nn.Conv2d(channels, width, 3, padding=1)
        self.conv2 = nn.Conv2d(width, 9 * factor * factor, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return 0.25 * self.conv2(F.relu(self.conv1(x)))


class MultiScaleUpdate(nn.Module):
    """ConvGRU (dilation 1), ConvGRU (dilation 2), then a modulated deformable convolution.

    The GRUs read the motion features and context; the DCN's offsets and masks are predicted
    from the same inputs and the second GRU's state, and its output feeds the flow and mask
    heads. The recurrent state carried to the next step is the second GRU's.
    """

    def __init__(self, hidden: int, context: int, corr_channels: int, motion_dim: int):
        super().__init__()
        self.motion = MotionEncoder(corr_channels, motion_dim)
        inputs = motion_dim + context
        self.gru1 = ConvGRU(hidden, inputs, dilation=1)
        self.gru2 = ConvGRU(hidden, inputs, dilation=2)
        self.dcn = ModulatedDeformConv(hidden, hidden + inputs)
        self.flow = FlowHead(hidden, 2 * hidden)

    def forward(self, hidden: torch.Tensor, context: torch.Tensor, corr: torch.Tensor,
                flow: torch.Tensor) -> UpdateOutput:
        x = torch.cat([self.motion(corr, flow), context], dim=1)
        h = self.gru2(self.gru1(hidden, x), x)
        features = F.relu(self.dcn(h, torch.cat([h, x], dim=1)))
        return UpdateOutput(h, self.flow(features), features)


class StandardUpdate(nn.Module):
    """RAFT-small's update: one ConvGRU (dilation 1) whose state feeds the heads."""

    def __init__(self, hidden: int, context: int, corr_channels: int, motion_dim: int):
        super().__init__()
        self.motion = MotionEncoder(corr_channels, motion_dim)
        self.gru = ConvGRU(hidden, motion_dim + context, dilation=1)
        self.flow = FlowHead(hidden, 2 * hidden)

    def forward(self, hidden: torch.Tensor, context: torch.Tensor, corr: torch.Tensor,
                flow: torch.Tensor) -> UpdateOutput:
        h = self.gru(hidden, torch.cat([self.motion(corr, flow), context], dim=1))
        return UpdateOutput(h, self.flow(h), h)
