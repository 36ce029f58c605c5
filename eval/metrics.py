"""APE and RPE of an estimated trajectory against ground truth, computed with evo (no file I/O).

* Association: evo's nearest-timestamp matching within ``EvalConfig.max_time_diff``.
* APE: translation part after SE(3) Umeyama alignment without scale correction, as in
  the TUM RGB-D benchmark's ATE.
* RPE: translation (m) and rotation angle (deg) over consecutive pairs ``rpe_delta_frames``
  frames apart, and over consecutive pairs 1 s apart. RPE does not depend on a global
  transform of either trajectory, so it uses the unaligned poses.

Inputs are never modified: evo's association returns copies, and alignment works on one.
"""

from __future__ import annotations

import copy
import logging
import math
from dataclasses import dataclass

import numpy as np
from evo.core import lie_algebra, sync
from evo.core.geometry import GeometryException
from evo.core.metrics import APE, PE, RPE, PoseRelation, StatisticsType, Unit
from evo.core.trajectory import PoseTrajectory3D

from osslam.config import ConfigError, EvalConfig
from osslam.errors import OsslamError
from osslam.trajectory_io import TumTrajectory

log = logging.getLogger(__name__)

STATISTICS = ("max", "mean", "median", "min", "rmse", "sse", "std")
METRICS = ("ape", "rpe_trans", "rpe_rot", "rpe_trans_per_second", "rpe_rot_per_second")
UNITS = {"ape": "m", "rpe_trans": "m", "rpe_rot": "deg", "rpe_trans_per_second": "m", "rpe_rot_per_second": "deg"}
ALIGNMENT = "SE(3) Umeyama alignment of the estimate to the ground truth, no scale correction"
RPE_DELTA_SECONDS = 1.0
TIME_TOLERANCE_S = 1e-4
MIN_ASSOCIATED_POSES = 3


class EvaluationError(OsslamError):
    """Trajectories that cannot be compared: no common timestamps, too few or degenerate poses."""


@dataclass
class TrajectoryErrors:
    """APE and RPE statistics of an estimate against ground truth, with the data behind them.

    ``stats`` maps each name of :data:`METRICS` to evo's statistics (:data:`STATISTICS`);
    a metric without any pose pair (trajectory shorter than its delta) has NaN statistics.
    ``ape_errors`` and ``timestamps`` hold the APE (m) and estimate timestamp of every
    associated pose; ``alignment`` is the 4x4 transform applied to the estimate.
    """

    stats: dict[str, dict[str, float]]
    ape_errors: np.ndarray
    timestamps: np.ndarray
    reference: PoseTrajectory3D
    aligned_estimate: PoseTrajectory3D
    alignment: np.ndarray
    n_reference: int
    n_estimate: int
    n_associated: int
    n_rpe_pairs: int
    n_rpe_pairs_per_second: int


def to_evo(trajectory: TumTrajectory) -> PoseTrajectory3D:
    """The same trajectory as evo's ``PoseTrajectory3D`` (quaternions reordered to w first)."""
    return PoseTrajectory3D(
        positions_xyz=trajectory.positions.copy(),
        orientations_quat_wxyz=trajectory.quaternions[:, [3, 0, 1, 2]],
        timestamps=trajectory.timestamps.copy(),
        name=trajectory.name or None,
    )


def associate(reference: PoseTrajectory3D, estimate: PoseTrajectory3D,
              max_diff: float) -> tuple[PoseTrajectory3D, PoseTrajectory3D]:
    """Copies of both trajectories reduced to the poses whose timestamps match within ``max_diff`` s."""
    try:
        return sync.associate_trajectories(reference, estimate, max_diff=max_diff)
    except sync.SyncException:
        raise EvaluationError(
            f"no estimated pose has a ground-truth pose within {max_diff} s "
            f"(estimate {estimate.timestamps[0]:.6f}..{estimate.timestamps[-1]:.6f}, "
            f"ground truth {reference.timestamps[0]:.6f}..{reference.timestamps[-1]:.6f})") from None


def align(reference: PoseTrajectory3D, estimate: PoseTrajectory3D) -> tuple[PoseTrajectory3D, np.ndarray]:
    """A copy of ``estimate`` moved onto ``reference`` by SE(3) Umeyama alignment, and the 4x4 transform used."""
    aligned = copy.deepcopy(estimate)
    try:
        rotation, translation, _ = aligned.align(reference, correct_scale=False)
    except GeometryException:
        raise EvaluationError("the associated positions are degenerate (all on one line or one point); "
                              "SE(3) alignment is not possible") from None
    return aligned, lie_algebra.se3(rotation, translation)


def all_statistics(metric: PE) -> dict[str, float]:
    """evo's statistics of a processed metric, as plain floats."""
    return {name: float(metric.get_statistic(StatisticsType(name))) for name in STATISTICS}


def _nan_statistics() -> dict[str, float]:
    """Statistics of a metric that has no data."""
    return dict.fromkeys(STATISTICS, math.nan)


def time_delta_ids(timestamps: np.ndarray, delta: float) -> list[int]:
    """Indices of a chain of poses, each the first at least ``delta`` seconds after the previous one.

    Consecutive entries form the pose pairs of a time-based RPE (evo's consecutive-pairs
    mode, with a tolerance of :data:`TIME_TOLERANCE_S` for rounding in the timestamps).
    """
    ids = [0]
    for i in range(1, len(timestamps)):
        if timestamps[i] - timestamps[ids[-1]] >= delta - TIME_TOLERANCE_S:
            ids.append(i)
    return ids


def relative_errors(reference: PoseTrajectory3D, estimate: PoseTrajectory3D,
                    delta_frames: int) -> tuple[dict[str, float], dict[str, float], int]:
    """RPE translation (m) and rotation (deg) statistics over consecutive pairs ``delta_frames`` apart, and the pair count."""
    if reference.num_poses <= delta_frames:
        return _nan_statistics(), _nan_statistics(), 0
    out = []
    for relation in (PoseRelation.translation_part, PoseRelation.rotation_angle_deg):
        rpe = RPE(relation, delta=delta_frames, delta_unit=Unit.frames, all_pairs=False)
        rpe.process_data((reference, estimate))
        out.append(all_statistics(rpe))
    return out[0], out[1], len(rpe.error)


def relative_errors_per_second(reference: PoseTrajectory3D, estimate: PoseTrajectory3D,
                               delta: float = RPE_DELTA_SECONDS) -> tuple[dict[str, float], dict[str, float], int]:
    """RPE translation (m) and rotation (deg) statistics over consecutive pairs ``delta`` seconds apart.

    evo 1.38 selects RPE pairs by frames, metres or angle only, so the pairs are chosen
    here with :func:`time_delta_ids` and evo's one-frame RPE runs on that chain of poses.
    """
    ids = time_delta_ids(estimate.timestamps, delta)
    ref_chain, est_chain = copy.deepcopy(reference), copy.deepcopy(estimate)
    ref_chain.reduce_to_ids(ids)
    est_chain.reduce_to_ids(ids)
    return relative_errors(ref_chain, est_chain, 1)


def compute_metrics(reference: PoseTrajectory3D, estimate: PoseTrajectory3D, cfg: EvalConfig) -> TrajectoryErrors:
    """Associate ``estimate`` with the ground truth ``reference`` and compute APE and RPE.

    Raises EvaluationError when no poses associate or too few (or degenerate) poses remain
    for alignment, and ConfigError for a non-positive ``rpe_delta_frames``.
    """
    if cfg.rpe_delta_frames < 1:
        raise ConfigError(f"eval.rpe_delta_frames must be at least 1, got {cfg.rpe_delta_frames}")
    ref, est = associate(reference, estimate, cfg.max_time_diff)
    if ref.num_poses < MIN_ASSOCIATED_POSES:
        raise EvaluationError(f"only {ref.num_poses} poses associate within {cfg.max_time_diff} s; "
                              f"at least {MIN_ASSOCIATED_POSES} are needed")
    aligned, alignment = align(ref, est)
    ape = APE(PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    rpe_trans, rpe_rot, n_pairs = relative_errors(ref, est, cfg.rpe_delta_frames)
    rpe_trans_s, rpe_rot_s, n_pairs_s = relative_errors_per_second(ref, est)
    for name, count in (("per-frame", n_pairs), ("per-second", n_pairs_s)):
        if count == 0:
            log.warning("the trajectory is too short for %s RPE; its statistics are NaN", name)
    log.info("evaluated %d associated poses (%d estimated, %d ground truth): APE RMSE %.4f m",
             ref.num_poses, estimate.num_poses, reference.num_poses, ape.get_statistic(StatisticsType.rmse))
    return TrajectoryErrors(
        stats={"ape": all_statistics(ape), "rpe_trans": rpe_trans, "rpe_rot": rpe_rot,
               "rpe_trans_per_second": rpe_trans_s, "rpe_rot_per_second": rpe_rot_s},
        ape_errors=np.asarray(ape.error, dtype=np.float64),
        timestamps=np.array(aligned.timestamps, dtype=np.float64),
        reference=ref,
        aligned_estimate=aligned,
        alignment=alignment,
        n_reference=reference.num_poses,
        n_estimate=estimate.num_poses,
        n_associated=ref.num_poses,
        n_rpe_pairs=n_pairs,
        n_rpe_pairs_per_second=n_pairs_s,
    )
