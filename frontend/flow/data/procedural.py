"""Procedurally generated pairs in the spirit of AutoFlow: textured layers under random affine motions, exact flow."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .sample import FlowSample


@dataclass
class ProceduralConfig:
    """Image size (H, W), how many foreground layers, and the motion ranges (pixels, degrees, relative scale)."""

    size: list[int] = field(default_factory=lambda: [192, 256])
    layers: list[int] = field(default_factory=lambda: [1, 5])
    background_translation: float = 10.0
    layer_translation: float = 16.0
    rotation_deg: float = 4.0
    scale: float = 0.06
    noise: float = 3.0  # grey-level noise standard deviation
    blur: float = 0.5  # probability of a Gaussian blur on the pair


def texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A random colour texture (H, W, 3) uint8: multi-scale noise, flat patches, shapes and lines."""
    base = np.zeros((h, w), np.float32)
    for cells in (2, 6, 20, 60):
        grid = rng.uniform(-1, 1, (max(2, cells * h // w), cells)).astype(np.float32)
        base += rng.uniform(0, 1) * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
    base = (base - base.min()) / max(float(np.ptp(base)), 1e-6)
    c0, c1 = rng.uniform(0, 255, 3), rng.uniform(0, 255, 3)
    tex = (c0 + base[..., None] * (c1 - c0)).astype(np.float32)
    for _ in range(int(rng.integers(5, 40))):
        colour = tuple(float(v) for v in rng.uniform(0, 255, 3))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        s = int(rng.integers(3, max(4, w // 6)))
        kind = rng.random()
        if kind < 0.4:
            cv2.rectangle(tex, (x, y), (x + s, y + int(rng.integers(3, s + 4))), colour, -1)
        elif kind < 0.7:
            cv2.circle(tex, (x, y), s // 2, colour, -1)
        else:
            cv2.line(tex, (x, y), (int(rng.integers(0, w)), int(rng.integers(0, h))), colour, int(rng.integers(1, 4)))
    return np.clip(tex, 0, 255).astype(np.uint8)


def _shape_mask(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A random filled ellipse or polygon (H, W) bool, somewhere in the frame."""
    mask = np.zeros((h, w), np.uint8)
    cx, cy = rng.uniform(0.1 * w, 0.9 * w), rng.uniform(0.1 * h, 0.9 * h)
    radius = rng.uniform(0.08, 0.3) * min(h, w)
    if rng.random() < 0.5:
        axes = (int(radius), int(radius * rng.uniform(0.4, 1.0)))
        cv2.ellipse(mask, (int(cx), int(cy)), axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    else:
        n = int(rng.integers(3, 8))
        angles = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = radius * rng.uniform(0.5, 1.2, n)
        pts = np.column_stack([cx + r * np.cos(angles), cy + r * np.sin(angles)]).astype(np.int32)
        cv2.fillPoly(mask, [pts], 1)
    if mask.sum() < 16:  # a degenerate polygon: a disc instead
        cv2.circle(mask, (int(cx), int(cy)), max(4, int(radius)), 1, -1)
    return mask.astype(bool)


def _affine(rng: np.random.Generator, centre: np.ndarray, translation: float, cfg: ProceduralConfig) -> np.ndarray:
    """A random 2x3 similarity about ``centre`` with translation up to ``translation`` px."""
    angle = np.radians(rng.uniform(-cfg.rotation_deg, cfg.rotation_deg))
    s = 1 + rng.uniform(-cfg.scale, cfg.scale)
    R = s * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    t = rng.uniform(-translation, translation, 2) * rng.uniform(0, 1) ** 0.5
    return np.hstack([R, (centre - R @ centre + t)[:, None]])


def procedural_pair(rng: np.random.Generator, cfg: ProceduralConfig) -> FlowSample:
    """One pair: a background and random textured shapes, each moving by its own similarity transform."""
    h, w = cfg.size
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    layers = [(texture(rng, h, w), np.ones((h, w), bool), cfg.background_translation)]
    for _ in range(int(rng.integers(cfg.layers[0], cfg.layers[1] + 1))):
        layers.append((texture(rng, h, w), _shape_mask(rng, h, w), cfg.layer_translation))
    image1 = np.zeros((h, w, 3), np.uint8)
    image2 = np.zeros((h, w, 3), np.uint8)
    flow = np.zeros((h, w, 2), np.float32)
    for k, (tex, mask, translation) in enumerate(layers):
        centre = np.array([xs[mask].mean(), ys[mask].mean()])
        A = _affine(rng, centre, translation, cfg)
        border = cv2.BORDER_REFLECT if k == 0 else cv2.BORDER_CONSTANT
        moved = cv2.warpAffine(tex, A, (w, h), flags=cv2.INTER_LINEAR, borderMode=border)
        moved_mask = cv2.warpAffine(mask.astype(np.uint8), A, (w, h), flags=cv2.INTER_NEAREST) > 0
        image1[mask] = tex[mask]
        image2[moved_mask] = moved[moved_mask]
        flow[mask, 0] = (A[0, 0] * xs + A[0, 1] * ys + A[0, 2] - xs)[mask]
        flow[mask, 1] = (A[1, 0] * xs + A[1, 1] * ys + A[1, 2] - ys)[mask]
    image1, image2 = _degrade(rng, image1, cfg), _degrade(rng, image2, cfg)
    return FlowSample(image1, image2, flow, np.ones((h, w), bool))


def _degrade(rng: np.random.Generator, image: np.ndarray, cfg: ProceduralConfig) -> np.ndarray:
    """Sensor-like noise and, sometimes, a blur."""
    out = image.astype(np.float32)
    if rng.random() < cfg.blur:
        out = cv2.GaussianBlur(out, (0, 0), rng.uniform(0.5, 1.5))
    out += rng.normal(0, cfg.noise, out.shape)
    return np.clip(out, 0, 255).astype(np.uint8)


class ProceduralPairs:
    """An endless, reproducible stream of procedural pairs: item ``i`` depends only on ``seed`` and ``i``."""

    def __init__(self, cfg: ProceduralConfig, seed: int = 0, length: int = 100_000):
        self.cfg = cfg
        self.seed = seed
        self.length = length

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, i: int) -> FlowSample:
        return procedural_pair(np.random.default_rng([self.seed, i]), self.cfg)
