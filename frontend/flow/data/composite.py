"""Ground-truth flow of ``osslam synth`` composites: the real scene's rigid flow plus the movers' own motion."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import yaml

from osslam.datasets.association import read_file_list
from osslam.datasets.composite import INFO_FILE, CompositeConfig, Mover, make_movers
from osslam.datasets.tum import TumSequence
from osslam.errors import InputError
from osslam.types import Frame

from .rigid import RigidFlowPairs, SceneMotion

#: How far (metres) a point may lie outside a mover's box and still count as on it (depth quantisation, noise).
MEMBER_TOL = 0.01


def composite_movers(sequence: TumSequence) -> list[Mover]:
    """The movers of a composite folder, rebuilt from its ``synth.yaml`` (boxes only; a person needs its photo)."""
    info_file = sequence.path / INFO_FILE
    if not info_file.is_file():
        raise InputError(info_file, "not found: the folder is not a composite written by osslam synth")
    try:
        info = yaml.safe_load(info_file.read_text())
        cfg = CompositeConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in info["config"].items()})
    except (yaml.YAMLError, KeyError, TypeError) as exc:
        raise InputError(info_file, f"corrupt composite description ({exc})") from None
    first = next((sequence.groundtruth.pose_at(float(t)) for t in sequence.timestamps
                  if sequence.groundtruth.pose_at(float(t)) is not None), None)
    if first is None:
        raise InputError(sequence.path, "no frame has a ground-truth pose")
    return make_movers(first, cfg, None)


def _on_mover(mover: Mover, world: np.ndarray, t: float) -> np.ndarray:
    """Which world points (N, 3) lie on ``mover`` at time ``t``."""
    local = (world - mover.position(t)) @ mover.R
    return np.all(np.abs(local) <= mover.half_extent + MEMBER_TOL, axis=1)


def mover_motion(movers: list[Mover], t0: float) -> Callable[[Frame, Frame], SceneMotion]:
    """For a frame pair, the motion that carries points on a mover along with it (times relative to ``t0``)."""

    def of(a: Frame, b: Frame) -> SceneMotion:
        t1, t2 = a.timestamp - t0, b.timestamp - t0
        mask = a.gt_mask

        def move(pix: np.ndarray, world: np.ndarray) -> np.ndarray:
            out = world.copy()
            if mask is None:
                return out
            candidates = mask[pix[:, 1].astype(int), pix[:, 0].astype(int)]
            unexplained = candidates.copy()
            for mover in movers:
                on = candidates & _on_mover(mover, world, t1)
                out[on] += mover.position(t2) - mover.position(t1)
                unexplained &= ~on
            out[unexplained] = np.nan  # a mover we cannot rebuild (a person): no ground truth there
            return out

        return move

    return of


def composite_flow_pairs(sequence: TumSequence, gaps: tuple[int, ...] = (1,)) -> RigidFlowPairs:
    """Flow pairs of a composite, movers included (pixels of movers that cannot be rebuilt are invalid)."""
    movers = composite_movers(sequence)
    t0 = float(read_file_list(sequence.path / "rgb.txt").timestamps[0])  # the movers' time origin
    return RigidFlowPairs(sequence, gaps, motion_of=mover_motion(movers, t0))
