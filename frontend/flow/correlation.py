"""RAFT's all-pairs correlation pyramid, looked up in a local window around each pixel's flow target."""

from __future__ import annotations

import torch
import torch.nn.functional as F

#: Pixels looked up together (each gathers (2r+2)^2 x D values): on the CPU about cache-sized, elsewhere fewer, larger.
CHUNK_CPU, CHUNK_OTHER = 512, 16384


class CorrPyramid:
    """Correlation of every pixel of ``f1`` with every pixel of ``f2``, pooled into ``levels`` levels.

    Level l of RAFT's pyramid averages the all-pairs volume over 2^l x 2^l blocks of
    ``f2``; since correlation is linear in ``f2`` this equals correlating ``f1`` with
    ``f2`` average-pooled 2^l times, so only the entries a look-up needs are computed,
    never the whole volume. All taps of a pixel's window share the sub-pixel part of its
    centre, so a look-up correlates at the (2r+2)^2 integer positions around it and
    interpolates those bilinearly: exactly RAFT's values (zero outside the image).
    """

    def __init__(self, f1: torch.Tensor, f2: torch.Tensor, levels: int, radius: int):
        b, d, h, w = f1.shape
        self.f1 = (f1 / d ** 0.5).permute(0, 2, 3, 1).reshape(b * h * w, 1, d).contiguous()
        self.radius = radius
        self.pad = 2 * radius + 2  # zero border: a centre clamped into [-(r+2), W+r] sees only zeros beyond the image
        self.chunk = CHUNK_CPU if f1.device.type == "cpu" else CHUNK_OTHER
        self.levels: list[tuple[int, int, torch.Tensor, torch.Tensor]] = []  # per level: H, W, strips, window
        level = f2
        for i in range(levels):
            if i:
                level = F.avg_pool2d(level, 2, stride=2)
            hl, wl = level.shape[-2:]
            padded = F.pad(level, (self.pad,) * 4)
            rows = padded.permute(0, 2, 3, 1).reshape(-1, d).contiguous()  # (B * Hp * Wp, D)
            # each entry: 2r+2 consecutive rows of ``rows`` (one row of a window), an overlapping view
            strips = rows.as_strided((rows.shape[0] - 2 * radius - 1, (2 * radius + 2) * d), (d, 1))
            r = torch.arange(-radius, radius + 2, device=f1.device)
            window = r * padded.shape[-1] - radius  # the strip of each window row, top to bottom
            self.levels.append((hl, wl, strips, window))

    @property
    def channels(self) -> int:
        """Number of correlation values per pixel a look-up returns."""
        return len(self.levels) * (2 * self.radius + 1) ** 2

    def __call__(self, coords: torch.Tensor) -> torch.Tensor:
        """Correlations (B, levels * (2r+1)^2, H, W) around target positions ``coords`` (B, 2, H, W), x first.

        Taps are ordered row by row (dy outer, dx inner), levels one after the other; the
        result is laid out channels-last.
        """
        b, _, h, w = coords.shape
        n, r, s = h * w, self.radius, 2 * self.radius + 2
        out = []
        for level, (hl, wl, strips, window) in enumerate(self.levels):
            centre = coords.permute(0, 2, 3, 1).reshape(b * n, 2) / 2 ** level
            base = centre.floor()
            frac = centre - base
            bx = base[:, 0].clamp(-(r + 2), wl + r).long() + self.pad
            by = base[:, 1].clamp(-(r + 2), hl + r).long() + self.pad
            hp, wp = hl + 2 * self.pad, wl + 2 * self.pad
            image = torch.arange(b, device=coords.device).repeat_interleave(n) * (hp * wp)
            start = image + by * wp + bx  # each pixel's window origin in ``rows``
            corr = torch.empty(b * n, s * s, dtype=self.f1.dtype, device=self.f1.device)
            for i in range(0, b * n, self.chunk):
                j = i + self.chunk
                taps = strips.index_select(0, (start[i:j, None] + window).reshape(-1)).view(-1, s * s, self.f1.shape[2])
                corr[i:j] = torch.matmul(self.f1[i:j], taps.transpose(1, 2)).squeeze(1)
            corr = corr.view(b * n, s, s)
            fx, fy = frac[:, 0].view(-1, 1, 1), frac[:, 1].view(-1, 1, 1)
            corr = torch.lerp(corr[..., :-1], corr[..., 1:], fx)
            corr = torch.lerp(corr[:, :-1], corr[:, 1:], fy)
            out.append(corr.reshape(b, n, -1))
        return torch.cat(out, dim=-1).view(b, h, w, -1).permute(0, 3, 1, 2)
