"""The online API and batch runs end to end on the synthetic room."""

import json
import warnings

import numpy as np
import pytest

from osslam.config import load_config
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.pipeline import run_sequence
from osslam.system import System


@pytest.fixture(scope="module")
def synthetic():
    return SyntheticSequence(SyntheticConfig(n_frames=120, seed=3))


@pytest.fixture(scope="module")
def synthetic_run(synthetic, tmp_path_factory):
    cfg = load_config("synthetic")
    out = tmp_path_factory.mktemp("synthetic_run")
    return run_sequence(synthetic, cfg, out, progress=False)


def test_synthetic_run_is_accurate_and_complete(synthetic_run, synthetic):
    stats = synthetic_run.stats
    assert stats["frames_in"] == len(synthetic)
    assert stats["frames_tracked"] == len(synthetic)
    assert stats["lost_events"] == 0
    assert stats["keyframes"] >= 3
    assert synthetic_run.ape_rmse is not None and synthetic_run.ape_rmse < 0.01
    assert synthetic_run.metrics["rpe_trans"]["rmse"] < 0.005


def test_run_writes_every_output(synthetic_run, synthetic):
    out = synthetic_run.out_dir
    for name in ("trajectory.txt", "keyframes.txt", "stats.json", "config.yaml", "groundtruth.txt",
                 "map.ply", "map_views.txt", "eval/metrics.json", "eval/report.md"):
        assert (out / name).is_file(), name
    rows = [l for l in (out / "trajectory.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert len(rows) == len(synthetic)
    views = [l for l in (out / "map_views.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert len(views) == synthetic_run.stats["mapping"]["views"] > 0
    assert set(views) <= set(rows)  # each view's pose is its frame's pose in the trajectory
    metrics = json.loads((out / "eval" / "metrics.json").read_text())
    for key in ("ape", "rpe_trans", "rpe_rot"):
        assert set(metrics[key]) == {"max", "mean", "median", "min", "rmse", "sse", "std"}
    stats = json.loads((out / "stats.json").read_text())
    for stage in ("features", "tracking", "backend", "total"):
        assert {"mean", "median", "p95"} <= set(stats["timings_ms"][stage])


def test_same_numbers_twice(synthetic, synthetic_run, tmp_path):
    again = run_sequence(synthetic, load_config("synthetic"), tmp_path, progress=False)
    assert (tmp_path / "trajectory.txt").read_text() == (synthetic_run.out_dir / "trajectory.txt").read_text()
    assert again.ape_rmse == synthetic_run.ape_rmse


def test_online_api_tracks_and_saves(synthetic, tmp_path):
    with System(load_config("synthetic"), synthetic.intrinsics) as slam:
        results = [slam.track(f.rgb, f.depth, f.timestamp) for f in (synthetic[i] for i in range(30))]
        assert results[0].is_keyframe and results[0].state == "ok"
        assert all(r.state == "ok" for r in results)
        assert all(r.n_inliers > 50 for r in results[1:])
        traj = slam.trajectory()
        assert len(traj) == 30 and len(slam.keyframes()) >= 1
    slam.save(tmp_path)
    assert (tmp_path / "trajectory.txt").is_file() and (tmp_path / "config.yaml").is_file()
    with pytest.raises(RuntimeError):
        slam.track(synthetic[30].rgb, synthetic[30].depth, synthetic[30].timestamp)


def test_mask_hook_keeps_masked_pixels_out_of_the_map(synthetic):
    frame = synthetic[0]
    w = frame.depth.shape[1]
    mask = np.zeros(frame.depth.shape, bool)
    mask[:, : w // 2] = True
    intr = synthetic.intrinsics
    with System(load_config("synthetic"), intr) as slam:
        result = slam.track(frame.rgb, frame.depth, frame.timestamp, mask=mask)
        lmap = slam.tracker.map
        points = lmap.positions[: lmap.size]  # first keyframe is the world frame
    assert result.is_keyframe and len(points) > 50
    u = points[:, 0] / points[:, 2] * intr.fx + intr.cx
    assert u.min() >= w // 2 - 1.0
    with System(load_config("synthetic"), intr) as slam:
        slam.track(frame.rgb, frame.depth, frame.timestamp)
        lmap = slam.tracker.map
        u_all = lmap.positions[: lmap.size, 0] / lmap.positions[: lmap.size, 2] * intr.fx + intr.cx
    assert u_all.min() < w // 4


def test_online_api_rejects_bad_frames(synthetic):
    f = synthetic[0]
    with System(load_config("synthetic"), synthetic.intrinsics) as slam:
        with pytest.raises(ValueError, match="rgb"):
            slam.track(f.rgb[:, :, 0], f.depth, f.timestamp)
        with pytest.raises(ValueError, match="depth"):
            slam.track(f.rgb, f.depth[:100], f.timestamp)
        with pytest.raises(ValueError, match="mask"):
            slam.track(f.rgb, f.depth, f.timestamp, mask=np.zeros((5, 5), bool))
        slam.track(f.rgb, f.depth, f.timestamp)
        with pytest.raises(ValueError, match="timestamps must increase"):
            slam.track(f.rgb, f.depth, f.timestamp)
        raw = (f.depth * 5000).astype(np.uint16)
        assert slam.track(f.rgb, raw, f.timestamp + 0.1).state == "ok"


def test_timestamps_must_increase_from_the_first_frame_even_when_it_is_not_tracked(synthetic, tmp_path):
    cfg = load_config("synthetic", ["gating.enabled=true", f"models.dir={tmp_path}"])
    f, g = synthetic[0], synthetic[1]
    with System(cfg, synthetic.intrinsics) as slam:
        assert slam.track(f.rgb, f.depth, f.timestamp).state == "initializing"  # the gate has no motion yet
        for stamp in (f.timestamp, f.timestamp - 0.1):
            with pytest.raises(ValueError, match="timestamps must increase"):
                slam.track(g.rgb, g.depth, stamp)
        assert slam.track(g.rgb, g.depth, g.timestamp).state == "ok"


def test_depth_without_a_measurement_may_be_nan_or_infinite(synthetic, tmp_path):
    cfg = load_config("synthetic", ["gating.enabled=true", "gating.worker=thread", f"models.dir={tmp_path}",
                                    "mapping.enabled=false"])
    holes = np.random.default_rng(0).random(synthetic[0].depth.shape) < 0.3
    poses = {}
    for missing in (0.0, np.nan, np.inf):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # nothing downstream meets a NaN or an infinity
            with System(cfg, synthetic.intrinsics) as slam:
                for i in range(6):
                    f = synthetic[i]
                    slam.track(f.rgb, np.where(holes, missing, f.depth).astype(np.float32), f.timestamp)
                poses[str(missing)] = np.array([p.pose for p in slam.trajectory()])
    assert len(poses["0.0"]) >= 4
    assert np.array_equal(poses["0.0"], poses["nan"]) and np.array_equal(poses["0.0"], poses["inf"])


class _InterruptedAt:
    """A synthetic source whose reading is interrupted (Ctrl-C) at frame ``stop``."""

    def __init__(self, seq, stop):
        self.seq, self.stop = seq, stop
        self.name, self.intrinsics = seq.name, seq.intrinsics

    def __len__(self):
        return len(self.seq)

    def __getitem__(self, i):
        if i == self.stop:
            raise KeyboardInterrupt
        return self.seq[i]


def test_interrupted_run_keeps_what_was_tracked(synthetic, tmp_path):
    with pytest.raises(KeyboardInterrupt):
        run_sequence(_InterruptedAt(synthetic, 25), load_config("synthetic"), tmp_path, progress=False)
    rows = [l for l in (tmp_path / "trajectory.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert len(rows) == 25
    assert json.loads((tmp_path / "stats.json").read_text())["frames_in"] == 25
