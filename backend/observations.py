"""One landmark observation, and the validation of a keyframe's raw observation arrays."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from osslam.config import BackendConfig

from .types import KeyframeObservations

log = logging.getLogger(__name__)

#: GTSAM symbol keys hold the index in 56 bits.
_MAX_ID = 1 << 56


@dataclass(frozen=True)
class Observation:
    """A landmark seen in a keyframe: undistorted pixel, depth (NaN when missing), noise scale."""

    keyframe_id: int
    landmark_id: int
    u: float
    v: float
    depth: float
    sigma_scale: float

    @property
    def has_depth(self) -> bool:
        """Whether the observation carries a depth measurement."""
        return not math.isnan(self.depth)


def valid_observations(obs: KeyframeObservations, cfg: BackendConfig) -> list[Observation]:
    """The usable observations of a keyframe, in input order.

    Drops observations with a non-finite pixel, a non-finite or non-positive noise scale,
    a landmark id outside [0, 2**56), or a landmark already validly observed earlier in the keyframe.
    Depths that are non-finite or outside ``[cfg.min_depth, cfg.max_depth]`` become
    missing (NaN), turning the observation monocular.
    """
    ids = np.asarray(obs.landmark_ids, dtype=np.int64).reshape(-1)
    n = len(ids)
    uv = np.asarray(obs.uv, dtype=np.float64).reshape(n, 2)
    depth = np.asarray(obs.depth, dtype=np.float64).reshape(n)
    scale = np.asarray(obs.sigma_scale, dtype=np.float64).reshape(n)
    keep = np.isfinite(uv).all(axis=1) & np.isfinite(scale) & (scale > 0) & (ids >= 0) & (ids < _MAX_ID)
    valid = np.flatnonzero(keep)
    _, first = np.unique(ids[valid], return_index=True)
    keep[:] = False
    keep[valid[first]] = True
    if not keep.all():
        log.debug("keyframe %d: dropped %d invalid observations", obs.keyframe_id, int(n - keep.sum()))
    with np.errstate(invalid="ignore"):
        has_depth = np.isfinite(depth) & (depth >= cfg.min_depth) & (depth <= cfg.max_depth)
    depth = np.where(has_depth, depth, np.nan)
    kf = int(obs.keyframe_id)
    return [Observation(kf, lid, u, v, d, s)
            for lid, (u, v), d, s in zip(ids[keep].tolist(), uv[keep].tolist(), depth[keep].tolist(),
                                         scale[keep].tolist())]
