"""Batch runs: a whole sequence through the system, results and evaluation written to a folder."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

import cv2
import numpy as np

from osslam.config import Config
from osslam.eval.masks import FAST_RADIUS, MaskCounts, mask_counts
from osslam.progress import Progress
from osslam.system import System
from osslam.types import CameraIntrinsics, Frame

log = logging.getLogger(__name__)


class FrameSource(Protocol):
    """What a run needs of a sequence: its name, intrinsics, length and frames."""

    name: str
    intrinsics: CameraIntrinsics

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> Frame: ...


@dataclass
class RunSummary:
    """Where a run's results went, its statistics and, with ground truth, its APE RMSE."""

    out_dir: Path
    stats: dict
    ape_rmse: float | None
    metrics: dict | None


def run_sequence(source: FrameSource, cfg: Config, out_dir: str | Path, groundtruth: Path | None = None,
                 progress: bool | None = None,
                 ignore: Callable[[Frame], np.ndarray | None] | None = None) -> RunSummary:
    """Track every frame of ``source``, save the results, and evaluate against ground truth.

    ``groundtruth`` is a TUM file; without one, the frames' own ``gt_pose`` (synthetic
    data) are written to ``out_dir/groundtruth.txt`` and used instead. Frames with a
    ground-truth mask of movers (``osslam synth`` composites) also get the system's dynamic
    mask scored against it, in ``out_dir/eval/masks.json`` and stats.json. ``ignore`` gives
    each frame a mask of pixels to leave out (``System.track``'s ``mask``), e.g. the
    ground-truth movers for the best a dynamic mask could do.
    """
    from osslam.eval.report import evaluate_files
    from osslam.trajectory_io import write_tum

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bar = Progress(len(source), label=source.name, enabled=progress)
    gt_stamps: list[float] = []
    gt_poses: list[np.ndarray] = []
    interrupted = False
    scorer = MaskScorer(cfg, source.intrinsics)
    with System(cfg, source.intrinsics) as slam:
        try:
            for i in range(len(source)):
                frame = source[i]
                result = slam.track(frame.rgb, frame.depth, frame.timestamp,
                                    None if ignore is None else ignore(frame))
                if frame.gt_pose is not None:
                    gt_stamps.append(frame.timestamp)
                    gt_poses.append(frame.gt_pose)
                if frame.gt_mask is not None:
                    scorer.add(frame, result.mask)
                bar.update(i + 1, result.state)
        except KeyboardInterrupt:
            interrupted = True
            log.warning("interrupted after %d frames; saving what was tracked", slam.stats()["frames_in"])
    slam.save(out)
    if interrupted:
        raise KeyboardInterrupt
    stats = slam.stats()
    if scorer.frames:
        stats["masks"] = scorer.write(out / "eval" / "masks.json")
        (out / "stats.json").write_text(json.dumps(stats, indent=2))
    if groundtruth is None and gt_poses:
        groundtruth = out / "groundtruth.txt"
        write_tum(groundtruth, gt_stamps, gt_poses)
    ape_rmse = metrics = None
    if groundtruth is not None and slam.trajectory():
        report = evaluate_files(groundtruth, out / "trajectory.txt", out / "eval", cfg.eval, extra=_run_section(stats),
                                images=_run_images(out, stats))
        metrics = report.metrics
        ape_rmse = float(metrics["ape"]["rmse"])
        stats["ape_rmse"] = ape_rmse
        (out / "stats.json").write_text(json.dumps(stats, indent=2))
    log.info("run finished: %d frames, %d keyframes", stats["frames_in"], stats["keyframes"])
    return RunSummary(out, stats, ape_rmse, metrics)


class MaskScorer:
    """Scores each frame's dynamic mask against its ground truth, over pixels and ORB keypoints."""

    def __init__(self, cfg: Config, intrinsics: CameraIntrinsics):
        self._cfg = cfg
        self._intrinsics = intrinsics
        self._extractor = None
        self.total = MaskCounts()
        self.frames: list[dict] = []

    def add(self, frame: Frame, predicted: np.ndarray | None) -> None:
        """Score one frame; keypoints are the tracker's ORB detections without any mask."""
        if self._extractor is None:
            from osslam.frontend.features import FeatureExtractor

            self._extractor = FeatureExtractor(self._cfg.features, self._cfg.camera, self._intrinsics)
        gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
        features = self._extractor.extract(gray, frame.depth)
        fast_radius = FAST_RADIUS * self._cfg.features.scale_factor ** features.octave
        counts = mask_counts(predicted, frame.gt_mask, features.pixels, fast_radius)
        self.total += counts
        self.frames.append({"timestamp": frame.timestamp, **counts.scores()})

    def write(self, path: Path) -> dict:
        """Write per-frame and total scores as JSON; return the totals."""
        path.parent.mkdir(parents=True, exist_ok=True)
        total = {"frames": len(self.frames), **self.total.scores()}
        path.write_text(json.dumps({"total": total, "per_frame": self.frames}, indent=1))
        return total


def _run_section(stats: dict) -> dict:
    """The run statistics shown in the evaluation report."""
    timings = stats["timings_ms"]
    rows = {k: stats[k] for k in ("frames_in", "frames_tracked", "lost_events", "keyframes", "landmarks")}
    rows["mean ms per frame"] = round(timings.get("total", {}).get("mean", float("nan")), 2)
    rows["peak memory (MB)"] = stats["peak_rss_mb"]
    if "gate_process_peak_rss_mb" in stats:
        rows["gate process peak memory (MB)"] = stats["gate_process_peak_rss_mb"]
    for key, value in stats.get("masks", {}).items():
        rows[f"mask {key}"] = "n/a" if value is None else round(value, 4)
    mapping = stats.get("mapping")
    if mapping and mapping["points_final"] is not None:
        rows["map points fused"] = mapping["points_fused"]
        rows["map points removed as seen through"] = mapping["removed_free_space"]
        rows["map points removed by SOR"] = mapping["removed_sor"]
        rows["map points removed as residue"] = mapping["removed_residue"]
        rows["map points kept"] = mapping["points_final"]
        rows["mapping ms per view"] = mapping["ms_per_view"]
    return rows


def _run_images(out: Path, stats: dict) -> dict[str, Path]:
    """Images of the run shown in the evaluation report: the dense map preview when this run wrote one."""
    if "mapping" not in stats:
        return {}
    from osslam.mapping.mapper import PREVIEW_FILE

    preview = out / PREVIEW_FILE
    return {"Static map": preview} if preview.is_file() else {}
