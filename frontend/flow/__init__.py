"""Dense optical flow between consecutive frames behind one interface.

``make_flow_estimator(cfg)`` returns the configured backend: ``dis`` (OpenCV's DIS, no
weights needed) or ``learned`` (the multi-scale RAFT-style network of paper §3.2, with
bundled weights or a file from ``osslam flow train``).
"""

from __future__ import annotations

from osslam.config import FlowConfig
from osslam.errors import OsslamError

from .base import FlowEstimator, FlowField, forward_backward_valid

__all__ = ["FlowEstimator", "FlowField", "forward_backward_valid", "make_flow_estimator"]


def make_flow_estimator(cfg: FlowConfig) -> FlowEstimator:
    """The flow backend named by ``cfg.backend``."""
    if cfg.backend == "dis":
        from .dis import DisFlow

        return DisFlow(cfg)
    if cfg.backend == "learned":
        from .learned import LearnedFlow

        return LearnedFlow(cfg)
    raise OsslamError(f"flow.backend '{cfg.backend}' unknown (dis, learned)")
