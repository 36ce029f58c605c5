"""The multi-scale sequence loss of paper §3.2.3: EPE form for pre-training, robust (|x|+eps)^q form for fine-tuning."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .network import FlowPrediction


@dataclass
class LossConfig:
    """Which form, the step decay ``gamma``, and whether every scale or only the finest is supervised.

    ``kind``: ``epe`` (L2 norm of the error) or ``robust`` ((|error|_1 + ``eps``)^``q``).
    Pixels whose ground truth exceeds ``max_flow`` pixels are ignored. Weight decay
    (the paper's gamma * ||theta||^2) is the optimiser's.
    """

    kind: str = "epe"
    gamma: float = 0.8
    multiscale: bool = True
    q: float = 0.7
    eps: float = 0.01
    max_flow: float = 400.0

    def __post_init__(self):
        if self.kind not in ("epe", "robust"):
            raise ValueError(f"loss.kind '{self.kind}' unknown (epe, robust)")


def pixel_error(pred: torch.Tensor, gt: torch.Tensor, cfg: LossConfig) -> torch.Tensor:
    """Per-pixel penalty (B, H, W) of a predicted flow against the ground truth."""
    diff = pred - gt
    if cfg.kind == "epe":
        return torch.sqrt((diff ** 2).sum(dim=1) + 1e-8)
    return (diff.abs().sum(dim=1) + cfg.eps) ** cfg.q


def sequence_loss(preds: list[FlowPrediction], gt: torch.Tensor, valid: torch.Tensor, cfg: LossConfig) -> torch.Tensor:
    """Sum over the supervised steps i = 1..N of gamma^(N-i) times the mean valid-pixel penalty.

    With ``multiscale`` every step of every scale counts; otherwise only the steps of the
    finest scale.
    """
    finest = preds[-1].stride
    steps = preds if cfg.multiscale else [p for p in preds if p.stride == finest]
    mask = (valid > 0.5) & (gt.norm(dim=1) < cfg.max_flow)
    weight = mask.float()
    denom = weight.sum().clamp(min=1.0)
    n = len(steps)
    total = gt.new_zeros(())
    for i, step in enumerate(steps):
        total = total + cfg.gamma ** (n - 1 - i) * (pixel_error(step.flow, gt, cfg) * weight).sum() / denom
    return total
