"""A darknet ``.cfg`` read into its sections, and the input size and ``[yolo]`` outputs it declares."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

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


@dataclass(frozen=True)
class YoloOutput:
    """A ``[yolo]`` layer's decoding: its anchors (A, 2) in input pixels, class count and centre scale."""

    anchors: np.ndarray
    classes: int
    scale_xy: float

    @classmethod
    def of(cls, section: Section) -> YoloOutput:
        """The decoding a ``[yolo]`` section declares (its masked anchors)."""
        anchors = np.array(section.get_ints("anchors"), dtype=np.float32).reshape(-1, 2)[section.get_ints("mask")]
        return cls(anchors, section.get_int("classes", 80), float(section.options.get("scale_x_y", 1.0)))


@dataclass(frozen=True)
class Layout:
    """What decoding needs of a darknet network: its input width and height and its ``[yolo]`` outputs in order."""

    width: int
    height: int
    outputs: tuple[YoloOutput, ...]

    @classmethod
    def of(cls, sections: list[Section]) -> Layout:
        """The layout the sections of a cfg declare."""
        net = sections[0]
        return cls(net.get_int("width", 416), net.get_int("height", 416),
                   tuple(YoloOutput.of(s) for s in sections[1:] if s.type == "yolo"))


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
