"""Frame-by-frame camera tracking against a local map of landmarks (ORB-SLAM style)."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from enum import Enum

import cv2
import numpy as np
from scipy.spatial import cKDTree

from osslam.backend.types import BackendUpdate, KeyframeObservations
from osslam.config import Config
from osslam.geometry import invert, pose_from_rvec, project_pinhole, transform_points
from osslam.imaging import grid_cells, rank_in_cells, values_at
from osslam.types import CameraIntrinsics, kinect_depth_sigma

from .features import FeatureExtractor, Features
from .keyframe_policy import KeyframePolicy
from .local_map import Keyframe, LandmarkMap
from .matching import Matches, match_brute_force, match_by_projection
from .pose_optimizer import PoseEstimate, optimize_pose

log = logging.getLogger(__name__)

SEEN_TOLERANCE = 0.05  # metres beyond three sigma of depth noise by which a landmark hidden behind a mover is farther


class TrackState(str, Enum):
    """Tracking state of one frame."""

    INITIALIZING = "initializing"
    OK = "ok"
    RELOCALIZED = "relocalized"
    LOST = "lost"


@dataclass
class TrackOutput:
    """The tracker's result for one frame."""

    pose: np.ndarray  # T_world_camera
    state: TrackState
    reference_kf: int
    is_keyframe: bool
    n_features: int
    n_matches: int
    n_inliers: int
    keyframe: KeyframeObservations | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class PendingFrame:
    """A frame whose features and pose are estimated but not yet committed to the map.

    ``previous_pose`` is the last tracked frame's pose (None before the map exists or
    after a lost frame); ``estimate`` is None when tracking failed.
    """

    frame_index: int
    timestamp: float
    feats: Features
    depth: np.ndarray
    timings_ms: dict[str, float]
    state: TrackState = TrackState.INITIALIZING
    previous_pose: np.ndarray | None = None
    predicted: np.ndarray | None = None
    estimate: PoseEstimate | None = None
    matches: Matches | None = None
    ids: np.ndarray | None = None
    anchored: bool = False  # the pose rests on a consensus of mature landmarks (or no consensus is asked for)

    @property
    def ego_motion(self) -> np.ndarray | None:
        """T_previous_current of the camera from the estimated pose, when both poses are known and anchored.

        A pose found while the map holds no mature landmarks may follow a mover that was
        mapped as static; it is not handed on as the camera's motion.
        """
        return self.tracked_motion if self.anchored else None

    @property
    def pose(self) -> np.ndarray | None:
        """T_world_camera estimated for the frame, or None when tracking failed."""
        return None if self.estimate is None else invert(self.estimate.T_cw)

    @property
    def tracked_motion(self) -> np.ndarray | None:
        """T_previous_current from the estimated pose, anchored or not, when both poses are known."""
        if self.estimate is None or self.previous_pose is None:
            return None
        return invert(self.previous_pose) @ self.pose


class Tracker:
    """Tracks RGB-D frames against the landmarks of covisible keyframes.

    Each frame: ORB features outside the ignore mask, a constant-velocity prediction,
    projection search in the local map, motion-only refinement, a second finer search and
    refinement; PnP-RANSAC against descriptors when the prediction fails. Keyframes seed
    new landmarks from depth and are handed to the back-end as observations.
    """

    MIN_INIT_POINTS = 50

    def __init__(self, cfg: Config, intrinsics: CameraIntrinsics):
        self.cfg = cfg
        self.intrinsics = intrinsics
        self.K = intrinsics.K
        self.extractor = FeatureExtractor(cfg.features, cfg.camera, intrinsics)
        self.policy = KeyframePolicy(cfg.keyframes)
        self.map = LandmarkMap()
        self.sigma2 = self.extractor.scale_sigma2
        self.reference_kf = -1
        self.T_ref_last = np.eye(4)  # last frame in its reference keyframe
        self.velocity = np.eye(4)  # motion from the previous to the last frame, in the camera frame
        self.frames_since_kf = 0
        self.lost_events = 0
        self._next_kf = 0
        self._local_ids: np.ndarray | None = None
        self._last_state = TrackState.INITIALIZING
        self._ref_tracked = 0  # inliers of the first frame tracked after the reference keyframe
        self._moving: list[np.ndarray] = []  # landmarks seen moving since the last keyframe
        self._on_moving_surface = np.zeros(0, np.int64)  # landmarks on a moving surface the last time motion was seen
        self._frame_index = 0  # of the frame being estimated
        self._anchored = False  # whether the frame being estimated found a consensus of mature landmarks

    # ------------------------------------------------------------------ public

    @property
    def initialized(self) -> bool:
        """Whether the map holds its first keyframe."""
        return self.reference_kf >= 0

    def last_pose(self) -> np.ndarray:
        """Pose of the last tracked frame, following the reference keyframe's current pose."""
        return self.map.keyframes[self.reference_kf].pose @ self.T_ref_last

    def track(self, frame_index: int, timestamp: float, gray: np.ndarray, depth: np.ndarray,
              ignore: np.ndarray | None = None) -> TrackOutput:
        """Estimate the pose of one frame and commit it; ``ignore`` marks pixels whose features are not used."""
        return self.commit(self.estimate(frame_index, timestamp, gray, depth, ignore))

    def estimate(self, frame_index: int, timestamp: float, gray: np.ndarray, depth: np.ndarray,
                 ignore: np.ndarray | None = None) -> PendingFrame:
        """Features and pose of one frame, not yet committed to the map (see :meth:`commit`)."""
        t0 = time.perf_counter()
        feats = self.extractor.extract(gray, depth, ignore)
        t1 = time.perf_counter()
        pending = PendingFrame(frame_index, timestamp, feats, depth, {"features": (t1 - t0) * 1e3})
        self._frame_index = frame_index
        if not self.initialized:
            return pending
        pending.previous_pose = self.last_pose() if self._last_state is not TrackState.LOST else None
        pending.predicted = self.last_pose() @ self.velocity
        self._anchored = not self.cfg.tracking.consensus
        est, matches, ids = self._track_local_map(feats, invert(pending.predicted))
        pending.anchored = self._anchored
        state = TrackState.OK
        if est is None:
            est, matches, ids = self._relocalize(feats)
            state = TrackState.RELOCALIZED if est is not None else TrackState.LOST
        pending.state, pending.estimate, pending.matches, pending.ids = state, est, matches, ids
        pending.timings_ms["tracking"] = (time.perf_counter() - t1) * 1e3
        return pending

    def commit(self, pending: PendingFrame, dynamic: np.ndarray | None = None,
               moving_now: np.ndarray | None = None) -> TrackOutput:
        """Commit an estimated frame: motion state, landmarks seen moving, and a keyframe when due.

        ``dynamic`` marks the pixels to ignore: features there make no landmarks and no
        observations, and landmarks matched there that the pose does not explain are retired.
        ``moving_now`` marks pixels with fresh evidence of motion: landmarks lying on the
        surface seen there, as the last time motion was seen, are retired too unless the pose
        explains them or they are mature (see :meth:`_retire_seen_moving`). With either mask given,
        the time that takes is ``timings_ms["masked"]``.
        """
        t0 = time.perf_counter()
        feats, timings = pending.feats, pending.timings_ms
        on_mover = np.zeros(len(feats), bool)
        if dynamic is not None and len(feats):
            on_mover = values_at(dynamic, feats.pixels)
        if not self.initialized:
            out = self._initialize(pending.frame_index, pending.timestamp, feats.subset(~on_mover))
            out.timings_ms = {**timings, "tracking": (time.perf_counter() - t0) * 1e3}
            return out
        est, matches, ids = pending.estimate, pending.matches, pending.ids
        explained = None if est is None else ids[matches.query[est.inliers]]
        if est is not None and on_mover.any():
            est, explained = self._drop_moving(est, feats, matches, ids, on_mover)
        if est is not None and moving_now is not None and moving_now.any():
            self._retire_seen_moving(est.T_cw, pending.depth, moving_now, explained)
        t1 = time.perf_counter()
        if dynamic is not None or moving_now is not None:
            timings["masked"] = (t1 - t0) * 1e3
        if est is None:
            if self._last_state is not TrackState.LOST:
                self.lost_events += 1
                log.warning("tracking lost at frame %d (t=%.6f)", pending.frame_index, pending.timestamp)
            self._last_state = TrackState.LOST
            self.velocity = np.eye(4)
            self.frames_since_kf += 1
            return TrackOutput(pending.predicted, TrackState.LOST, self.reference_kf, False, len(feats), 0, 0,
                               timings_ms=timings)
        T_wc = invert(est.T_cw)
        state = pending.state
        # after a lost stretch the last pose is stale, so no velocity is known yet
        self.velocity = np.eye(4) if self._last_state is TrackState.LOST else invert(self.last_pose()) @ T_wc
        self._last_state = state
        self.frames_since_kf += 1
        inlier_ids = ids[matches.query[est.inliers]]
        if state is TrackState.RELOCALIZED:
            self._rereference(inlier_ids)
        ref = self.map.keyframes[self.reference_kf]
        T_ref_cur = invert(ref.pose) @ T_wc
        if self.frames_since_kf == 1:
            self._ref_tracked = est.n_inliers
        keyframe = None
        if state is TrackState.OK and self.policy.is_keyframe(self.frames_since_kf, est.n_inliers,
                                                              self._ref_tracked, T_ref_cur):
            keyframe = self._insert_keyframe(pending.frame_index, pending.timestamp, T_wc, feats, matches, est, ids,
                                             on_mover)
            timings["keyframe"] = (time.perf_counter() - t1) * 1e3
        else:
            self.T_ref_last = T_ref_cur
        return TrackOutput(T_wc, state, self.reference_kf, keyframe is not None, len(feats), len(matches),
                           len(inlier_ids), keyframe, timings)

    def _drop_moving(self, est: PoseEstimate, feats: Features, matches: Matches, ids: np.ndarray,
                     on_mover: np.ndarray) -> tuple[PoseEstimate, np.ndarray]:
        """The pose refined without observations on movers, and the landmarks it explains, movers' or not.

        Landmarks matched on movers that the pose does not explain retire. The pose was
        estimated before the frame's mask was known, so movers outside the previous frame's
        mask may have pulled it; it is refined again from the rest when enough of them remain
        and stay consistent, and kept as it was otherwise.
        """
        masked = on_mover[matches.feature]
        keep = ~masked
        if (masked & est.inliers).any() and (est.inliers & keep).sum() >= self.cfg.tracking.min_inliers:
            kept = Matches(matches.query[keep], matches.feature[keep], matches.distance[keep])
            refined = self._optimize(est.T_cw, feats, kept, ids, est.inliers[keep])
            if refined.n_inliers >= self.cfg.tracking.min_inliers:
                est = self._optimize(refined.T_cw, feats, matches, ids, refine=False)
        self._retire(ids[matches.query[masked & ~est.inliers]])
        inliers = est.inliers & keep
        return PoseEstimate(est.T_cw, inliers, int(inliers.sum())), ids[matches.query[est.inliers]]

    def _retire_seen_moving(self, T_cw: np.ndarray, depth: np.ndarray, moving: np.ndarray,
                            explained: np.ndarray) -> None:
        """Retire local landmarks seen on moving pixels twice in a row and not hidden behind the mover there.

        A landmark on a moving object lies on the moving surface seen at its pixel; a static
        landmark behind a mover is farther than the mover's surface and stays. Moving cells
        reach over the static surface around a mover, and one frame's ego-motion may be off,
        so a landmark retires only when it was on a moving surface the last time motion was
        seen as well; landmarks the pose explains in this frame (``explained``) and mature
        landmarks (see :meth:`_mature`) stay: a mature landmark that moves is retired once
        matched where the pose cannot explain it.
        """
        ids = self._local_landmarks()
        ids = ids[~np.isin(ids, explained) & ~self._mature(ids)]
        pc = transform_points(T_cw, self.map.positions[ids])
        front = pc[:, 2] > 0.05
        ids, pc = ids[front], pc[front]
        px = np.rint(self.intrinsics.project(pc)).astype(int)
        h, w = moving.shape
        inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        ids, pc, px = ids[inside], pc[inside], px[inside]
        measured = depth[px[:, 1], px[:, 0]]
        z = pc[:, 2]
        hidden = np.isfinite(measured) & (measured > 0) & (z > measured + SEEN_TOLERANCE + 3 * kinect_depth_sigma(measured))
        on_surface = ids[moving[px[:, 1], px[:, 0]] & ~hidden]
        self._retire(on_surface[np.isin(on_surface, self._on_moving_surface)])
        self._on_moving_surface = on_surface

    def _rereference(self, inlier_ids: np.ndarray) -> None:
        """After relocalisation, the keyframe sharing most landmarks with the frame becomes the reference.

        The local map around the keyframe of the lost stretch may be wrong; the one
        around the place relocalisation found is what the next frames will see.
        """
        best = self.map.most_observing(inlier_ids)
        if best is not None and best != self.reference_kf:
            self.reference_kf = best
            self._local_ids = None

    def _retire(self, moving: np.ndarray) -> None:
        """Stop tracking landmarks seen moving; the back-end retires them at the next keyframe."""
        if len(moving):
            self.map.retire(moving)
            self._moving.append(moving)
            if self._local_ids is not None:  # the same keyframes' landmarks, less the retired ones
                self._local_ids = self._local_ids[self.map.alive[self._local_ids]]

    def apply_update(self, update: BackendUpdate) -> None:
        """Take optimised keyframe poses and landmark positions from the back-end."""
        for kf_id, pose in update.poses.items():
            if kf_id in self.map.keyframes:
                self.map.keyframes[kf_id].pose = pose
        if update.landmarks:
            ids = np.fromiter(update.landmarks.keys(), dtype=np.int64, count=len(update.landmarks))
            self.map.positions[ids] = np.array([update.landmarks[i] for i in ids.tolist()])
        for kf_id, lid in update.outlier_observations:
            self.map.drop_observation(kf_id, lid)
        if update.retired_landmarks or update.outlier_observations:
            self.map.retire(update.retired_landmarks)
            self._local_ids = None

    # ----------------------------------------------------------------- helpers

    def _initialize(self, frame_index: int, timestamp: float, feats: Features) -> TrackOutput:
        n_depth = int((feats.depth > 0).sum())
        if n_depth < self.MIN_INIT_POINTS:
            return TrackOutput(np.eye(4), TrackState.INITIALIZING, -1, False, len(feats), 0, 0)
        empty = Matches(np.zeros(0, int), np.zeros(0, int), np.zeros(0, np.int32))
        est = PoseEstimate(np.eye(4), np.zeros(0, bool), 0)
        kf = self._insert_keyframe(frame_index, timestamp, np.eye(4), feats, empty, est, np.zeros(0, np.int64))
        self._last_state = TrackState.OK
        log.info("map initialised at frame %d with %d landmarks", frame_index, len(kf.landmark_ids))
        return TrackOutput(np.eye(4), TrackState.OK, self.reference_kf, True, len(feats), 0, 0, kf)

    def _local_landmarks(self) -> np.ndarray:
        if self._local_ids is None:
            kfs = self.map.covisible(self.reference_kf, self.cfg.tracking.local_keyframes)
            recent = sorted(self.map.keyframes)[-3:]
            self._local_ids = self.map.local_landmarks(sorted(set(kfs) | set(recent)))
        return self._local_ids

    def _project(self, T_cw: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel projections of landmarks that fall inside the image, and their ids."""
        pc = transform_points(T_cw, self.map.positions[ids])
        front = pc[:, 2] > 0.05
        pc, ids = pc[front], ids[front]
        uv = project_pinhole(pc, self.K)
        w, h = self.intrinsics.width, self.intrinsics.height
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        return uv[inside], ids[inside]

    def _search_and_refine(self, feats: Features, T_cw: np.ndarray, ids: np.ndarray, radius: float,
                           tree: cKDTree, consensus: bool = False) -> tuple[PoseEstimate | None, Matches, np.ndarray]:
        tcfg = self.cfg.tracking
        uv, ids = self._project(T_cw, ids)
        matches = match_by_projection(uv, self.map.descriptors[ids], feats.uv, feats.descriptors, radius,
                                      tcfg.max_descriptor_distance, tcfg.ratio, tree=tree)
        if len(matches) < tcfg.min_matches:
            return None, matches, ids
        start = None
        if consensus:
            T_cw, start = self._consensus(T_cw, feats, matches, ids)
        est = self._optimize(T_cw, feats, matches, ids, start)
        return (est if est.n_inliers >= tcfg.min_inliers else None), matches, ids

    def _consensus(self, T_cw: np.ndarray, feats: Features, matches: Matches,
                   ids: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The pose and matches of the rigid consensus of long-observed landmarks, or the guess and None.

        Landmarks on an object that has moved since they were mapped agree with each other
        but not with the static scene, and a local refinement would settle between the two.
        The consensus (PnP with MAGSAC++) is sought among landmarks seen by at least
        ``tracking.mature_observations`` keyframes when there are enough of them: the
        static scene has been seen the longest, while an object that paused was mapped
        only during its pause. With fewer of them, but at least ``tracking.arbiter_mature``,
        they choose among rigid fits of all matches (see :meth:`_arbitrate`). Every match
        the consensus pose explains starts the refinement.
        """
        tcfg = self.cfg.tracking
        points = self.map.positions[ids[matches.query]]
        uv = feats.uv[matches.feature]
        pool = np.flatnonzero(self._mature(ids[matches.query]))
        if len(pool) >= tcfg.min_matches:
            T = self._rigid_fit(points[pool], uv[pool])
            self._anchored = T is not None
        elif tcfg.arbiter_mature > 0 and len(pool) >= tcfg.arbiter_mature:
            T = self._arbitrate(points, uv, pool)
        else:
            T = self._rigid_fit(points, uv)
        if T is None:
            return T_cw, None
        return T, self._explained(T, points, uv)

    def _mature(self, ids: np.ndarray) -> np.ndarray:
        """Which landmarks are seen by ``tracking.mature_observations`` keyframes and ``tracking.mature_frames`` old."""
        tcfg = self.cfg.tracking
        age = self._frame_index - self.map.born[ids]
        return (self.map.seen[ids] >= tcfg.mature_observations) & (age >= tcfg.mature_frames)

    def _arbitrate(self, points: np.ndarray, uv: np.ndarray, mature: np.ndarray) -> np.ndarray | None:
        """Of up to three rigid fits of all matches, each to the matches the ones before left unexplained, the one
        explaining most of the ``mature`` matches.

        Too few landmarks are mature to fit a pose of their own (the camera looks at new
        ground), and a densely textured mover mapped while it paused may hold most of the
        matches; the mature landmarks still tell which rigid motion is the static scene's.
        Fitting stops once a fit explains half of them.
        """
        remaining = np.arange(len(points))
        best, best_votes = None, -1
        for _ in range(3):
            if len(remaining) < self.cfg.tracking.min_matches:
                break
            T = self._rigid_fit(points[remaining], uv[remaining])
            if T is None:
                break
            explained = self._explained(T, points, uv)
            votes = int(np.count_nonzero(explained[mature]))
            if votes > best_votes:
                best, best_votes = T, votes
            if 2 * best_votes >= len(mature):
                break
            remaining = remaining[~explained[remaining]]
        return best

    def _rigid_fit(self, points: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
        """T_cw of the rigid consensus of 3D ``points`` seen at pixels ``uv`` (PnP, MAGSAC++), or None."""
        tcfg = self.cfg.tracking
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            points.astype(np.float64), uv.astype(np.float64), self.K, None,
            iterationsCount=tcfg.pnp_iterations, reprojectionError=tcfg.consensus_threshold, confidence=0.99,
            flags=cv2.USAC_MAGSAC)
        if not ok or inl is None or len(inl) < tcfg.min_inliers:
            return None
        return pose_from_rvec(rvec, tvec)

    def _explained(self, T_cw: np.ndarray, points: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Which of the ``points`` the pose projects within ``tracking.consensus_threshold`` of their pixels."""
        pc = transform_points(T_cw, points)
        return (pc[:, 2] > 1e-6) & (np.linalg.norm(project_pinhole(pc, self.K) - uv, axis=1)
                                     < self.cfg.tracking.consensus_threshold)

    def _optimize(self, T_cw: np.ndarray, feats: Features, matches: Matches, ids: np.ndarray,
                  start: np.ndarray | None = None, refine: bool = True) -> PoseEstimate:
        """The pose refined against the matches; with ``refine`` off, ``T_cw`` and the matches it explains."""
        f = matches.feature
        steps = {"iterations": self.cfg.tracking.pose_iterations} if refine else {"rounds": 1, "iterations": 0}
        return optimize_pose(T_cw, self.map.positions[ids[matches.query]], feats.uv[f], feats.depth[f],
                             self.sigma2[feats.octave[f]], self.K, self.cfg.tracking.virtual_baseline,
                             start_inliers=start, **steps)

    def _track_local_map(self, feats: Features, T_cw_pred: np.ndarray):
        if len(feats) == 0:
            return None, None, None
        tree = cKDTree(feats.uv)
        local = self._local_landmarks()
        est, matches, ids = self._search_and_refine(feats, T_cw_pred, local, self.cfg.tracking.search_radius, tree,
                                                    self.cfg.tracking.consensus)
        if est is None:
            return None, None, None
        fine, fine_matches, fine_ids = self._search_and_refine(feats, est.T_cw, local,
                                                               self.cfg.tracking.refine_radius, tree)
        if fine is not None and fine.n_inliers >= est.n_inliers:
            return fine, fine_matches, fine_ids
        return est, matches, ids

    def _relocalize(self, feats: Features):
        """Pose from descriptor matches against the map and PnP-RANSAC (seeded)."""
        tcfg = self.cfg.tracking
        ids = np.flatnonzero(self.map.alive[: self.map.size]).astype(np.int64)
        if self._last_state is not TrackState.LOST:
            ids = self._local_landmarks()
        matches = match_brute_force(self.map.descriptors[ids], feats.descriptors, tcfg.max_descriptor_distance, 0.75)
        if len(matches) < tcfg.min_matches:
            return None, None, None
        cv2.setRNGSeed(self.cfg.run.seed)
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            self.map.positions[ids[matches.query]].astype(np.float64), feats.uv[matches.feature].astype(np.float64),
            self.K, None, iterationsCount=tcfg.pnp_iterations, reprojectionError=tcfg.pnp_reprojection_error,
            confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
        if not ok or inl is None or len(inl) < tcfg.min_inliers:
            return None, None, None
        T_cw = pose_from_rvec(rvec, tvec)
        est = self._optimize(T_cw, feats, matches, ids)
        if est.n_inliers < tcfg.min_inliers:
            return None, None, None
        tree = cKDTree(feats.uv)
        fine, fine_matches, fine_ids = self._search_and_refine(feats, est.T_cw, self._local_landmarks(),
                                                               tcfg.refine_radius, tree)
        log.info("relocalised with %d inliers", est.n_inliers)
        if fine is not None and fine.n_inliers >= est.n_inliers:
            return fine, fine_matches, fine_ids
        return est, matches, ids

    def _insert_keyframe(self, frame_index: int, timestamp: float, T_wc: np.ndarray, feats: Features,
                         matches: Matches, est: PoseEstimate, ids: np.ndarray,
                         on_mover: np.ndarray | None = None) -> KeyframeObservations:
        kcfg = self.cfg.keyframes
        tracked_f = matches.feature[est.inliers]
        tracked_ids = ids[matches.query[est.inliers]]
        free = np.ones(len(feats), dtype=bool) if on_mover is None else ~on_mover
        free[matches.feature] = False
        cand = np.flatnonzero(free & (feats.depth > 0))
        cand = cand[np.argsort(feats.depth[cand], kind="stable")]
        cand = cand[_spread_order(feats.uv[cand], (self.intrinsics.width, self.intrinsics.height))]
        cand = cand[: kcfg.max_new_landmarks]
        pc = self.intrinsics.backproject(feats.uv[cand], feats.depth[cand])
        new_ids = self.map.add_landmarks(transform_points(T_wc, pc), feats.descriptors[cand], feats.octave[cand],
                                         frame_index)

        kf_id = self._next_kf
        self._next_kf += 1
        all_f = np.concatenate([tracked_f, cand])
        all_ids = np.concatenate([tracked_ids, new_ids])
        self.map.add_keyframe(Keyframe(kf_id, frame_index, timestamp, T_wc.copy(), all_ids))
        self.reference_kf = kf_id
        self.T_ref_last = np.eye(4)
        self.frames_since_kf = 0
        self._local_ids = None
        scale = np.sqrt(self.sigma2[feats.octave[all_f]])
        return KeyframeObservations(
            keyframe_id=kf_id,
            pose_guess=T_wc.copy(),
            landmark_ids=all_ids,
            uv=feats.uv[all_f],
            depth=feats.depth[all_f],
            sigma_scale=scale,
            new_landmarks={int(i): self.map.positions[i].copy() for i in new_ids.tolist()},
            moving_landmarks=self._take_moving(),
        )

    def _take_moving(self) -> np.ndarray:
        """Landmarks seen moving since the last keyframe, handed to the back-end once."""
        moving = np.unique(np.concatenate(self._moving)) if self._moving else np.zeros(0, np.int64)
        self._moving = []
        return moving


SPREAD_GRID = (8, 6)  # columns, rows of the grid over which new landmarks are spread


def _spread_order(uv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """An order of points that takes the first of each image cell, then the second of each, and so on.

    Points keep their given order within a cell (nearest first), so a near object filling
    part of the image cannot take all the new landmarks.
    """
    return np.argsort(rank_in_cells(grid_cells(uv, size, SPREAD_GRID)), kind="stable")
