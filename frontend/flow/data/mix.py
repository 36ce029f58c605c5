"""The training stream: samples drawn from weighted sources, cropped, flipped and turned grey, as tensors."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence

from .procedural import ProceduralConfig, ProceduralPairs
from .rigid import RigidFlowPairs
from .sample import FlowSample
from .standard import LAYOUTS


@dataclass
class Batch:
    """Images (B, 3, H, W) in [-1, 1], flow (B, 2, H, W) and validity (B, H, W) as float."""

    image1: torch.Tensor
    image2: torch.Tensor
    flow: torch.Tensor
    valid: torch.Tensor


class CachedSource:
    """A dataset whose first ``capacity`` samples read stay in memory."""

    def __init__(self, dataset: Sequence[FlowSample], capacity: int):
        self.dataset = dataset
        self.capacity = capacity
        self._cache: dict[int, FlowSample] = {}

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, i: int) -> FlowSample:
        if i in self._cache:
            return self._cache[i]
        sample = self.dataset[i]
        if len(self._cache) < self.capacity:
            self._cache[i] = sample
        return sample


def room_pairs(seeds: list[int], frames: int, size: list[int], gaps: list[int]) -> RigidFlowPairs:
    """Rigid flow of the synthetic room (noise-free depth), one sequence per seed, as one dataset."""
    w, h = size
    f = 525.0 * w / 640
    parts = [RigidFlowPairs(SyntheticSequence(SyntheticConfig(n_frames=frames, seed=s, width=w, height=h, fx=f, fy=f,
                                                              cx=(w - 1) / 2, cy=(h - 1) / 2, depth_noise=False,
                                                              dropout=0.0, holes=False)), tuple(gaps))
             for s in seeds]
    return _Concat(parts)


class _Concat:
    """Datasets one after another."""

    def __init__(self, parts: list):
        self.parts = parts
        self.offsets = np.cumsum([0] + [len(p) for p in parts])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def __getitem__(self, i: int) -> FlowSample:
        k = int(np.searchsorted(self.offsets, i, side="right")) - 1
        return self.parts[k][i - int(self.offsets[k])]


def build_sources(weights: dict[str, float], procedural: ProceduralConfig, room: dict, roots: dict[str, str],
                  cache: int, seed: int) -> dict[str, Sequence[FlowSample]]:
    """The datasets a training mix names: ``procedural``, ``room`` and the standard layouts by name."""
    sources: dict[str, Sequence[FlowSample]] = {}
    for name in weights:
        if name == "procedural":
            sources[name] = ProceduralPairs(procedural, seed)
        elif name == "room":
            sources[name] = CachedSource(room_pairs(**room), cache)
        elif name in LAYOUTS:
            if name not in roots:
                raise ValueError(f"data.weights names '{name}' but data.roots gives no folder for it")
            sources[name] = LAYOUTS[name](roots[name])
        else:
            raise ValueError(f"data source '{name}' unknown (procedural, room, {', '.join(LAYOUTS)})")
    return sources


def to_network(image: np.ndarray, grayscale: bool) -> np.ndarray:
    """uint8 RGB (H, W, 3) or grey (H, W) -> float32 (3, H, W) in [-1, 1], grey replicated when asked."""
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    elif grayscale:
        image = np.repeat(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[:, :, None], 3, axis=2)
    return image.transpose(2, 0, 1).astype(np.float32) / 127.5 - 1.0


class TrainingStream:
    """Batch ``step`` is a pure function of (seed, step): training resumes on the same data."""

    def __init__(self, sources: dict[str, Sequence[FlowSample]], weights: dict[str, float], crop: list[int],
                 batch: int, seed: int, grayscale: bool, flip: bool):
        self.sources = sources
        self.names = list(weights)
        p = np.array([weights[n] for n in self.names], np.float64)
        self.p = p / p.sum()
        self.crop = crop
        self.batch = batch
        self.seed = seed
        self.grayscale = grayscale
        self.flip = flip

    def __call__(self, step: int) -> Batch:
        rng = np.random.default_rng([self.seed, step])
        items = []
        for _ in range(self.batch):
            source = self.sources[self.names[rng.choice(len(self.names), p=self.p)]]
            items.append(self._augment(source[int(rng.integers(len(source)))], rng))
        im1, im2, flow, valid = (torch.from_numpy(np.stack(x)) for x in zip(*items))
        return Batch(im1, im2, flow, valid)

    def _augment(self, s: FlowSample, rng: np.random.Generator):
        """Random crop (padded when too small), horizontal flip and brightness/contrast jitter."""
        ch, cw = self.crop
        im1, im2, flow, valid = s.image1, s.image2, s.flow, s.valid
        h, w = flow.shape[:2]
        if h < ch or w < cw:
            pad = ((0, max(0, ch - h)), (0, max(0, cw - w)))
            im1, im2 = (np.pad(x, pad + ((0, 0),), mode="edge") for x in (im1, im2))
            flow, valid = np.pad(flow, pad + ((0, 0),)), np.pad(valid, pad)
            h, w = flow.shape[:2]
        y, x = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
        win = (slice(y, y + ch), slice(x, x + cw))
        im1, im2, flow, valid = im1[win], im2[win], flow[win].copy(), valid[win]
        if self.flip and rng.random() < 0.5:
            im1, im2, flow, valid = im1[:, ::-1], im2[:, ::-1], flow[:, ::-1].copy(), valid[:, ::-1]
            flow[..., 0] *= -1
        gain, bias = rng.uniform(0.8, 1.2), rng.uniform(-20, 20)
        im1, im2 = (np.clip(im.astype(np.float32) * gain + bias, 0, 255).astype(np.uint8) for im in (im1, im2))
        return (to_network(im1, self.grayscale), to_network(im2, self.grayscale),
                np.ascontiguousarray(flow.transpose(2, 0, 1), np.float32), np.ascontiguousarray(valid, np.float32))
