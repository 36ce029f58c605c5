"""osslam synth: movers composited into a real-format sequence with honest z-tests and masks."""

import cv2
import numpy as np
import pytest
import yaml

from osslam.cli import main
from osslam.config import CameraConfig, DatasetConfig
from osslam.datasets.composite import (CompositeConfig, Compositor, Mover, composite_sequence, filled_depth,
                                       person_cutout, write_composite)
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.datasets.tum import TumSequence
from osslam.types import CameraIntrinsics

from conftest import MODELS

PERSON = MODELS / "samples" / "person.jpg"
SELFIE = MODELS / "mediapipe-selfie-segmentation" / "selfie_segmentation.tflite"


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    folder = tmp_path_factory.mktemp("room") / "room"
    return SyntheticSequence(SyntheticConfig(n_frames=20, seed=1)).write_tum(folder)


def _read(folder):
    return TumSequence(folder, DatasetConfig(), CameraConfig())


def test_composite_draws_movers_in_front_and_leaves_the_rest(room, tmp_path):
    out = composite_sequence(_read(room), tmp_path / "comp", CompositeConfig(seed=2, n_boxes=2))
    src, comp = _read(room), _read(out)
    assert len(comp) == len(src) == 20
    covered = []
    for i in (0, 10, 19):
        mask = cv2.imread(str(out / "masks" / f"{src.timestamps[i]:.6f}.png"), cv2.IMREAD_UNCHANGED) > 0
        a, b = src[i], comp[i]
        covered.append(mask.mean())
        assert np.array_equal(a.rgb[~mask], b.rgb[~mask])
        assert np.abs(a.depth[~mask] - b.depth[~mask]).max() < 1e-3
        if mask.any():  # movers only where they are in front
            assert np.all(b.depth[mask] < filled_depth(a.depth)[mask] + 1e-3)
    assert max(covered) > 0.02
    assert (out / "masks.txt").is_file() and (out / "synth.yaml").is_file()
    again = composite_sequence(_read(room), tmp_path / "again", CompositeConfig(seed=2, n_boxes=2))
    assert np.array_equal(_read(again)[10].rgb, comp[10].rgb)


def _box_at(distance: float) -> Mover:
    """A still 0.1 m box on the optical axis, its front face ``distance`` metres from the camera."""
    return Mover("box", np.array([0.05, 0.05, 0.05]), np.array([0.0, 0.0, distance + 0.05]),
                 np.array([1.0, 0.0, 0.0]), 0.0, 1.0, 0.0, np.eye(3), np.full((8, 8, 3), 200, np.uint8))


def test_movers_do_not_show_through_missing_depth():
    intrinsics = CameraIntrinsics(100.0, 100.0, 32.0, 24.0, 64, 48)
    rgb = np.zeros((48, 64, 3), np.uint8)
    wall = np.full((48, 64), 1.5)
    wall[14:34, 20:44] = 0.0  # a screen the sensor measured nothing on, larger than the box's image
    for distance in (1.0, 2.0):
        box = Compositor(intrinsics, [_box_at(distance)])
        _, _, alone = box.render(rgb, np.full((48, 64), 9.0), np.eye(4), 0.0)
        assert alone.sum() >= 20 and not alone[wall > 0].any()  # the box's image lies inside the screen
        _, depth, mask = box.render(rgb, wall, np.eye(4), 0.0)
        if distance < 1.5:  # in front of the wall the whole box shows, at its own depth
            assert np.array_equal(mask, alone) and np.allclose(depth[mask], distance)
        else:  # behind it the screen hides the box and keeps its missing depth
            assert not mask.any() and np.array_equal(depth, wall)


def test_filled_depth_takes_the_nearest_measurement():
    depth = np.array([[1.0, 0.0, 0.0, 3.0], [1.0, 0.0, 0.0, 3.0]])
    assert np.array_equal(filled_depth(depth), [[1.0, 1.0, 3.0, 3.0], [1.0, 1.0, 3.0, 3.0]])
    assert np.isinf(filled_depth(np.zeros((2, 2)))).all()


def _listing(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_synth_never_writes_over_the_source_or_other_data(room, tmp_path, capsys):
    before = _listing(room)
    rgb_list = (room / "rgb.txt").read_text()
    for out in (room, room.parent):
        assert main(["synth", str(room), str(out), "--overwrite", "--frames", "3"]) == 1
        assert "source sequence" in capsys.readouterr().err
    assert _listing(room) == before and (room / "rgb.txt").read_text() == rgb_list
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("keep")
    assert main(["synth", str(room), str(other), "--frames", "3"]) == 1
    assert "--overwrite" in capsys.readouterr().err
    assert main(["synth", str(room), str(other), "--frames", "3", "--overwrite"]) == 1
    assert "synth.yaml" in capsys.readouterr().err
    assert _listing(other) == ["notes.txt"] and (other / "notes.txt").read_text() == "keep"


def test_synth_replaces_an_earlier_composite_only_when_asked(room, tmp_path, capsys):
    out = tmp_path / "comp"
    assert main(["synth", str(room), str(out), "--frames", "5", "--seed", "1"]) == 0
    first = _listing(out)
    assert main(["synth", str(room), str(out), "--frames", "3", "--seed", "2"]) == 1
    assert "--overwrite" in capsys.readouterr().err
    assert _listing(out) == first
    assert main(["synth", str(room), str(out), "--frames", "3", "--seed", "2", "--overwrite"]) == 0
    info = yaml.safe_load((out / "synth.yaml").read_text())
    assert info["frames"] == 3 and info["config"]["seed"] == 2
    assert len(list((out / "rgb").iterdir())) == len(list((out / "masks").iterdir())) == 3  # no frame of the first
    assert [p.name for p in tmp_path.iterdir()] == ["comp"]  # nothing half-built or replaced is left beside it


def test_an_interrupted_synth_leaves_the_earlier_composite_as_it_was(room, tmp_path, monkeypatch):
    out = tmp_path / "comp"
    write_composite(_read(room), out, CompositeConfig(seed=1, max_frames=3))
    before = {name: (out / name).read_bytes() for name in _listing(out) if (out / name).is_file()}
    render, rendered = Compositor.render, []

    def interrupted(self, *args):
        if len(rendered) == 2:
            raise KeyboardInterrupt
        rendered.append(True)
        return render(self, *args)

    monkeypatch.setattr(Compositor, "render", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_composite(_read(room), out, CompositeConfig(seed=2, max_frames=5), overwrite=True)
    assert {name: (out / name).read_bytes() for name in _listing(out) if (out / name).is_file()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["comp"]


def test_composite_sequence_shows_its_progress_when_asked(room, tmp_path, capsys):
    composite_sequence(_read(room), tmp_path / "quiet", CompositeConfig(max_frames=4))
    assert capsys.readouterr().err == ""
    composite_sequence(_read(room), tmp_path / "shown", CompositeConfig(max_frames=4), progress=True)
    assert "4/4" in capsys.readouterr().err


def test_composite_needs_ground_truth(room, tmp_path, capsys):
    (room.parent / "nogt").mkdir()
    import shutil

    shutil.copytree(room, room.parent / "nogt" / "seq")
    (room.parent / "nogt" / "seq" / "groundtruth.txt").unlink()
    assert main(["synth", str(room.parent / "nogt" / "seq"), str(tmp_path / "o")]) == 1
    assert "groundtruth" in capsys.readouterr().err


@pytest.mark.skipif(not (PERSON.is_file() and SELFIE.is_file()), reason=f"{MODELS} not present")
def test_person_cutout_and_cli(room, tmp_path, capsys):
    rgb, alpha = person_cutout(PERSON, SELFIE)
    assert rgb.shape[:2] == alpha.shape and alpha.mean() > 0.3
    assert rgb.shape[0] > 2 * rgb.shape[1]  # a standing person is tall and narrow
    code = main(["synth", str(room), str(tmp_path / "p"), "--boxes", "0", "--person-image", str(PERSON),
                 "--person-model", str(SELFIE), "--seed", "4"])
    assert code == 0
    assert "person" in (tmp_path / "p" / "synth.yaml").read_text()


def test_mask_counts_on_hand_made_masks():
    from osslam.eval.masks import MaskCounts, mask_counts

    truth = np.zeros((10, 10), bool)
    truth[:, :5] = True
    pred = np.zeros((10, 10), bool)
    pred[:, 3:7] = True
    keypoints = np.array([[1, 1], [4, 4], [6, 6], [8, 8]], float)  # mover, mover+removed, static removed, static
    c = mask_counts(pred, truth, keypoints)
    assert (c.pixels_tp, c.pixels_fp, c.pixels_fn) == (20, 20, 30)
    s = c.scores()
    assert s["pixel_precision"] == 0.5 and s["pixel_recall"] == 0.4
    assert s["keypoint_recall"] == 0.5 and s["static_keypoints_removed"] == 0.5
    total = MaskCounts()
    total += c
    total += mask_counts(None, truth, keypoints)
    assert total.scores()["keypoint_recall"] == 0.25 and total.pixels_fn == 80
    assert MaskCounts().scores()["pixel_recall"] is None


def test_mask_counts_tell_keypoints_near_movers_apart():
    from osslam.eval.masks import FAST_RADIUS, ORB_PATCH_RADIUS, mask_counts

    truth = np.zeros((60, 100), bool)
    truth[:, :20] = True
    pred = np.zeros_like(truth)
    pred[:, :70] = True
    outline, near, far, farther = 19 + FAST_RADIUS - 1, 20 + ORB_PATCH_RADIUS - 5, 20 + ORB_PATCH_RADIUS + 10, 90
    keypoints = np.array([[outline, 30], [near, 30], [far, 30], [farther, 30]], float)
    s = mask_counts(pred, truth, keypoints).scores()
    assert s["static_keypoints_removed"] == 3 / 4  # all but the farthest lie under the prediction
    assert s["off_outline_keypoints_removed"] == 2 / 3  # the outline corner, within FAST's circle, is left out
    assert s["clear_keypoints_removed"] == 0.5  # of the two beyond a patch radius, the far one is removed
    coarse = mask_counts(pred, truth, keypoints, np.array([3.0, ORB_PATCH_RADIUS, 3.0, 3.0])).scores()
    assert coarse["off_outline_keypoints_removed"] == 0.5  # a coarse level's larger circle reaches the mover too
    assert mask_counts(pred, np.zeros_like(truth), keypoints).scores()["off_outline_keypoints_removed"] == 3 / 4


def test_runs_on_composites_score_their_masks(room, tmp_path):
    import json

    from osslam.config import load_config
    from osslam.datasets import open_sequence
    from osslam.pipeline import run_sequence

    folder = composite_sequence(_read(room), tmp_path / "comp", CompositeConfig(seed=2, n_boxes=2))
    cfg = load_config("synthetic", ["mapping.enabled=false"])
    seq = open_sequence(folder, cfg)
    assert seq[3].gt_mask is not None and seq[3].gt_mask.any()
    summary = run_sequence(seq, cfg, tmp_path / "run", progress=False)
    scores = json.loads((tmp_path / "run" / "eval" / "masks.json").read_text())
    assert scores["total"]["frames"] == len(seq) == summary.stats["masks"]["frames"]
    # gating is off: nothing is masked, so no mover keypoint is removed and no static one either
    assert scores["total"]["keypoint_recall"] == 0.0 and scores["total"]["static_keypoints_removed"] == 0.0
    assert scores["total"]["pixel_precision"] is None
    assert len(scores["per_frame"]) == len(seq)


def test_a_run_given_the_ground_truth_masks_leaves_out_exactly_those(room, tmp_path):
    from osslam.config import load_config
    from osslam.datasets import open_sequence
    from osslam.pipeline import run_sequence

    folder = composite_sequence(_read(room), tmp_path / "comp", CompositeConfig(seed=2, n_boxes=2))
    cfg = load_config("synthetic", ["mapping.enabled=false"])
    seq = open_sequence(folder, cfg)
    asked = []

    def truth(frame):
        asked.append(frame.timestamp)
        return frame.gt_mask

    masks = run_sequence(seq, cfg, tmp_path / "run", progress=False, ignore=truth).stats["masks"]
    assert asked == [seq[i].timestamp for i in range(len(seq))]
    assert masks["pixel_precision"] == masks["pixel_recall"] == masks["keypoint_recall"] == 1.0
    assert masks["static_keypoints_removed"] == 0.0
