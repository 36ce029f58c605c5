"""The command line: light start-up, one-line errors naming the bad file, eval alone."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from osslam.cli import main
from osslam.trajectory_io import write_tum
from osslam.geometry import se3_exp


def test_help_imports_no_heavy_library():
    code = (
        "import sys\n"
        "from osslam.cli import main\n"
        "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
        "heavy = [m for m in ('torch', 'open3d', 'gtsam', 'cv2', 'evo', 'matplotlib') if m in sys.modules]\n"
        "print('HEAVY', heavy)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "usage: osslam" in out
    assert "HEAVY []" in out


def _one_line_error(capsys, argv, expect_in_message):
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and "Traceback" not in err[0]
    assert expect_in_message in err[0]
    return err[0]


def _tiny_sequence(root: Path) -> Path:
    import cv2

    seq = root / "rgbd_dataset_freiburg1_tiny"
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    rgb_lines, depth_lines = [], []
    for i in range(3):
        t = 100.0 + i / 30
        cv2.imwrite(str(seq / "rgb" / f"{t:.6f}.png"), np.full((480, 640, 3), 100, np.uint8))
        cv2.imwrite(str(seq / "depth" / f"{t:.6f}.png"), np.full((480, 640), 5000, np.uint16))
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{t:.6f} depth/{t:.6f}.png")
    (seq / "rgb.txt").write_text("# rgb\n" + "\n".join(rgb_lines) + "\n")
    (seq / "depth.txt").write_text("# depth\n" + "\n".join(depth_lines) + "\n")
    return seq


def test_run_missing_depth_list(tmp_path, capsys):
    seq = _tiny_sequence(tmp_path)
    (seq / "depth.txt").unlink()
    _one_line_error(capsys, ["run", str(seq), "--out", str(tmp_path / "out")], "depth.txt")


def test_run_unreadable_image(tmp_path, capsys):
    seq = _tiny_sequence(tmp_path)
    bad = sorted((seq / "rgb").iterdir())[0]
    bad.write_bytes(b"not an image")
    _one_line_error(capsys, ["run", str(seq), "--out", str(tmp_path / "out")], bad.name)


def test_run_no_associable_frames(tmp_path, capsys):
    seq = _tiny_sequence(tmp_path)
    lines = (seq / "depth.txt").read_text().splitlines()
    shifted = [lines[0]] + [f"{float(l.split()[0]) + 5:.6f} {l.split()[1]}" for l in lines[1:]]
    (seq / "depth.txt").write_text("\n".join(shifted) + "\n")
    _one_line_error(capsys, ["run", str(seq), "--out", str(tmp_path / "out")], str(seq.name))


def test_run_missing_folder(tmp_path, capsys):
    _one_line_error(capsys, ["run", str(tmp_path / "nowhere"), "--out", str(tmp_path / "out")], "nowhere")


def test_an_output_folder_taken_by_a_file_is_one_line_error(tmp_path, capsys):
    seq = _tiny_sequence(tmp_path)
    taken = tmp_path / "taken"
    taken.write_text("not a folder")
    _one_line_error(capsys, ["run", str(seq), "--out", str(taken)], f"{taken}: File exists")
    gt, est = _trajectories(tmp_path)
    _one_line_error(capsys, ["eval", str(gt), str(est), "--out", str(taken / "eval")], str(taken))
    assert taken.read_text() == "not a folder"


def _trajectories(tmp_path):
    stamps = np.arange(100) / 30.0
    poses = [se3_exp(np.array([0.3 * np.sin(t), 0.2 * np.cos(t), 0.1 * t, 0.05 * t, 0.1 * np.sin(t), 0.0]))
             for t in stamps]
    gt, est = tmp_path / "gt.txt", tmp_path / "est.txt"
    write_tum(gt, stamps, poses)
    write_tum(est, stamps, poses)
    return gt, est


def test_eval_alone(tmp_path, capsys):
    gt, est = _trajectories(tmp_path)
    assert main(["eval", str(gt), str(est), "--out", str(tmp_path / "ev")]) == 0
    out = capsys.readouterr().out
    assert "ape" in out and (tmp_path / "ev" / "metrics.json").is_file()


def test_eval_malformed_groundtruth_line(tmp_path, capsys):
    gt, est = _trajectories(tmp_path)
    lines = gt.read_text().splitlines()
    lines[5] = "1.0 2.0 oops"
    gt.write_text("\n".join(lines) + "\n")
    msg = _one_line_error(capsys, ["eval", str(gt), str(est), "--out", str(tmp_path / "ev")], str(gt))
    assert ":6" in msg


def test_eval_empty_estimate(tmp_path, capsys):
    gt, est = _trajectories(tmp_path)
    est.write_text("# nothing\n")
    _one_line_error(capsys, ["eval", str(gt), str(est), "--out", str(tmp_path / "ev")], str(est))


@pytest.mark.parametrize("argv", [["run"], ["eval", "a"]])
def test_usage_errors_exit_2(argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2


def test_preset_follows_the_sensor_in_the_folder_name(tmp_path):
    from osslam.cli import _preset_for

    assert _preset_for(tmp_path / "rgbd_dataset_freiburg2_desk", None) == "tum_fr2"
    assert _preset_for(tmp_path / "fr3_walking_xyz", None) == "tum_fr3"
    assert _preset_for(tmp_path / "my_office", None) is None
    assert _preset_for(tmp_path / "fr3_walking_xyz", "synthetic") == "synthetic"
