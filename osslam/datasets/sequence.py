"""The interface every sequence reader offers: indexable, iterable frames plus their metadata."""

from __future__ import annotations

import operator
from abc import ABC, abstractmethod
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from osslam.types import CameraIntrinsics, Frame

from .groundtruth import GroundTruth


class FrameSequence(ABC):
    """Frames of one sequence, produced on access.

    Subclasses set ``name``, ``intrinsics``, ``timestamps`` (colour time of each frame),
    ``groundtruth`` (or None) and ``groundtruth_path`` (a TUM file, or None), and
    implement :meth:`_load`.
    """

    name: str
    intrinsics: CameraIntrinsics
    timestamps: np.ndarray
    groundtruth: GroundTruth | None
    groundtruth_path: Path | None

    def __len__(self) -> int:
        """Number of frames."""
        return len(self.timestamps)

    def __getitem__(self, i: int) -> Frame:
        """Frame ``i`` (negative counts from the end); IndexError outside the sequence."""
        i = operator.index(i)
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range for {self.name} ({n} frames)")
        return self._load(i % n)

    def __iter__(self) -> Iterator[Frame]:
        """Every frame in order."""
        for i in range(len(self)):
            yield self._load(i)

    @abstractmethod
    def _load(self, i: int) -> Frame:
        """Produce frame ``i``, with ``0 <= i < len(self)``."""
