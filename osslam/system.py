"""The SLAM system: wires the tracker to the back-end and keeps the trajectory."""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from osslam.config import Config, check_config, save_config
from osslam.frontend.tracker import Tracker, TrackOutput, TrackState
from osslam.timing import StageTimer, peak_rss_mb
from osslam.types import CameraIntrinsics, StampedPose, TrackingResult

log = logging.getLogger(__name__)


@dataclass
class _FrameRecord:
    timestamp: float
    reference_kf: int
    T_ref_frame: np.ndarray
    state: TrackState


def _union(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    """Union of two optional masks."""
    if a is None or b is None:
        return b if a is None else a
    return a | b


class System:
    """Online RGB-D SLAM: feed frames with :meth:`track`, read poses back at any time.

    Example::

        with System(load_config("tum_fr1"), intrinsics) as slam:
            for rgb, depth, t in frames:
                result = slam.track(rgb, depth, t)
            slam.save("out/")
    """

    def __init__(self, config: Config, intrinsics: CameraIntrinsics):
        from osslam.backend.isam import IsamBackend

        check_config(config)  # settings made in code rather than loaded
        self.config = config
        self.intrinsics = intrinsics
        cv2.setRNGSeed(config.run.seed)
        cv2.setNumThreads(config.run.threads)
        self.tracker = Tracker(config, intrinsics)
        self.backend = IsamBackend(intrinsics, config.backend, config.tracking.virtual_baseline)
        self.timer = StageTimer()
        self.mapper = None
        if config.mapping.enabled:
            from osslam.mapping.mapper import DenseMapper

            self.mapper = DenseMapper(config.mapping, intrinsics)
        self.gate = None
        if config.gating.enabled:
            from osslam.frontend.gate_process import open_gate

            self.gate = open_gate(config, intrinsics)
        self._records: list[_FrameRecord] = []
        self._views: list[int] = []  # the records of the frames that are map views
        self._frames_in = 0
        self._last_timestamp: float | None = None  # of the last frame taken, tracked or not
        self._predicted = 0  # frames the gate segmented beside tracking, as tracking confirmed
        self._closed = False

    def __enter__(self) -> "System":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def track(self, rgb: np.ndarray, depth: np.ndarray, timestamp: float,
              mask: np.ndarray | None = None) -> TrackingResult:
        """Track one frame.

        ``rgb`` is (H, W, 3) uint8 RGB; ``depth`` is (H, W) float metres (0, NaN or infinity =
        missing) or uint16 raw values divided by ``dataset.depth_scale``; ``mask`` marks pixels to ignore
        (dynamic objects), in tracking and in the dense map; with ``gating.enabled`` the
        system's own dynamic mask is added to it. Timestamps must increase.
        """
        if self._closed:
            raise RuntimeError("System.track called after close()")
        gray, depth_m, ignore = self._check_inputs(rgb, depth, timestamp, mask)
        self._frames_in += 1
        start = time.perf_counter()
        gate_ms: dict[str, float] = {}
        map_ignore = ignore
        if self.gate is None:
            out = self.tracker.track(self._frames_in - 1, timestamp, gray, depth_m, ignore)
        else:
            self.gate.start(np.asarray(rgb), gray, depth_m)
            pending = self.tracker.estimate(self._frames_in - 1, timestamp, gray, depth_m,
                                            _union(ignore, self.gate.prior()))
            gated = self.gate.finish(pending.ego_motion, pending.tracked_motion, pending.pose)
            if self.mapper is not None:
                map_ignore = _union(ignore, gated.map_mask)
            ignore = gated.mask if ignore is None else (ignore | gated.mask)
            gate_ms = {"segmentation": gated.cost_ms, **gated.timings_ms}
            self._predicted += gated.predicted
            if not gated.segmented and not self.tracker.initialized and self.config.motion.enabled:
                # the map starts at the first frame with motion evidence, not detections alone
                out = TrackOutput(np.eye(4), TrackState.INITIALIZING, -1, False, len(pending.feats), 0, 0,
                                  timings_ms=pending.timings_ms)
            else:
                out = self.tracker.commit(pending, ignore, gated.moving_now)
        timings = {**gate_ms, **out.timings_ms}
        if out.keyframe is not None:
            t0 = time.perf_counter()
            update = self.backend.add_keyframe(out.keyframe)
            self.tracker.apply_update(update)
            timings["backend"] = (time.perf_counter() - t0) * 1e3
        pose = out.pose
        if out.reference_kf >= 0:
            ref_pose = self.tracker.map.keyframes[out.reference_kf].pose
            T_ref = np.linalg.solve(ref_pose, out.pose) if not out.is_keyframe else np.eye(4)
            self._records.append(_FrameRecord(timestamp, out.reference_kf, T_ref, out.state))
            pose = ref_pose @ T_ref
        if self.mapper is not None:
            tracked = out.reference_kf >= 0 and out.state in (TrackState.OK, TrackState.RELOCALIZED)
            if tracked and self.mapper.wants_view(timestamp, out.is_keyframe):
                t0 = time.perf_counter()
                self._views.append(len(self._records) - 1)
                self.mapper.add_view(self._views[-1], timestamp, pose, np.asarray(rgb), depth_m, map_ignore)
                timings["mapping"] = (time.perf_counter() - t0) * 1e3
            self.mapper.remember_mask(map_ignore)
        timings["total"] = (time.perf_counter() - start) * 1e3
        self.timer.add(timings)
        return TrackingResult(timestamp, pose, out.state.value, out.is_keyframe, out.n_features, out.n_matches,
                              out.n_inliers, timings, ignore)

    def _check_inputs(self, rgb, depth, timestamp, mask):
        h, w = self.intrinsics.height, self.intrinsics.width
        rgb = np.asarray(rgb)
        depth = np.asarray(depth)
        if rgb.shape != (h, w, 3) or rgb.dtype != np.uint8:
            raise ValueError(f"rgb must be uint8 of shape {(h, w, 3)}, got {rgb.dtype} {rgb.shape}")
        if depth.shape != (h, w):
            raise ValueError(f"depth must have shape {(h, w)}, got {depth.shape}")
        if depth.dtype == np.uint16:
            depth = depth.astype(np.float32) / self.config.dataset.depth_scale
        elif depth.dtype.kind != "f":
            raise ValueError(f"depth must be float metres or uint16, got {depth.dtype}")
        else:
            measured = np.isfinite(depth)  # NaN or infinity where the sensor measured nothing (as ROS does)
            if not measured.all():
                depth = np.where(measured, depth, 0.0).astype(depth.dtype)
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != (h, w):
                raise ValueError(f"mask must have shape {(h, w)}, got {mask.shape}")
        if not math.isfinite(timestamp):
            raise ValueError(f"timestamp must be finite, got {timestamp}")
        if self._last_timestamp is not None and timestamp <= self._last_timestamp:
            raise ValueError(f"timestamps must increase: {timestamp:.6f} after {self._last_timestamp:.6f}")
        self._last_timestamp = timestamp
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), depth, mask

    def trajectory(self) -> list[StampedPose]:
        """A pose for every tracked frame, each following its optimised reference keyframe."""
        return [self._stamped(r) for r in self._records]

    def _stamped(self, record: _FrameRecord) -> StampedPose:
        """A tracked frame's pose: its optimised reference keyframe's, moved by the tracked offset."""
        return StampedPose(record.timestamp, self.tracker.map.keyframes[record.reference_kf].pose @ record.T_ref_frame)

    def keyframes(self) -> list[StampedPose]:
        """The optimised keyframe poses."""
        kfs = self.tracker.map.keyframes
        return [StampedPose(kfs[k].timestamp, kfs[k].pose.copy()) for k in sorted(kfs)]

    def map_views(self) -> dict[int, StampedPose]:
        """The dense map's views (id -> pose), each following its optimised reference keyframe."""
        return {i: self._stamped(self._records[i]) for i in self._views}

    def stats(self) -> dict:
        """Counts and per-stage timings of the run so far."""
        states = [r.state for r in self._records]
        return {
            "frames_in": self._frames_in,
            "frames_tracked": sum(s in (TrackState.OK, TrackState.RELOCALIZED) for s in states),
            "frames_lost": sum(s is TrackState.LOST for s in states),
            "lost_events": self.tracker.lost_events,
            "relocalizations": sum(s is TrackState.RELOCALIZED for s in states),
            "keyframes": len(self.tracker.map.keyframes),
            "landmarks": int(self.tracker.map.alive[: self.tracker.map.size].sum()),
            "landmarks_in_graph": self.backend.n_landmarks,
            "timings_ms": self.timer.summary(),
            "peak_rss_mb": peak_rss_mb(),
            **self._gate_stats(),
            **({"mapping": self.mapper.stats_dict()} if self.mapper is not None else {}),
        }

    def _gate_stats(self) -> dict:
        """The gate's counts: frames segmented beside tracking and, run as a process, that process's peak memory."""
        if self.gate is None:
            return {}
        from osslam.frontend.gate_process import GateProcess

        stats = {"gate_predicted_frames": self._predicted}
        if isinstance(self.gate, GateProcess):
            stats["gate_process_peak_rss_mb"] = self.gate.peak_rss_mb
        return stats

    def save(self, out_dir: str | Path) -> Path:
        """Write trajectory.txt, keyframes.txt, stats.json, config.yaml and, with mapping on, the dense map.

        The map (map.ply, map_preview.png, mesh.ply with TSDF on) is fused at the current
        optimised poses of its views, written to map_views.txt, so it matches the trajectory.
        """
        from osslam.trajectory_io import write_tum

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for name, poses in (("trajectory.txt", self.trajectory()), ("keyframes.txt", self.keyframes())):
            write_tum(out / name, [p.timestamp for p in poses], [p.pose for p in poses])
        if self.mapper is not None:
            from osslam.mapping.mapper import MAP_VIEWS_FILE

            views = self.map_views()
            write_tum(out / MAP_VIEWS_FILE, [v.timestamp for v in views.values()], [v.pose for v in views.values()])
            self.mapper.save(out, {i: v.pose for i, v in views.items()})
        (out / "stats.json").write_text(json.dumps(self.stats(), indent=2))
        save_config(self.config, out / "config.yaml")
        return out

    def close(self) -> None:
        """Finish the back-end's pending work; further tracking is refused."""
        if not self._closed:
            if self.gate is not None:
                self.gate.close()
            update = self.backend.finish()
            self.tracker.apply_update(update)
            self._closed = True
