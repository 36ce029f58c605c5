"""Evaluation: TUM file I/O and validation, APE/RPE on trajectories with known errors, reports."""

import json
import math

import numpy as np
import pytest
from evo.core.trajectory import PoseTrajectory3D
from scipy.spatial.transform import Rotation

from osslam.config import ConfigError, EvalConfig
from osslam.errors import InputError
from osslam.eval import EvaluationError, compute_metrics, evaluate_files, write_markdown
from osslam.eval.metrics import METRICS, STATISTICS, time_delta_ids, to_evo
from osslam.eval.plots import PLOT_FILES
from osslam.trajectory_io import read_tum, write_tum

T0 = 1305031102.175304  # a TUM-sized timestamp, to exercise rounding


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def _curve(n: int = 200) -> np.ndarray:
    """A closed, non-planar curve of camera poses; positions hold harmonics 1-3 of a full period."""
    th = 2 * np.pi * np.arange(n) / n
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(np.c_[0.2 * np.sin(th), 0.3 * np.cos(2 * th), th]).as_matrix()
    poses[:, :3, 3] = np.c_[np.cos(th) + 0.3 * np.sin(2 * th), np.sin(2 * th) + 0.2 * np.cos(th),
                            0.4 * np.cos(3 * th) + 0.1 * np.sin(th)]
    return poses


def _screw(n: int, step: np.ndarray) -> np.ndarray:
    """Poses Q_i = step^i: constant motion in the camera frame (a helix for a screw step)."""
    poses = [np.eye(4)]
    for _ in range(n - 1):
        poses.append(poses[-1] @ step)
    return np.array(poses)


def _traj(stamps, poses) -> PoseTrajectory3D:
    return PoseTrajectory3D(poses_se3=[p.copy() for p in poses], timestamps=np.asarray(stamps, float))


def _with_step_error(gt: np.ndarray, D: np.ndarray, start: np.ndarray) -> np.ndarray:
    """An estimate whose every relative motion is the true one followed by the error D."""
    est = [start @ gt[0]]
    for a, b in zip(gt[:-1], gt[1:]):
        est.append(est[-1] @ np.linalg.inv(a) @ b @ D)
    return np.array(est)


W = _pose([0.3, -1.1, 0.7], [2.0, -5.0, 1.5])  # an arbitrary rigid transform of the estimate's world frame


# ---------------------------------------------------------------- file I/O


def test_write_read_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    stamps = T0 + np.cumsum(rng.uniform(0.01, 0.05, 50))
    poses = np.array([_pose(rng.normal(size=3), rng.normal(scale=3.0, size=3)) for _ in range(50)])
    path = write_tum(tmp_path / "traj.txt", stamps, list(poses))
    traj = read_tum(path)
    assert len(traj) == 50
    np.testing.assert_allclose(traj.timestamps, stamps, rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.poses, poses, rtol=0, atol=1e-8)
    data_lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    assert len(data_lines) == 50 and all(len(ln.split()) == 8 for ln in data_lines)
    evo_traj = to_evo(traj)
    np.testing.assert_allclose(np.array(evo_traj.poses_se3), poses, atol=1e-8)
    np.testing.assert_allclose(evo_traj.orientations_quat_wxyz[:, 0], traj.quaternions[:, 3])


def test_read_skips_comments_and_blank_lines_and_normalises_quaternions(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text("# ground truth\n\n1.0 1 2 3 0 0 0 2\n  # note\n2.5 4 5 6 0 0 3 4\n\n")
    traj = read_tum(path)
    np.testing.assert_allclose(traj.timestamps, [1.0, 2.5])
    np.testing.assert_allclose(traj.positions, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_allclose(traj.quaternions, [[0, 0, 0, 1], [0, 0, 0.6, 0.8]])


GOOD = "1.0 0 0 0 0 0 0 1\n"


@pytest.mark.parametrize(
    "text, line, needle",
    [
        (GOOD + "2.0 0 0 0 0 0 1\n", 2, "expected 8 fields"),
        (GOOD + "2.0 0 0 0 0 0 0 1 7\n", 2, "expected 8 fields"),
        ("# header\n" + GOOD + "2.0 0 0 abc 0 0 0 1\n", 3, "not a number"),
        ("1.0 nan 0 0 0 0 0 1\n", 1, "not finite"),
        (GOOD + "2.0 0 0 0 0 0 0 inf\n", 2, "not finite"),
        (GOOD + "\n2.0 0 0 0 0 0 0 0\n", 3, "zero length"),
        (GOOD + "2.0 0 0 0 0 0 0 1\n\n2.0 0 0 0 0 0 0 1\n", 4, "does not increase"),
        (GOOD + "0.5 0 0 0 0 0 0 1\n", 2, "does not increase"),
    ],
)
def test_read_rejects_bad_lines_naming_file_and_line(tmp_path, text, line, needle):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_tum(path)
    assert info.value.line == line
    assert f"{path}:{line}:" in str(info.value)
    assert needle in str(info.value)


@pytest.mark.parametrize("text", ["", "# only a comment\n\n"])
def test_read_rejects_file_without_poses(tmp_path, text):
    path = tmp_path / "empty.txt"
    path.write_text(text)
    with pytest.raises(InputError, match="no poses") as info:
        read_tum(path)
    assert str(path) in str(info.value)


def test_read_rejects_missing_file(tmp_path):
    path = tmp_path / "nowhere.txt"
    with pytest.raises(InputError, match="not found") as info:
        read_tum(path)
    assert str(path) in str(info.value)


def test_write_tum_rejects_inconsistent_input_and_writes_empty_header(tmp_path):
    with pytest.raises(ValueError, match="timestamps"):
        write_tum(tmp_path / "a.txt", [1.0, 2.0], [np.eye(4)])
    with pytest.raises(ValueError, match="4x4"):
        write_tum(tmp_path / "a.txt", [1.0], [np.eye(4)[:3]])
    with pytest.raises(ValueError, match="finite"):
        write_tum(tmp_path / "a.txt", [math.nan], [np.eye(4)])
    empty = write_tum(tmp_path / "empty.txt", [], [])
    assert empty.read_text().startswith("#")
    with pytest.raises(InputError, match="no poses"):
        read_tum(empty)


# ---------------------------------------------------------------- metrics


def test_rigid_transform_of_ground_truth_has_zero_error():
    gt = _curve()
    stamps = T0 + 0.05 * np.arange(len(gt))
    errors = compute_metrics(_traj(stamps, gt), _traj(stamps, W @ gt), EvalConfig())
    assert errors.n_associated == len(gt)
    for name in METRICS:
        assert errors.stats[name]["max"] < 1e-6, name
    np.testing.assert_allclose(errors.alignment, np.linalg.inv(W), atol=1e-9)
    np.testing.assert_allclose(errors.aligned_estimate.positions_xyz, gt[:, :3, 3], atol=1e-9)


def test_alternating_offsets_give_known_ape():
    # Offsets +d, -d, +d, ... along one world axis: on a full period of a curve of low
    # harmonics they are uncorrelated with the positions, so no rigid motion absorbs them.
    d = 0.05
    gt = _curve(200)
    offsets = np.outer((-1.0) ** np.arange(len(gt)), d * np.array([2.0, -1.0, 2.0]) / 3.0)
    est = gt.copy()
    est[:, :3, 3] += offsets
    stamps = T0 + 0.05 * np.arange(len(gt))
    errors = compute_metrics(_traj(stamps, gt), _traj(stamps, W @ est), EvalConfig())
    ape = errors.stats["ape"]
    np.testing.assert_allclose(errors.ape_errors, d, rtol=1e-9)
    for stat in ("rmse", "mean", "median", "max", "min"):
        assert ape[stat] == pytest.approx(d, rel=1e-9), stat
    assert ape["sse"] == pytest.approx(len(gt) * d * d, rel=1e-9)
    assert ape["std"] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(errors.timestamps, stamps)


def test_rpe_of_constant_step_error_is_that_error():
    gt = _curve(120)
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    angle_deg, shift = 0.7, np.array([0.012, -0.004, 0.003])
    D = _pose(np.radians(angle_deg) * axis, shift)
    est = _with_step_error(gt, D, W)
    stamps = T0 + 0.05 * np.arange(len(gt))
    errors = compute_metrics(_traj(stamps, gt), _traj(stamps, est), EvalConfig())
    e = float(np.linalg.norm(shift))
    trans, rot = errors.stats["rpe_trans"], errors.stats["rpe_rot"]
    assert errors.n_rpe_pairs == len(gt) - 1
    for stat in ("rmse", "mean", "median", "max", "min"):
        assert trans[stat] == pytest.approx(e, rel=1e-7), stat
        assert rot[stat] == pytest.approx(angle_deg, rel=1e-6), stat
    assert trans["sse"] == pytest.approx((len(gt) - 1) * e * e, rel=1e-7)
    assert trans["std"] == pytest.approx(0.0, abs=1e-9)
    assert errors.stats["ape"]["rmse"] > 10 * e  # the step errors accumulate into drift


def test_rpe_per_second_and_per_frame_delta():
    # A helix: constant screw motion about z; step errors about/along z commute with it,
    # so k steps of error compose to k times the error.
    step = _pose([0, 0, np.radians(6.0)], [0.05, 0.0, 0.01])
    gt = _screw(101, step)
    stamps = T0 + 0.1 * np.arange(101)  # 10 Hz for 10 s
    e, phi = 0.002, 0.25
    shifted = compute_metrics(_traj(stamps, gt), _traj(stamps, _with_step_error(gt, _pose([0, 0, 0], [0, 0, e]), W)),
                              EvalConfig(rpe_delta_frames=5))
    assert shifted.n_rpe_pairs == 20 and shifted.n_rpe_pairs_per_second == 10
    assert shifted.stats["rpe_trans"]["mean"] == pytest.approx(5 * e, rel=1e-7)
    assert shifted.stats["rpe_trans_per_second"]["min"] == pytest.approx(10 * e, rel=1e-7)
    assert shifted.stats["rpe_trans_per_second"]["max"] == pytest.approx(10 * e, rel=1e-7)
    assert shifted.stats["rpe_rot_per_second"]["max"] < 1e-6
    turned = compute_metrics(_traj(stamps, gt),
                             _traj(stamps, _with_step_error(gt, _pose([0, 0, np.radians(phi)], [0, 0, 0]), W)),
                             EvalConfig())
    assert turned.stats["rpe_rot"]["rmse"] == pytest.approx(phi, rel=1e-6)
    assert turned.stats["rpe_rot_per_second"]["min"] == pytest.approx(10 * phi, rel=1e-6)
    assert turned.stats["rpe_rot_per_second"]["max"] == pytest.approx(10 * phi, rel=1e-6)


def test_time_delta_ids_chain_pairs_about_delta_apart():
    stamps = T0 + np.array([0.0, 0.4, 0.99995, 1.5, 2.2, 2.5, 4.0])
    assert time_delta_ids(stamps, 1.0) == [0, 2, 4, 6]


def test_association_with_small_time_offset():
    gt = _curve(300)
    stamps = T0 + 0.03 * np.arange(300)
    est_ids = np.arange(0, 300, 3)
    est = _traj(stamps[est_ids] + 0.004, W @ gt[est_ids])
    errors = compute_metrics(_traj(stamps, gt), est, EvalConfig(max_time_diff=0.01))
    assert errors.n_associated == len(est_ids)
    assert errors.n_estimate == len(est_ids) and errors.n_reference == 300
    assert errors.stats["ape"]["max"] < 1e-6
    with pytest.raises(EvaluationError, match="no estimated pose"):
        compute_metrics(_traj(stamps, gt), est, EvalConfig(max_time_diff=0.002))


def test_compute_metrics_leaves_inputs_unchanged():
    gt = _curve(100)
    stamps = T0 + 0.05 * np.arange(100)
    est_poses = W @ gt
    est_poses[:, :3, 3] += np.random.default_rng(3).normal(scale=0.02, size=(100, 3))
    ref, est = _traj(stamps, gt), _traj(stamps, est_poses)
    first = compute_metrics(ref, est, EvalConfig())
    second = compute_metrics(ref, est, EvalConfig())
    assert first.stats == second.stats
    assert first.stats["ape"]["rmse"] > 0.01
    np.testing.assert_array_equal(np.array(est.poses_se3), est_poses)
    np.testing.assert_array_equal(est.positions_xyz, est_poses[:, :3, 3])
    np.testing.assert_array_equal(est.timestamps, stamps)


def test_short_trajectory_has_nan_per_second_rpe():
    gt = _curve(20)
    stamps = T0 + np.arange(20) / 30.0  # 0.63 s
    errors = compute_metrics(_traj(stamps, gt), _traj(stamps, W @ gt), EvalConfig())
    assert errors.n_rpe_pairs_per_second == 0
    assert all(math.isnan(v) for v in errors.stats["rpe_trans_per_second"].values())
    assert errors.n_rpe_pairs == 19 and errors.stats["rpe_trans"]["max"] < 1e-6


def test_degenerate_and_misconfigured_inputs_raise():
    stamps = T0 + np.arange(10) * 0.1
    line = np.array([_pose([0, 0, 0], [0.1 * i, 0, 0]) for i in range(10)])
    with pytest.raises(EvaluationError, match="degenerate"):
        compute_metrics(_traj(stamps, line), _traj(stamps, line), EvalConfig())
    gt = _curve(10)
    with pytest.raises(EvaluationError, match="at least 3"):
        compute_metrics(_traj(stamps, gt), _traj(stamps[:2], gt[:2]), EvalConfig())
    with pytest.raises(ConfigError, match="rpe_delta_frames"):
        compute_metrics(_traj(stamps, gt), _traj(stamps, gt), EvalConfig(rpe_delta_frames=0))


# ---------------------------------------------------------------- report


def _write_pair(tmp_path, n=150, noise=0.01):
    gt = _curve(n)
    stamps = T0 + 0.05 * np.arange(n)
    est = W @ gt
    est[:, :3, 3] += np.random.default_rng(0).normal(scale=noise, size=(n, 3))
    gt_path = write_tum(tmp_path / "groundtruth.txt", stamps, gt)
    est_path = write_tum(tmp_path / "trajectory.txt", stamps + 0.002, est)
    return gt_path, est_path


def test_evaluate_files_writes_metrics_report_and_plots(tmp_path):
    gt_path, est_path = _write_pair(tmp_path)
    out = tmp_path / "results" / "eval"
    report = evaluate_files(gt_path, est_path, out, EvalConfig(), extra={"frames_in": 150, "mean ms per frame": 31.5})
    doc = json.loads((out / "metrics.json").read_text())
    assert set(doc) == {*METRICS, "info"}
    for name in METRICS:
        assert list(doc[name]) == list(STATISTICS)
        assert all(isinstance(v, float) for v in doc[name].values())
        assert doc[name] == pytest.approx(report.metrics[name])
    assert 0.005 < doc["ape"]["rmse"] < 0.03
    assert doc["info"]["poses_associated"] == 150
    assert doc["info"]["units"]["rpe_rot"] == "deg"
    assert doc["info"]["estimate"] == str(est_path)
    for name in PLOT_FILES.values():
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (out / "report.md").read_text()
    for row in ("| Max |", "| Mean |", "| Median |", "| Min |", "| RMSE |", "| SSE |", "| Std |"):
        assert row in md
    assert "| APE (m) | RPE trans (m) | RPE rot (deg) |" in md
    assert f"| RMSE | {doc['ape']['rmse']:.4f} |" in md
    assert "](trajectory_xy.png)" in md and "](ape_over_time.png)" in md
    assert "## Run" in md and "| frames_in | 150 |" in md and "| mean ms per frame | 31.5000 |" in md
    assert report.report_path == out / "report.md" and set(report.plots) == set(PLOT_FILES)


def test_evaluate_files_without_plots(tmp_path):
    gt_path, est_path = _write_pair(tmp_path)
    report = evaluate_files(gt_path, est_path, tmp_path / "out", EvalConfig(plots=False))
    assert report.plots == {}
    assert not list((tmp_path / "out").glob("*.png"))
    md = report.report_path.read_text()
    assert "## Plots" not in md and "## Run" not in md and "| RMSE |" in md


def test_evaluate_files_names_the_estimate_when_nothing_associates(tmp_path):
    gt = _curve(50)
    gt_path = write_tum(tmp_path / "gt.txt", T0 + 0.05 * np.arange(50), gt)
    est_path = write_tum(tmp_path / "est.txt", T0 + 100 + 0.05 * np.arange(50), gt)
    with pytest.raises(InputError, match="no estimated pose") as info:
        evaluate_files(gt_path, est_path, tmp_path / "out", EvalConfig())
    assert str(est_path) in str(info.value)
    assert not (tmp_path / "out").exists()


def test_metrics_json_writes_nan_as_null_and_markdown_as_na(tmp_path):
    gt = _curve(20)
    stamps = T0 + np.arange(20) / 30.0
    gt_path = write_tum(tmp_path / "gt.txt", stamps, gt)
    est_path = write_tum(tmp_path / "est.txt", stamps, W @ gt)
    report = evaluate_files(gt_path, est_path, tmp_path / "out", EvalConfig(plots=False))
    doc = json.loads(report.metrics_path.read_text())
    assert doc["rpe_trans_per_second"]["rmse"] is None
    assert isinstance(doc["rpe_trans"]["rmse"], float)
    md = write_markdown(tmp_path / "again.md", report.metrics, report.info).read_text()
    assert "| RMSE | n/a | n/a |" in md
