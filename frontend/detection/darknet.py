"""Darknet ``.cfg`` + ``.weights`` read into a PyTorch module (the layers Yolo-Fastest v1.1 uses)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from osslam.errors import InputError

SUPPORTED = {"net", "convolutional", "maxpool", "route", "shortcut", "upsample", "dropout", "yolo"}


@dataclass
class Section:
    """One ``[type]`` block of a darknet cfg with its key=value options and its line."""

    type: str
    options: dict[str, str] = field(default_factory=dict)
    line: int = 0

    def get_int(self, key: str, default: int) -> int:
        return int(self.options.get(key, default))

    def get_ints(self, key: str) -> list[int]:
        return [int(v) for v in self.options[key].split(",") if v.strip()]


def parse_cfg(path: str | Path) -> list[Section]:
    """The sections of a darknet cfg file; InputError naming the file and line when malformed."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file not found")
    sections: list[Section] = []
    for n, raw in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("["):
            if not line.endswith("]"):
                raise InputError(path, f"malformed section header {line!r}", line=n)
            kind = line[1:-1].strip()
            if kind not in SUPPORTED:
                raise InputError(path, f"unsupported layer [{kind}]", line=n)
            sections.append(Section(kind, line=n))
        elif "=" in line and sections:
            key, value = line.split("=", 1)
            sections[-1].options[key.strip()] = value.strip()
        else:
            raise InputError(path, f"expected 'key=value' inside a section, got {line!r}", line=n)
    if not sections or sections[0].type != "net":
        raise InputError(path, "a darknet cfg starts with a [net] section")
    return sections


class YoloHead(nn.Module):
    """Marks a ``[yolo]`` output; the raw map passes through, decoding happens outside the network."""

    def __init__(self, anchors: np.ndarray, classes: int, scale_xy: float):
        super().__init__()
        self.anchors = anchors  # (A, 2) in input pixels
        self.classes = classes
        self.scale_xy = scale_xy

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x


class DarknetNet(nn.Module):
    """The network of a darknet cfg; ``forward`` returns the raw map of each ``[yolo]`` layer."""

    def __init__(self, sections: list[Section]):
        super().__init__()
        net = sections[0]
        self.width, self.height = net.get_int("width", 416), net.get_int("height", 416)
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
            elif s.type == "yolo":
                anchors = np.array(s.get_ints("anchors"), dtype=np.float32).reshape(-1, 2)[s.get_ints("mask")]
                self.layers.append(YoloHead(anchors, s.get_int("classes", 80), float(s.options.get("scale_x_y", 1.0))))
                c_out = c_in
            else:  # maxpool, shortcut, upsample, dropout keep the channel count
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

    def heads(self) -> list[YoloHead]:
        """The ``[yolo]`` layers, in output order."""
        return [m for m in self.layers if isinstance(m, YoloHead)]


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
