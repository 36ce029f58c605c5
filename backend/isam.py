"""The incremental back-end: one iSAM2 update per keyframe, outlier culling, failure recovery."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from osslam.config import BackendConfig
from osslam.geometry import invert
from osslam.types import CameraIntrinsics

from .batch import Batch
from .factors import FactorFactory, to_pose3
from .landmarks import LandmarkBook
from .observations import Observation, valid_observations
from .reprojection import backproject, camera_depths, reprojection_chi2
from .solver import IncrementalSolver, isam2_params, offending_key
from .types import BackendUpdate, GraphEstimate, KeyframeObservations

log = logging.getLogger(__name__)

#: Rebuild attempts after a failed update; the last one keeps only the pose graph.
_MAX_RECOVERY_ATTEMPTS = 4


@dataclass
class _Outcome:
    """What happened to the graph during one call, for the BackendUpdate."""

    retired: list[int] = field(default_factory=list)
    outliers: list[tuple[int, int]] = field(default_factory=list)
    ok: bool = True


class IsamBackend:
    """RGB-D bundle adjustment over keyframe poses and landmarks with GTSAM's iSAM2.

    Variables are ``x<keyframe id>`` (``Pose3``, camera to world) and ``l<landmark id>``
    (``Point3``). The first keyframe gets a tight prior, every later one a loose odometry
    factor to its predecessor, so no keyframe is ever undetermined. A landmark enters the
    graph once it has ``cfg.min_observations`` observations, one with depth; its initial
    position is re-triangulated from its most recent depth observation through the current
    estimate of that keyframe (the front-end's ``new_landmarks`` position is not used).
    After each update the observations of the landmarks seen by the new keyframe are
    checked against chi-square thresholds (without the robust loss); outlier factors are
    removed in the next iSAM2 update of the same call, and a landmark with
    ``cfg.max_bad_observations`` outliers, or left without a depth observation or with fewer
    than ``cfg.min_observations`` observations, is retired (all its factors removed; iSAM2
    then drops the variable). A failed iSAM2 update is recovered by rebuilding the solver
    without the landmark GTSAM names (or without the new observations, or with the pose
    graph only) and reported with ``ok=False``.

    Each keyframe costs one iSAM2 update that eliminates the new pose last, plus, every
    ``cfg.relinearize_skip`` keyframes, ``cfg.extra_updates`` relinearising updates (the first
    also removes the culled factors; a removal-only update runs otherwise when needed).

    Example::

        backend = IsamBackend(intrinsics, config.backend, config.tracking.virtual_baseline)
        update = backend.add_keyframe(observations)
        ...
        final = backend.finish()
    """

    def __init__(self, intrinsics: CameraIntrinsics, cfg: BackendConfig, virtual_baseline: float):
        self.intrinsics = intrinsics
        self.cfg = cfg
        self._factory = FactorFactory(intrinsics, cfg, virtual_baseline)
        self._solver = IncrementalSolver(isam2_params(cfg))
        self._book = LandmarkBook()
        self._keyframes: list[int] = []
        self._poses: dict[int, np.ndarray] = {}
        self._points: dict[int, np.ndarray] = {}
        self._suspects: list[int] = []

    # ------------------------------------------------------------------ public API

    @property
    def n_landmarks(self) -> int:
        """Number of landmarks in the graph."""
        return self._book.n_landmarks

    @property
    def n_factors(self) -> int:
        """Number of factors in the graph."""
        return self._solver.n_factors

    @property
    def keyframe_ids(self) -> list[int]:
        """Ids of the keyframes in the graph, in insertion order."""
        return list(self._keyframes)

    def in_graph(self, lid: int) -> bool:
        """Whether a landmark is currently a variable of the graph."""
        return self._book.in_graph(lid)

    def pose(self, kf_id: int) -> np.ndarray | None:
        """Current estimate of a keyframe's ``T_world_camera``, or None if it is not in the graph."""
        return self._solver.pose(X(kf_id)) if kf_id in self._poses else None

    def landmark(self, lid: int) -> np.ndarray | None:
        """Current estimate of a landmark's world position, or None if it is not in the graph."""
        return self._solver.point(L(lid)) if self._book.in_graph(lid) else None

    def estimate(self) -> GraphEstimate:
        """The current estimate of every pose and landmark in the graph."""
        poses = {kf: self._solver.pose(X(kf)) for kf in self._keyframes}
        landmarks = {lid: self._solver.point(L(lid)) for lid in self._book.landmark_ids()}
        return GraphEstimate(poses, landmarks)

    def add_keyframe(self, obs: KeyframeObservations) -> BackendUpdate:
        """Add a keyframe with its observations, optimise, cull outliers; return the new estimate."""
        start = time.perf_counter()
        kf = int(obs.keyframe_id)
        if self._keyframes and kf <= self._keyframes[-1]:
            raise ValueError(f"keyframe ids must increase: {kf} after {self._keyframes[-1]}")
        seq = len(self._keyframes)
        outcome = _Outcome()
        pose = self._checked_pose(obs.pose_guess, kf)
        moving = self._retire_moving(obs.moving_landmarks, outcome)
        batch = self._pose_batch(kf, pose)
        self._add_observations(valid_observations(obs, self.cfg), pose, seq, batch)
        self._book.prune_pending(seq, self.cfg.pending_max_age)
        self._commit(batch, moving, outcome, last_keys=[X(kf)])
        self._keyframes.append(kf)
        remove = self._cull(batch.landmarks(), outcome)
        relinearizations = self.cfg.extra_updates if seq % max(self.cfg.relinearize_skip, 1) == 0 else 0
        for i in range(max(relinearizations, 1 if remove else 0)):
            self._commit(Batch(), remove if i == 0 else [], outcome, relinearize=i < relinearizations)
        window = self._keyframes[-self.cfg.report_window:] if self.cfg.report_window > 0 else []
        return self._report(self._book.landmarks_seen_by(window), outcome, start)

    def finish(self) -> BackendUpdate:
        """Run ``cfg.finish_iterations`` full relinearising updates; report every pose and landmark."""
        start = time.perf_counter()
        outcome = _Outcome()
        for _ in range(self.cfg.finish_iterations):
            self._commit(Batch(), [], outcome, relinearize=True, full_solve=True)
        return self._report(self._book.landmark_ids(), outcome, start)

    # ------------------------------------------------------------------ building the update

    def _checked_pose(self, T: np.ndarray, kf: int) -> np.ndarray:
        """The pose guess with an exact rotation; the previous pose if the guess is unusable."""
        T = np.asarray(T, dtype=np.float64)
        if T.shape == (4, 4) and np.isfinite(T).all() and np.linalg.det(T[:3, :3]) > 0.5:
            return to_pose3(T).matrix()
        log.warning("keyframe %d: invalid pose guess, using the previous keyframe's pose", kf)
        return self._poses[self._keyframes[-1]].copy() if self._keyframes else np.eye(4)

    def _pose_batch(self, kf: int, pose: np.ndarray) -> Batch:
        """A batch with the new pose and its prior (first keyframe) or odometry factor."""
        batch = Batch()
        batch.poses[kf] = to_pose3(pose)
        if not self._keyframes:
            batch.add(self._factory.pose_prior(X(kf), batch.poses[kf]))
        else:
            prev = self._keyframes[-1]
            batch.add(self._factory.odometry(X(prev), X(kf), to_pose3(invert(self._poses[prev]) @ pose)))
        return batch

    def _add_observations(self, observations: list[Observation], pose: np.ndarray, seq: int, batch: Batch) -> None:
        """Route the new keyframe's observations: factors for landmarks in the graph, else the buffer.

        Observations of retired landmarks are ignored, and so are those of landmarks in the
        graph that lie less than ``min_depth`` in front of the new camera.
        """
        known = [o for o in observations if self._book.in_graph(o.landmark_id)]
        if known:
            points = np.array([self._points[o.landmark_id] for o in known])
            ahead = camera_depths(np.broadcast_to(pose, (len(known), 4, 4)), points) >= self.cfg.min_depth
            for o, ok in zip(known, ahead.tolist()):
                if ok:
                    batch.add(self._factory.observation(o, X(o.keyframe_id), L(o.landmark_id)), o)
        for o in observations:
            lid = o.landmark_id
            if self._book.in_graph(lid) or self._book.is_retired(lid):
                continue
            pending = self._book.buffer(o, seq)
            if len(pending) >= self.cfg.min_observations and any(p.has_depth for p in pending):
                self._insert_landmark(lid, pose, o.keyframe_id, seq, batch)

    def _insert_landmark(self, lid: int, pose: np.ndarray, kf: int, seq: int, batch: Batch) -> None:
        """Move a buffered landmark into the batch: its value and the observations that see it ahead.

        The position is back-projected from the most recent depth observation; observations
        from keyframes that would see it less than ``min_depth`` ahead are dropped. With too
        few left the rest goes back into the buffer.
        """
        pending = self._book.take_pending(lid)
        poses = np.stack([pose if p.keyframe_id == kf else self._poses[p.keyframe_id] for p in pending])
        anchor = max(i for i, p in enumerate(pending) if p.has_depth)
        a = pending[anchor]
        point = backproject(poses[anchor], a.u, a.v, a.depth, self.intrinsics)
        ahead = camera_depths(poses, np.broadcast_to(point, (len(pending), 3))) >= self.cfg.min_depth
        ahead[anchor] = True
        usable = [p for p, ok in zip(pending, ahead.tolist()) if ok]
        if len(usable) < self.cfg.min_observations:
            for p in usable:
                self._book.buffer(p, seq)
            return
        batch.points[lid] = point
        for p in usable:
            batch.add(self._factory.observation(p, X(p.keyframe_id), L(lid)), p)

    def _inliers(self, T_wc: np.ndarray, points: np.ndarray, measured: np.ndarray, scale: np.ndarray) -> np.ndarray:
        """Which observations pass the chi-square test and see their point at least ``min_depth`` ahead.

        ``T_wc`` (N, 4, 4), ``points`` (N, 3), ``measured`` (N, 3) rows of (u, v, depth) with
        depth NaN when missing, ``scale`` (N,) noise scales.
        """
        fxb = self._factory.fx_baseline
        stereo = np.column_stack([measured[:, 0], measured[:, 1], measured[:, 0] - fxb / measured[:, 2]])
        chi2 = reprojection_chi2(T_wc, points, stereo, self.cfg.pixel_sigma * scale, self.intrinsics, fxb)
        threshold = np.where(np.isnan(measured[:, 2]), self.cfg.chi2_threshold_mono, self.cfg.chi2_threshold)
        return (chi2 <= threshold) & (camera_depths(T_wc, points) >= self.cfg.min_depth)

    # ------------------------------------------------------------------ solving

    def _commit(self, batch: Batch, remove: list[int], outcome: _Outcome, last_keys: list[int] = (),
                relinearize: bool = False, full_solve: bool = False) -> None:
        """Run one iSAM2 update; on failure rebuild the solver and mark the outcome not ok."""
        try:
            indices = self._solver.update(batch.factors, batch.values(), remove, last_keys, relinearize, full_solve)
        except Exception as exc:  # GTSAM raises RuntimeError (indeterminant system), ValueError, ...
            log.warning("iSAM2 update failed, recovering: %s", " ".join(str(exc).split())[:200])
            outcome.ok = False
            batch, indices = self._recover(batch, remove, exc, outcome)
        for index, obs in zip(indices, batch.observations):
            if obs is not None:
                self._book.add_factor(index, obs)
        self._points.update(batch.points)
        self._poses.update({kf: p.matrix() for kf, p in batch.poses.items()})

    def _recover(self, batch: Batch, remove: list[int], exc: Exception,
                 outcome: _Outcome) -> tuple[Batch, list[int]]:
        """Rebuild the solver without what made it fail; returns the batch that went in and its indices.

        Each attempt drops the landmark the exception names; without such a name it drops the
        batch's observations, and the last attempt keeps only the pose graph (landmarks leave
        the graph unretired and re-enter through the buffer when observed again).
        """
        drop = set(remove)
        for attempt in range(_MAX_RECOVERY_ATTEMPTS):
            last = attempt == _MAX_RECOVERY_ATTEMPTS - 1
            key = offending_key(exc)
            if not last and key is not None and chr(key.chr()) == "l":
                lid = int(key.index())
                batch = batch.without_landmark(lid)
                drop.update(self._book.retire(lid))
                self._points.pop(lid, None)
                outcome.retired.append(lid)
            elif not last and batch.landmarks():
                batch = batch.without_observations()
            else:
                drop.update(self._book.factor_indices())
                self._book.forget_all()
                self._points.clear()
                batch = batch.without_observations()
            keep = [i for i in self._solver.factor_indices() if i not in drop]
            values = self._current_values()
            values.insert(batch.values())
            try:
                old_to_new, indices = self._solver.rebuild(keep, batch.factors, values)
            except Exception as err:  # same as in _commit
                log.warning("rebuild attempt %d failed: %s", attempt + 1, " ".join(str(err).split())[:200])
                exc = err
                continue
            self._book.remap(old_to_new)
            return batch, indices
        raise RuntimeError("the back-end could not be rebuilt even as a pose graph") from exc

    def _current_values(self) -> gtsam.Values:
        """The latest known estimate of every variable in the graph."""
        values = gtsam.Values()
        for kf in self._keyframes:
            values.insert(X(kf), to_pose3(self._poses[kf]))
        for lid in self._book.landmark_ids():
            values.insertPoint3(L(lid), self._points[lid])
        return values

    # ------------------------------------------------------------------ culling and reporting

    def _retire_moving(self, landmarks: np.ndarray, outcome: _Outcome) -> list[int]:
        """Retire landmarks seen on moving objects; returns the factor indices to remove."""
        remove: list[int] = []
        for lid in np.unique(landmarks).tolist():
            if self._book.is_retired(lid):
                continue
            remove.extend(self._book.retire(lid))
            self._points.pop(lid, None)
            outcome.retired.append(lid)
        return remove

    def _cull(self, landmarks: list[int], outcome: _Outcome) -> list[int]:
        """Find outlier observations of ``landmarks``; returns the factor indices to remove.

        A landmark is retired when it reaches ``max_bad_observations`` outliers or no longer
        meets the entry condition (``min_observations`` observations, one with depth);
        landmarks that lose an observation but stay are checked again at the next keyframe.
        """
        checked = list(dict.fromkeys(landmarks + self._suspects))
        indices = np.array([i for lid in checked for i in self._book.factors_of(lid)], dtype=np.int64)
        self._suspects = []
        if not len(indices):
            return []
        kfs, lids, measured, scale = self._book.factor_arrays(indices)
        unique_kfs, kf_row = np.unique(kfs, return_inverse=True)
        unique_lids, lid_row = np.unique(lids, return_inverse=True)
        poses = np.stack([self._solver.pose(X(int(k))) for k in unique_kfs])
        points = np.stack([self._solver.point(L(int(lid))) for lid in unique_lids])
        inliers = self._inliers(poses[kf_row], points[lid_row], measured, scale)
        remove: list[int] = []
        outlier_counts: dict[int, int] = {}
        for index in indices[~inliers].tolist():
            kf, lid = self._book.remove_factor(index)
            remove.append(index)
            outcome.outliers.append((kf, lid))
            outlier_counts[lid] = self._book.record_outlier(lid)
        for lid, count in outlier_counts.items():
            if count >= self.cfg.max_bad_observations or not self._book.has_depth_factor(lid) or \
                    len(self._book.factors_of(lid)) < self.cfg.min_observations:
                remove.extend(self._book.retire(lid))
                self._points.pop(lid, None)
                outcome.retired.append(lid)
            else:
                self._suspects.append(lid)
        return remove

    def _report(self, landmarks: list[int], outcome: _Outcome, start: float) -> BackendUpdate:
        """Read back the estimate, refresh the caches and package a BackendUpdate."""
        poses = {kf: self._solver.pose(X(kf)) for kf in self._keyframes}
        points = {lid: self._solver.point(L(lid)) for lid in landmarks}
        self._poses.update(poses)
        self._points.update(points)
        return BackendUpdate(
            poses={kf: p.copy() for kf, p in poses.items()},
            landmarks={lid: p.copy() for lid, p in points.items()},
            retired_landmarks=outcome.retired,
            outlier_observations=outcome.outliers,
            n_factors=self._solver.n_factors,
            n_landmarks=self._book.n_landmarks,
            ok=outcome.ok,
            time_ms=(time.perf_counter() - start) * 1e3,
        )
