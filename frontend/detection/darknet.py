"""Darknet ``.cfg`` sections + ``.weights`` read into a PyTorch module (the layers Yolo-Fastest v1.1 uses)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from osslam.errors import InputError

from .darknet_cfg import Layout, Section


class DarknetNet(nn.Module):
    """The network of a darknet cfg; ``forward`` returns the raw map of each ``[yolo]`` layer."""

    def __init__(self, sections: list[Section]):
        super().__init__()
        net = sections[0]
        self.layout = Layout.of(sections)
        self.defs = sections[1:]
        self.layers = nn.ModuleList()
        channels = [net.get_int("channels", 3)]
        out_channels: list[int] = []
        for s in self.defs:
            c_in = channels[-1]
            if s.type == "convolutional":
                filters, size = s.get_int("filters", 1), s.get_int("size", 1)
                groups, stride = s.get_int("groups", 1), s.get_int("stride", 1)
                pad = size // 2 if s.get_int("pad", 0) else 0
                bn = bool(s.get_int("batch_normalize", 0))
                block = nn.Sequential()
                block.add_module("conv", nn.Conv2d(c_in, filters, size, stride, pad, groups=groups, bias=not bn))
                if bn:
                    block.add_module("bn", nn.BatchNorm2d(filters, eps=1e-5))
                act = s.options.get("activation", "linear")
                if act == "leaky":
                    block.add_module("act", nn.LeakyReLU(0.1))
                elif act != "linear":
                    raise ValueError(f"line {s.line}: activation {act} not supported")
                self.layers.append(block)
                c_out = filters
            elif s.type == "route":
                idx = [i if i >= 0 else len(out_channels) + i for i in s.get_ints("layers")]
                c_out = sum(out_channels[i] for i in idx)
                self.layers.append(nn.Identity())
            else:  # maxpool, shortcut, upsample, dropout and yolo keep the channel count
                self.layers.append(nn.Identity())
                c_out = c_in
            out_channels.append(c_out)
            channels.append(c_out)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        outputs: list[torch.Tensor] = []
        heads: list[torch.Tensor] = []
        for s, layer in zip(self.defs, self.layers):
            if s.type == "convolutional":
                x = layer(x)
            elif s.type == "maxpool":
                size, stride = s.get_int("size", 2), s.get_int("stride", 2)
                if stride == 1:
                    x = F.max_pool2d(F.pad(x, (size // 2,) * 4, value=float("-inf")), size, 1)
                else:
                    x = F.max_pool2d(x, size, stride)
            elif s.type == "route":
                idx = [i if i >= 0 else len(outputs) + i for i in s.get_ints("layers")]
                x = torch.cat([outputs[i] for i in idx], dim=1)
            elif s.type == "shortcut":
                x = x + outputs[s.get_int("from", -1) + len(outputs)]
            elif s.type == "upsample":
                x = F.interpolate(x, scale_factor=s.get_int("stride", 2), mode="nearest")
            elif s.type == "yolo":
                heads.append(x)
            outputs.append(x)
        return heads


def load_weights(net: DarknetNet, path: str | Path) -> None:
    """Read a darknet ``.weights`` file into ``net``; InputError when its size does not fit the cfg."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    data = path.read_bytes()
    major, minor, _ = np.frombuffer(data[:12], dtype=np.int32)
    offset = 12 + (8 if major * 10 + minor >= 2 else 4)
    values = np.frombuffer(data[offset:], dtype=np.float32)
    pos = 0

    def take(n: int) -> torch.Tensor:
        nonlocal pos
        if pos + n > len(values):
            raise InputError(path, f"ends after {len(values)} floats; the cfg needs more")
        out = torch.from_numpy(values[pos : pos + n].copy())
        pos += n
        return out

    with torch.no_grad():
        for s, layer in zip(net.defs, net.layers):
            if s.type != "convolutional":
                continue
            conv = layer.conv
            if hasattr(layer, "bn"):
                bn = layer.bn
                n = bn.num_features
                bn.bias.copy_(take(n))
                bn.weight.copy_(take(n))
                bn.running_mean.copy_(take(n))
                bn.running_var.copy_(take(n))
            else:
                conv.bias.copy_(take(conv.out_channels))
            conv.weight.copy_(take(conv.weight.numel()).view_as(conv.weight))
    if pos != len(values):
        raise InputError(path, f"{len(values) - pos} floats left over after the last layer; cfg and weights differ")
