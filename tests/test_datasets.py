"""Dataset readers: TUM lists, association, intrinsics selection, lazy frames, bad input; synthetic room."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from osslam.config import CameraConfig, Config, ConfigError, DatasetConfig
from osslam.datasets import open_sequence
from osslam.datasets.association import associate, read_file_list
from osslam.datasets.intrinsics import TUM_INTRINSICS, select_intrinsics, sensor_from_name
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.datasets.tum import TumSequence
from osslam.errors import InputError

FR1_XYZ = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "tum" / "rgbd_dataset_freiburg1_xyz"


def test_association_is_nearest_one_to_one_within_limit():
    rgb = np.array([1.000, 1.033, 1.066, 1.100, 1.300])
    depth = np.array([0.990, 1.030, 1.040, 1.095, 1.200])
    pairs = associate(rgb, depth, 0.02)
    # 1.066 and 1.300 have no depth stamp within 0.02 s
    assert pairs == [(0, 0), (1, 1), (3, 3)]
    # one-to-one: two colour stamps near one depth stamp, only the nearest gets it
    assert associate(np.array([1.0, 1.01]), np.array([1.008]), 0.02) == [(1, 0)]
    assert associate(rgb, depth, 0.5) == [(0, 0), (1, 1), (2, 2), (3, 3), (4, 4)]
    assert associate(rgb, np.array([]), 0.02) == []


def test_sensor_from_folder_name():
    assert sensor_from_name("rgbd_dataset_freiburg1_xyz") == "freiburg1"
    assert sensor_from_name("rgbd_dataset_freiburg3_walking_xyz") == "freiburg3"
    assert sensor_from_name("fr2_desk") == "freiburg2"
    assert sensor_from_name("my_office") is None


def test_intrinsics_selection_and_override(tmp_path):
    for n in (1, 2, 3):
        folder = tmp_path / f"rgbd_dataset_freiburg{n}_desk"
        folder.mkdir()
        assert select_intrinsics(folder, CameraConfig()) == TUM_INTRINSICS[f"freiburg{n}"]
    fr1 = tmp_path / "rgbd_dataset_freiburg1_desk"
    assert select_intrinsics(fr1, CameraConfig(model="freiburg3")).fx == 535.4
    custom = CameraConfig(model="custom", fx=600, fy=601, cx=320, cy=240, dist=[0.1, 0, 0, 0, 0])
    intr = select_intrinsics(fr1, custom)
    assert (intr.fx, intr.fy, intr.dist[0]) == (600, 601, 0.1)
    unnamed = tmp_path / "office"
    unnamed.mkdir()
    with pytest.raises(InputError, match="camera.model"):
        select_intrinsics(unnamed, CameraConfig())
    with pytest.raises(ConfigError):
        select_intrinsics(fr1, CameraConfig(model="kinect9"))


def _write_sequence(root: Path, n=4, depth_value=5000, name="rgbd_dataset_freiburg1_test") -> Path:
    seq = root / name
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    rgb_lines, depth_lines, gt_lines = ["# rgb"], ["# depth"], ["# gt"]
    for i in range(n):
        t = 10.0 + i / 30
        img = np.zeros((48, 64, 3), np.uint8)
        img[:, :, 2] = 200  # red in BGR
        cv2.imwrite(str(seq / "rgb" / f"{i}.jpg"), img)
        cv2.imwrite(str(seq / "depth" / f"{i}.png"), np.full((48, 64), depth_value, np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{i}.jpg")
        depth_lines.append(f"{t + 0.005:.6f} depth/{i}.png")
    for k in range(40):
        t = 9.9 + k * 0.01
        gt_lines.append(f"{t:.4f} {k * 0.01:.4f} 0 0 0 0 0 1")
    (seq / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (seq / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (seq / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    return seq


def _open(seq: Path) -> TumSequence:
    return TumSequence(seq, DatasetConfig(), CameraConfig(model="custom", fx=50, fy=50, cx=32, cy=24))


def test_tum_reader_loads_lazily_with_interpolated_ground_truth(tmp_path):
    seq = _open(_write_sequence(tmp_path))
    assert len(seq) == 4
    frame = seq[2]
    assert frame.rgb.shape == (48, 64, 3) and frame.rgb[0, 0, 0] > 150  # converted to RGB order
    assert frame.depth.dtype == np.float32 and np.allclose(frame.depth, 1.0)
    assert frame.gt_pose is not None
    assert frame.gt_pose[0, 3] == pytest.approx((frame.timestamp - 9.9) * 1.0, abs=1e-6)
    assert seq.groundtruth_path.name == "groundtruth.txt"
    assert [f.index for f in seq] == [0, 1, 2, 3]


def test_stride_start_and_max_frames(tmp_path):
    seq = TumSequence(_write_sequence(tmp_path, n=10), DatasetConfig(start_frame=1, stride=2, max_frames=3),
                      CameraConfig(model="freiburg1"))
    assert len(seq) == 3
    assert seq.timestamps[0] == pytest.approx(10.0 + 1 / 30)


def test_missing_depth_list(tmp_path):
    seq = _write_sequence(tmp_path)
    (seq / "depth.txt").unlink()
    with pytest.raises(InputError, match="depth.txt"):
        _open(seq)


def test_unreadable_image_names_the_file(tmp_path):
    seq = _write_sequence(tmp_path)
    (seq / "depth" / "1.png").write_bytes(b"\x89PNG garbage")
    reader = _open(seq)
    reader[0]
    with pytest.raises(InputError, match=r"depth/1\.png"):
        reader[1]


def test_no_associable_frames(tmp_path):
    seq = _write_sequence(tmp_path)
    (seq / "depth.txt").write_text("100.0 depth/0.png\n")
    with pytest.raises(InputError, match="no colour frame"):
        _open(seq)


def test_malformed_groundtruth_line_names_file_and_line(tmp_path):
    seq = _write_sequence(tmp_path)
    lines = (seq / "groundtruth.txt").read_text().splitlines()
    lines[3] = "10.0 1 2 three 0 0 0 1"
    (seq / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as err:
        _open(seq)
    assert "groundtruth.txt:4" in str(err.value)


def test_nan_ground_truth_and_non_monotonic_list(tmp_path):
    seq = _write_sequence(tmp_path)
    gt = (seq / "groundtruth.txt").read_text().splitlines()
    gt[2] = "9.92 nan 0 0 0 0 0 1"
    (seq / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    with pytest.raises(InputError, match="groundtruth.txt:3"):
        _open(seq)
    rgb = seq / "rgb.txt"
    rgb.write_text("# rgb\n2.0 rgb/0.jpg\n1.0 rgb/1.jpg\n")
    with pytest.raises(InputError, match=r"rgb\.txt:3.*increase"):
        read_file_list(rgb)


def test_wrong_depth_scale_is_reported(tmp_path):
    seq = TumSequence(_write_sequence(tmp_path), DatasetConfig(depth_scale=1.0), CameraConfig(model="freiburg1"))
    with pytest.raises(InputError, match="depth_scale"):
        seq[0]


def test_open_sequence_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        open_sequence(tmp_path / "absent", Config())
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        open_sequence(f, Config())


@pytest.mark.skipif(not (FR1_XYZ / "rgb.txt").is_file(), reason=f"{FR1_XYZ} not present")
def test_real_fr1_xyz():
    seq = open_sequence(FR1_XYZ, Config())
    assert len(seq) == 792
    assert seq.intrinsics == TUM_INTRINSICS["freiburg1"]
    frame = seq[100]
    valid = frame.depth[frame.depth > 0]
    assert 0.5 < np.median(valid) < 3.0
    assert frame.gt_pose is not None and np.allclose(frame.gt_pose[:3, :3] @ frame.gt_pose[:3, :3].T, np.eye(3))


# --------------------------------------------------------------------------- synthetic


def test_synthetic_is_reproducible_from_its_seed():
    a = SyntheticSequence(SyntheticConfig(n_frames=5, seed=1))[3]
    b = SyntheticSequence(SyntheticConfig(n_frames=5, seed=1))[3]
    c = SyntheticSequence(SyntheticConfig(n_frames=5, seed=2))[3]
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
    assert np.array_equal(a.gt_pose, b.gt_pose)
    assert not np.array_equal(a.rgb, c.rgb)


def test_synthetic_depth_lands_on_room_surfaces():
    seq = SyntheticSequence(SyntheticConfig(n_frames=3, depth_noise=False, dropout=0.0))
    f = seq[1]
    K = seq.intrinsics
    rng = np.random.default_rng(0)
    v, u = rng.integers(0, 480, 200), rng.integers(0, 640, 200)
    z = f.depth[v, u].astype(np.float64)
    pc = np.column_stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z])
    pw = pc @ f.gt_pose[:3, :3].T + f.gt_pose[:3, 3]
    lo, hi = np.array([-3.0, -1.5, -2.5]), np.array([3.0, 1.5, 2.5])
    on_wall = (np.abs(pw - lo) < 1e-3).any(axis=1) | (np.abs(pw - hi) < 1e-3).any(axis=1)
    inside = np.all((pw > lo - 1e-3) & (pw < hi + 1e-3), axis=1)
    assert inside.all()
    # most samples hit a wall; the rest hit a box face (one coordinate on the box boundary)
    assert on_wall.mean() > 0.5


def test_synthetic_frames_have_texture_for_orb_and_noise_when_asked():
    seq = SyntheticSequence(SyntheticConfig(n_frames=2))
    f = seq[0]
    assert len(cv2.ORB_create(1000).detect(cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY))) > 500
    assert 0.005 < (f.depth == 0).mean() < 0.05


def test_synthetic_write_tum_round_trips(tmp_path):
    seq = SyntheticSequence(SyntheticConfig(n_frames=4, seed=5))
    folder = seq.write_tum(tmp_path / "synth")
    back = TumSequence(folder, DatasetConfig(), CameraConfig())
    assert len(back) == 4
    assert back.intrinsics == seq.intrinsics
    for i in range(4):
        a, b = seq[i], back[i]
        assert np.allclose(a.gt_pose, b.gt_pose, atol=1e-6)
        assert np.abs(a.depth - b.depth).max() < 1e-3
        assert np.array_equal(a.rgb, b.rgb)
