"""TUM reading: list files, association, intrinsics selection, lazy frames, ground truth and bad input."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from osslam.config import CameraConfig, Config, ConfigError, DatasetConfig
from osslam.datasets import TumSequence, open_sequence
from osslam.datasets.association import associate, read_file_list
from osslam.datasets.intrinsics import TUM_INTRINSICS, select_intrinsics, sensor_from_name
from osslam.errors import InputError

from conftest import FR1_XYZ

H, W = 48, 64
CAMERA = CameraConfig(model="custom", fx=50, fy=50, cx=32, cy=24, width=W, height=H)


def _write_sequence(root: Path, n: int = 4, depth_value: int = 5000, name: str = "rgbd_dataset_freiburg1_test",
                    groundtruth: bool = True) -> Path:
    """A tiny TUM folder: n frames at 30 Hz, depth 5 ms after colour, ground truth at 100 Hz from 9.9 s.

    Ground truth moves x = t - 9.9 metres and turns about z by t - 9.9 radians.
    """
    seq = root / name
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for i in range(n):
        t = 10.0 + i / 30
        bgr = np.zeros((H, W, 3), np.uint8)
        bgr[:] = (10, 20, 200)
        cv2.imwrite(str(seq / "rgb" / f"{i}.jpg"), bgr)
        cv2.imwrite(str(seq / "depth" / f"{i}.png"), np.full((H, W), depth_value, np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{i}.jpg")
        depth_lines.append(f"{t + 0.005:.6f} depth/{i}.png")
    (seq / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (seq / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if groundtruth:
        gt_lines = ["# timestamp tx ty tz qx qy qz qw"]
        for k in range(40):
            a = k * 0.01
            gt_lines.append(f"{9.9 + a:.4f} {a:.4f} 0 0 0 0 {np.sin(a / 2):.9f} {np.cos(a / 2):.9f}")
        (seq / "groundtruth.txt").write_text("\n".join(gt_lines) + "\n")
    return seq


def _replace_line(path: Path, number: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[number - 1] = text
    path.write_text("\n".join(lines) + "\n")


def _one_line_error(excinfo, *parts: str) -> str:
    message = str(excinfo.value)
    assert "\n" not in message
    for part in parts:
        assert part in message, f"{part!r} not in {message!r}"
    return message


# --------------------------------------------------------------------------- association


def test_association_pairs_nearest_stamps_one_to_one_within_the_limit():
    rgb = np.array([1.000, 1.033, 1.066, 1.100, 1.300])
    depth = np.array([0.990, 1.030, 1.040, 1.095, 1.200])
    # 1.066 has 1.040 at 0.026 s and 1.300 nothing: both left out at 0.02 s
    assert associate(rgb, depth, 0.02) == [(0, 0), (1, 1), (3, 3)]
    # with a generous limit everything pairs, still one-to-one
    assert associate(rgb, depth, 0.5) == [(0, 0), (1, 1), (2, 2), (3, 3), (4, 4)]


def test_association_gives_a_contested_stamp_to_the_nearest():
    # both colour stamps want depth 1.008; the nearer (1.01) wins, the other takes the next best
    assert associate(np.array([1.0, 1.01]), np.array([1.008]), 0.02) == [(1, 0)]
    assert associate(np.array([1.0, 1.01]), np.array([0.995, 1.008]), 0.02) == [(0, 0), (1, 1)]
    # greedy on the smallest difference overall, not first come first served
    assert associate(np.array([1.000, 1.012]), np.array([1.010, 1.030]), 0.02) == [(1, 0)]


def test_association_limit_is_inclusive_and_result_sorted_by_colour():
    assert associate(np.array([2.0, 1.0]), np.array([1.0, 2.0]), 0.0) == [(0, 1), (1, 0)]
    assert associate(np.array([1.0]), np.array([1.25]), 0.25) == [(0, 0)]
    assert associate(np.array([1.0]), np.array([1.2501]), 0.25) == []
    assert associate(np.array([1.0]), np.array([]), 0.02) == []
    with pytest.raises(ValueError):
        associate(np.array([1.0]), np.array([1.0]), -0.1)


def test_read_file_list_skips_comments_and_reports_bad_lines(tmp_path):
    good = tmp_path / "rgb.txt"
    good.write_text("# color images\n\n1.5 rgb/a.jpg\n  2.25 rgb/b.jpg  \n")
    listing = read_file_list(good)
    assert listing.timestamps.tolist() == [1.5, 2.25] and listing.files == ["rgb/a.jpg", "rgb/b.jpg"]
    cases = {
        "# c\n1.0 a.png\n2.0\n": ("rgb.txt:3", "timestamp filename"),
        "# c\n1.0 a.png\nabc b.png\n": ("rgb.txt:3", "not a number"),
        "1.0 a.png\nnan b.png\n": ("rgb.txt:2", "not finite"),
        "# c\n2.0 a.png\n1.0 b.png\n": ("rgb.txt:3", "increase"),
        "1.0 a.png\n1.0 b.png\n": ("rgb.txt:2", "increase"),
        "# only a comment\n\n": ("rgb.txt", "no entries"),
    }
    for text, parts in cases.items():
        good.write_text(text)
        with pytest.raises(InputError) as err:
            read_file_list(good)
        _one_line_error(err, *parts)
    with pytest.raises(InputError, match="not found"):
        read_file_list(tmp_path / "absent.txt")


# --------------------------------------------------------------------------- intrinsics


def test_sensor_from_folder_name():
    assert sensor_from_name("rgbd_dataset_freiburg1_xyz") == "freiburg1"
    assert sensor_from_name("rgbd_dataset_freiburg2_desk") == "freiburg2"
    assert sensor_from_name("rgbd_dataset_freiburg3_walking_xyz") == "freiburg3"
    assert sensor_from_name("copy_of_Freiburg3walking") == "freiburg3"
    assert sensor_from_name("fr2_desk") == "freiburg2"
    assert sensor_from_name("tum-fr1-room") == "freiburg1"
    assert sensor_from_name("my_office") is None
    assert sensor_from_name("frame1") is None
    assert sensor_from_name("fr12_run") is None


def test_intrinsics_from_folder_name_and_overrides(tmp_path):
    for n in (1, 2, 3):
        folder = tmp_path / f"rgbd_dataset_freiburg{n}_desk"
        folder.mkdir()
        assert select_intrinsics(folder, CameraConfig()) == TUM_INTRINSICS[f"freiburg{n}"]
    fr1 = tmp_path / "rgbd_dataset_freiburg1_desk"
    assert TUM_INTRINSICS["freiburg1"].fx == 517.3 and TUM_INTRINSICS["freiburg1"].dist[4] == 1.1633
    assert TUM_INTRINSICS["freiburg2"].cy == 249.7 and not TUM_INTRINSICS["freiburg3"].has_distortion
    assert select_intrinsics(fr1, CameraConfig(model="freiburg3")) == TUM_INTRINSICS["freiburg3"]
    custom = CameraConfig(model="custom", fx=600, fy=601, cx=320, cy=240, dist=[0.1, 0, 0, 0, 0], width=800,
                          height=600)
    intr = select_intrinsics(fr1, custom)
    assert (intr.fx, intr.fy, intr.cx, intr.cy, intr.dist[0], intr.width, intr.height) == (600, 601, 320, 240, 0.1,
                                                                                            800, 600)


def test_intrinsics_errors(tmp_path):
    unnamed = tmp_path / "office"
    unnamed.mkdir()
    with pytest.raises(InputError) as err:
        select_intrinsics(unnamed, CameraConfig())
    _one_line_error(err, "office", "camera.model")
    with pytest.raises(ConfigError, match="kinect9"):
        select_intrinsics(unnamed, CameraConfig(model="kinect9"))
    with pytest.raises(ConfigError, match="custom"):
        select_intrinsics(unnamed, CameraConfig(model="custom"))  # fx = 0
    with pytest.raises(ConfigError, match="dist"):
        select_intrinsics(unnamed, CameraConfig(model="custom", fx=500, fy=500, cx=320, cy=240, dist=[0.1]))


def test_camera_yaml_takes_precedence_over_the_folder_name(tmp_path):
    folder = tmp_path / "rgbd_dataset_freiburg1_copy"
    folder.mkdir()
    camera_file = folder / "camera.yaml"
    camera_file.write_text("fx: 400.0\nfy: 410.0\ncx: 160.0\ncy: 120.0\nwidth: 320\nheight: 240\n"
                           "dist: [0.0, 0.0, 0.0, 0.0, 0.0]\n")
    intr = select_intrinsics(folder, CameraConfig())
    assert (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height) == (400, 410, 160, 120, 320, 240)
    # an explicit model still wins over the file
    assert select_intrinsics(folder, CameraConfig(model="freiburg2")) == TUM_INTRINSICS["freiburg2"]
    for text, part in (("fx: 400\nfy: 410\n", "missing cx"), ("fx: [unclosed\n", "invalid YAML"),
                       ("fx: 0\nfy: 1\ncx: 1\ncy: 1\nwidth: 2\nheight: 2\n", "positive")):
        camera_file.write_text(text)
        with pytest.raises(InputError) as err:
            select_intrinsics(folder, CameraConfig())
        _one_line_error(err, "camera.yaml", part)


# --------------------------------------------------------------------------- TUM reader


def test_tum_reader_loads_frames_lazily_with_interpolated_ground_truth(tmp_path):
    folder = _write_sequence(tmp_path, n=4)
    seq = TumSequence(folder, DatasetConfig(), CAMERA)
    assert len(seq) == 4 and seq.name == "rgbd_dataset_freiburg1_test"
    assert seq.timestamps.tolist() == pytest.approx([10.0 + i / 30 for i in range(4)])
    assert seq.groundtruth_path == folder / "groundtruth.txt"
    assert seq.intrinsics.fx == 50 and (seq.intrinsics.width, seq.intrinsics.height) == (W, H)
    (folder / "rgb" / "3.jpg").unlink()  # lazily loaded: opening did not read it, frame 2 still loads
    frame = seq[2]
    assert frame.index == 2 and frame.timestamp == pytest.approx(10.0 + 2 / 30)
    assert frame.rgb.shape == (H, W, 3) and frame.rgb.dtype == np.uint8
    assert frame.rgb[..., 0].min() > 180 and frame.rgb[..., 2].max() < 40  # BGR file, RGB frame
    assert frame.depth.dtype == np.float32 and frame.depth.shape == (H, W) and np.allclose(frame.depth, 1.0)
    assert frame.source.endswith("2.jpg")
    # ground truth between two 100 Hz stamps: x and the angle about z both equal t - 9.9
    elapsed = frame.timestamp - 9.9
    assert frame.gt_pose[:3, 3] == pytest.approx([elapsed, 0, 0], abs=1e-9)
    angle = Rotation.from_matrix(frame.gt_pose[:3, :3]).as_rotvec()
    assert angle == pytest.approx([0, 0, elapsed], abs=1e-7)
    assert seq[-2].index == 2
    with pytest.raises(IndexError):
        seq[4]
    with pytest.raises(InputError, match="3.jpg"):
        list(seq)


def test_ground_truth_is_none_outside_its_range_or_across_a_gap(tmp_path):
    folder = _write_sequence(tmp_path, n=10)  # frames up to 10.3 s, ground truth up to 10.29 s
    gt = folder / "groundtruth.txt"
    lines = gt.read_text().splitlines()
    # drop the stamps 10.00-10.06 so frame 1 (10.0333) falls in a 0.08 s gap
    gt.write_text("\n".join(line for line in lines if not line.startswith(("10.00", "10.01", "10.02", "10.03",
                                                                            "10.04", "10.05", "10.06"))) + "\n")
    seq = TumSequence(folder, DatasetConfig(), CAMERA)
    assert seq[1].gt_pose is None
    assert seq[9].gt_pose is None
    assert seq[3].gt_pose is not None
    assert seq.groundtruth.poses.shape == (len(seq.groundtruth.timestamps), 4, 4)


def test_sequence_without_ground_truth(tmp_path):
    seq = TumSequence(_write_sequence(tmp_path, groundtruth=False), DatasetConfig(), CAMERA)
    assert seq.groundtruth_path is None and seq.groundtruth is None
    assert all(frame.gt_pose is None for frame in seq)


def test_start_frame_stride_and_max_frames(tmp_path):
    folder = _write_sequence(tmp_path, n=10)
    seq = TumSequence(folder, DatasetConfig(start_frame=1, stride=2, max_frames=3), CAMERA)
    assert seq.timestamps.tolist() == pytest.approx([10.0 + k / 30 for k in (1, 3, 5)])
    assert [f.index for f in seq] == [0, 1, 2]
    assert len(TumSequence(folder, DatasetConfig(start_frame=7), CAMERA)) == 3
    with pytest.raises(InputError, match="start_frame"):
        TumSequence(folder, DatasetConfig(start_frame=10), CAMERA)
    with pytest.raises(ConfigError, match="stride"):
        TumSequence(folder, DatasetConfig(stride=0), CAMERA)


def test_missing_list_files_are_named(tmp_path):
    folder = _write_sequence(tmp_path)
    (folder / "depth.txt").unlink()
    with pytest.raises(InputError) as err:
        TumSequence(folder, DatasetConfig(), CAMERA)
    _one_line_error(err, "depth.txt", "not found")
    (folder / "rgb.txt").unlink()
    with pytest.raises(InputError) as err:
        TumSequence(folder, DatasetConfig(), CAMERA)
    _one_line_error(err, "rgb.txt", "not found")


@pytest.mark.parametrize("image", ["rgb/1.jpg", "depth/1.png"])
def test_unreadable_or_missing_image_names_the_file(tmp_path, image):
    folder = _write_sequence(tmp_path)
    (folder / image).write_bytes(b"\x89PNG\r\n\x1a\n garbage, not an image")
    seq = TumSequence(folder, DatasetConfig(), CAMERA)
    assert seq[0].rgb.shape == (H, W, 3)
    with pytest.raises(InputError) as err:
        seq[1]
    _one_line_error(err, image, "cannot decode")
    assert err.value.path == str(folder / image)
    (folder / image).unlink()
    with pytest.raises(InputError) as err:
        seq[1]
    _one_line_error(err, image, "not found")


def test_depth_must_be_single_channel_16_bit(tmp_path):
    folder = _write_sequence(tmp_path)
    cv2.imwrite(str(folder / "depth" / "0.png"), np.full((H, W), 200, np.uint8))
    with pytest.raises(InputError) as err:
        TumSequence(folder, DatasetConfig(), CAMERA)[0]
    _one_line_error(err, "depth/0.png", "16-bit")


def test_image_size_must_match_the_camera(tmp_path):
    seq = TumSequence(_write_sequence(tmp_path), DatasetConfig(), CameraConfig(model="freiburg1"))
    with pytest.raises(InputError) as err:
        seq[0]
    _one_line_error(err, "rgb/0.jpg", "64x48", "640x480")


def test_no_associable_frames(tmp_path):
    folder = _write_sequence(tmp_path)
    (folder / "depth.txt").write_text("100.0 depth/0.png\n")
    with pytest.raises(InputError) as err:
        TumSequence(folder, DatasetConfig(), CAMERA)
    _one_line_error(err, "no colour frame", "max_time_diff")


def test_malformed_ground_truth_line_names_file_and_line(tmp_path):
    folder = _write_sequence(tmp_path)
    gt = folder / "groundtruth.txt"
    original = gt.read_text()
    for bad in ("9.93 1 2 three 0 0 0 1", "9.93 1 2 3 0 0 0", "9.93 nan 0 0 0 0 0 1", "9.90 0 0 0 0 0 0 1"):
        gt.write_text(original)
        _replace_line(gt, 5, bad)
        with pytest.raises(InputError) as err:
            TumSequence(folder, DatasetConfig(), CAMERA)
        _one_line_error(err, "groundtruth.txt:5")


def test_non_monotonic_timestamps_in_a_list_name_file_and_line(tmp_path):
    folder = _write_sequence(tmp_path)
    _replace_line(folder / "rgb.txt", 4, "9.5 rgb/1.jpg")
    with pytest.raises(InputError) as err:
        TumSequence(folder, DatasetConfig(), CAMERA)
    _one_line_error(err, "rgb.txt:4", "increase")


@pytest.mark.parametrize("scale", [1.0, 1e6])
def test_wrong_depth_scale_is_reported(tmp_path, scale):
    seq = TumSequence(_write_sequence(tmp_path), DatasetConfig(depth_scale=scale), CAMERA)
    with pytest.raises(InputError) as err:
        seq[0]
    _one_line_error(err, "depth/0.png", "dataset.depth_scale", "implausible")


def test_open_sequence(tmp_path):
    with pytest.raises(InputError, match="not found"):
        open_sequence(tmp_path / "absent", Config())
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        open_sequence(f, Config())
    with pytest.raises(InputError, match="no rgb.txt"):
        open_sequence(tmp_path, Config())
    cfg = Config(camera=CAMERA)
    seq = open_sequence(_write_sequence(tmp_path), cfg)
    assert isinstance(seq, TumSequence) and len(seq) == 4


@pytest.mark.skipif(not (FR1_XYZ / "rgb.txt").is_file(), reason=f"{FR1_XYZ} not present")
def test_real_fr1_xyz():
    seq = open_sequence(FR1_XYZ, Config())
    # 798 colour and 798 depth stamps; TUM's associate.py (0.02 s) pairs 792 of them
    assert len(seq) == 792
    assert seq.intrinsics == TUM_INTRINSICS["freiburg1"]
    assert seq.timestamps[0] == pytest.approx(1305031102.175304)
    assert np.all(np.diff(seq.timestamps) > 0)
    frame = seq[100]
    assert frame.rgb.shape == (480, 640, 3) and frame.depth.shape == (480, 640)
    valid = frame.depth[frame.depth > 0]
    assert valid.size > 0.5 * frame.depth.size and 0.5 < np.median(valid) < 3.0
    assert frame.gt_pose is not None
    assert np.allclose(frame.gt_pose[:3, :3] @ frame.gt_pose[:3, :3].T, np.eye(3))
    # the motion capture has one 0.11 s gap (at 1305031108.8): the 4 frames inside it get no ground truth
    without = [t for t in seq.timestamps if seq.groundtruth.pose_at(t) is None]
    assert len(without) == 4 and all(1305031108.8 < t < 1305031108.95 for t in without)
