"""RAFT's all-pairs correlation pyramid, looked up in a local window around each pixel's flow target."""

from __future__ import annotations

import torch
import torch.nn.functional as F


class CorrPyramid:
    """Correlation of every pixel of ``f1`` with every pixel of ``f2``, pooled into ``levels`` levels.

    Level l of RAFT's pyramid averages the all-pairs volume over 2^l x 2^l blocks of
    ``f2``; since correlation is linear in ``f2`` this equals correlating ``f1`` with
    ``f2`` average-pooled 2^l times, so only the (2r+1)^2 entries a look-up needs are
    computed, never the whole volume. Look-ups return exactly RAFT's values.
    """

    def __init__(self, f1: torch.Tensor, f2: torch.Tensor, levels: int, radius: int):
        b, d, h, w = f1.shape
        self.f1 = (f1 / d ** 0.5).reshape(b, d, h * w, 1)
        self.levels = [f2]
        for _ in range(levels - 1):
            self.levels.append(F.avg_pool2d(self.levels[-1], 2, stride=2))
        self.radius = radius
        r = torch.arange(-radius, radius + 1, dtype=f1.dtype, device=f1.device)
        dy, dx = torch.meshgrid(r, r, indexing="ij")
        self.delta = torch.stack([dx, dy], dim=-1).reshape(1, 1, -1, 2)  # (1, 1, K, 2), x first

    @property
    def channels(self) -> int:
        """Number of correlation values per pixel a look-up returns."""
        return len(self.levels) * (2 * self.radius + 1) ** 2

    def __call__(self, coords: torch.Tensor) -> torch.Tensor:
        """Correlations (B, levels * (2r+1)^2, H, W) around target positions ``coords`` (B, 2, H, W), x first."""
        b, _, h, w = coords.shape
        centre = coords.permute(0, 2, 3, 1).reshape(b, h * w, 1, 2)
        out = []
        for level, f2 in enumerate(self.levels):
            hl, wl = f2.shape[-2:]
            pos = centre / 2 ** level + self.delta
            grid = torch.stack([2 * pos[..., 0] / max(wl - 1, 1) - 1, 2 * pos[..., 1] / max(hl - 1, 1) - 1], dim=-1)
            sampled = F.grid_sample(f2, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
            out.append((self.f1 * sampled).sum(dim=1))  # (B, HW, K)
        corr = torch.cat(out, dim=-1)
        return corr.permute(0, 2, 1).reshape(b, -1, h, w)
