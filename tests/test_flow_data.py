"""Flow file formats, the standard dataset layouts (on tiny files written here), and the data made here."""

import cv2
import numpy as np
import pytest
from osslam.frontend.flow.data.composite import mover_motion
from osslam.frontend.flow.data.formats import (
    read_flo,
    read_flow,
    read_kitti_flow,
    read_pfm,
    write_flo,
    write_kitti_flow,
    write_pfm,
)
from osslam.frontend.flow.data.procedural import ProceduralConfig, ProceduralPairs
from osslam.frontend.flow.data.rigid import rigid_flow
from osslam.frontend.flow.data.standard import (
    flying_chairs,
    flying_things,
    hd1k,
    kitti2015,
    sintel,
)

from osslam.datasets.composite import Mover
from osslam.errors import InputError
from osslam.types import CameraIntrinsics, Frame

RNG = np.random.default_rng(0)
FLOW = RNG.uniform(-30, 30, (6, 7, 2)).astype(np.float32)


def test_flo_round_trip(tmp_path):
    write_flo(tmp_path / "a.flo", FLOW)
    assert np.array_equal(read_flo(tmp_path / "a.flo"), FLOW)


def test_kitti_png_round_trip_keeps_validity_and_1_64_px(tmp_path):
    valid = RNG.random((6, 7)) > 0.3
    write_kitti_flow(tmp_path / "f.png", FLOW, valid)
    flow, got = read_kitti_flow(tmp_path / "f.png")
    assert np.array_equal(got, valid)
    assert np.abs(flow - FLOW).max() <= 1 / 128 + 1e-6


@pytest.mark.parametrize("shape", [(6, 7, 3), (6, 7)])
def test_pfm_round_trip(tmp_path, shape):
    image = RNG.normal(size=shape).astype(np.float32)
    write_pfm(tmp_path / "x.pfm", image)
    assert np.array_equal(read_pfm(tmp_path / "x.pfm"), image)


def test_read_flow_by_suffix_and_clear_errors(tmp_path):
    write_pfm(tmp_path / "f.pfm", np.dstack([FLOW, np.zeros((6, 7))]))
    flow, valid = read_flow(tmp_path / "f.pfm")
    assert np.array_equal(flow, FLOW) and valid.all()
    (tmp_path / "bad.flo").write_bytes(b"garbage-bytes-here")
    with pytest.raises(InputError, match="bad.flo.*magic"):
        read_flo(tmp_path / "bad.flo")
    write_flo(tmp_path / "cut.flo", FLOW)
    (tmp_path / "cut.flo").write_bytes((tmp_path / "cut.flo").read_bytes()[:-8])
    with pytest.raises(InputError, match="cut.flo.*truncated"):
        read_flo(tmp_path / "cut.flo")
    with pytest.raises(InputError, match="missing.pfm.*not found"):
        read_pfm(tmp_path / "missing.pfm")
    cv2.imwrite(str(tmp_path / "grey.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(InputError, match="grey.png.*KITTI"):
        read_kitti_flow(tmp_path / "grey.png")
    with pytest.raises(InputError, match="unknown flow format"):
        read_flow(tmp_path / "f.txt")


def _image(path, value=0):
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full((6, 7, 3), value, np.uint8))


def test_standard_layouts_pair_images_with_flow(tmp_path):
    chairs = tmp_path / "chairs"
    for i in (1, 2, 3):
        _image(chairs / "data" / f"{i:05d}_img1.ppm", 10)
        _image(chairs / "data" / f"{i:05d}_img2.ppm", 20)
        write_flo(chairs / "data" / f"{i:05d}_flow.flo", FLOW)
    (chairs / "FlyingChairs_train_val.txt").write_text("1\n2\n1\n")
    train = flying_chairs(chairs)
    assert len(train) == 2 and len(flying_chairs(chairs, "val")) == 1
    sample = train[0]
    assert sample.image1[0, 0, 0] == 10 and sample.image2[0, 0, 0] == 20 and np.array_equal(sample.flow, FLOW)

    things = tmp_path / "things"
    for f in (6, 7, 8):
        _image(things / "frames_cleanpass/TRAIN/A/0000/left" / f"{f:04d}.png")
    flow_dir = things / "optical_flow/TRAIN/A/0000/into_future/left"
    flow_dir.mkdir(parents=True)
    for f in (6, 7):
        write_pfm(flow_dir / f"OpticalFlowIntoFuture_{f:04d}_L.pfm", np.dstack([FLOW, np.zeros((6, 7))]))
    assert [p.image1.name for p in flying_things(things).pairs] == ["0006.png", "0007.png"]

    sin = tmp_path / "sintel"
    for f in (1, 2, 3):
        _image(sin / "training/clean/alley_1" / f"frame_{f:04d}.png")
    for f in (1, 2):
        (sin / "training/flow/alley_1").mkdir(parents=True, exist_ok=True)
        write_flo(sin / "training/flow/alley_1" / f"frame_{f:04d}.flo", FLOW)
    assert len(sintel(sin)) == 2 and np.array_equal(sintel(sin)[1].flow, FLOW)

    kitti = tmp_path / "kitti"
    _image(kitti / "training/image_2/000000_10.png")
    _image(kitti / "training/image_2/000000_11.png")
    (kitti / "training/flow_occ").mkdir(parents=True)
    write_kitti_flow(kitti / "training/flow_occ/000000_10.png", FLOW, np.ones((6, 7), bool))
    assert kitti2015(kitti)[0].valid.all()

    hd = tmp_path / "hd1k"
    for f in (0, 1):
        _image(hd / "hd1k_input/image_2" / f"000000_{f:04d}.png")
    (hd / "hd1k_flow_gt/flow_occ").mkdir(parents=True)
    write_kitti_flow(hd / "hd1k_flow_gt/flow_occ/000000_0000.png", FLOW, np.ones((6, 7), bool))
    write_kitti_flow(hd / "hd1k_flow_gt/flow_occ/000000_0001.png", FLOW, np.ones((6, 7), bool))  # no next frame
    assert [p.image2.name for p in hd1k(hd).pairs] == ["000000_0001.png"]

    with pytest.raises(InputError, match="no Sintel image pairs"):
        sintel(tmp_path / "nothing")


def test_procedural_pairs_are_reproducible_and_their_flow_explains_the_second_image():
    cfg = ProceduralConfig(size=[96, 128], noise=0.0, blur=0.0)
    a, b = ProceduralPairs(cfg, seed=3)[5], ProceduralPairs(cfg, seed=3)[5]
    assert np.array_equal(a.image1, b.image1) and np.array_equal(a.flow, b.flow)
    assert not np.array_equal(a.image1, ProceduralPairs(cfg, seed=3)[6].image1)
    ys, xs = np.mgrid[0:96, 0:128].astype(np.float32)
    back = cv2.remap(a.image2, xs + a.flow[..., 0], ys + a.flow[..., 1], cv2.INTER_LINEAR)
    err = np.abs(back.astype(float) - a.image1).mean(axis=2)
    assert np.median(err) < 2.0 and (err < 5).mean() > 0.7
    assert np.abs(a.flow).max() > 1.0


CAM = CameraIntrinsics(fx=100.0, fy=100.0, cx=31.5, cy=23.5, width=64, height=48)


def _pose(x=0.0):
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_rigid_flow_of_a_sideways_camera_over_a_wall_is_the_parallax():
    depth = np.full((48, 64), 2.0, np.float32)
    flow, valid = rigid_flow(depth, depth, _pose(0.0), _pose(0.1), CAM)
    # camera 0.1 m to the right: a wall at 2 m moves 100 * 0.1 / 2 = 5 px to the left
    assert np.allclose(flow[valid][:, 0], -5.0, atol=1e-4) and np.allclose(flow[valid][:, 1], 0.0, atol=1e-4)
    assert valid[:, 10:].all() and not valid[:, :5].any()  # the left edge leaves the image


def test_rigid_flow_marks_points_hidden_in_the_second_frame():
    depth1 = np.full((48, 64), 2.0, np.float32)
    depth2 = depth1.copy()
    depth2[:, 30:40] = 1.0  # something closer covers these columns in frame 2
    flow, valid = rigid_flow(depth1, depth2, _pose(), _pose(), CAM)
    assert not valid[:, 30:40].any() and valid[:, :30].all()
    assert not flow[~valid].any()  # no flow where there is no ground truth
    depth1[5, 5] = 0.0
    assert not rigid_flow(depth1, depth1, _pose(), _pose(), CAM)[1][5, 5]


def test_composite_movers_carry_their_pixels_along():
    box = Mover("box", np.array([0.3, 0.3, 0.05]), centre=np.array([0.0, 0.0, 1.95]), axis=np.array([1.0, 0, 0]),
                amplitude=0.2, period=4.0, phase=0.0, R=np.eye(3), texture=np.zeros((2, 2, 3), np.uint8))
    depth = np.full((48, 64), 2.0, np.float32)
    depth[14:34, 22:42] = 1.9  # the box's front face
    mask = depth < 2.0
    frames = [Frame(i, t, np.zeros((48, 64, 3), np.uint8), depth, CAM, _pose(), gt_mask=mask) for i, t in
              enumerate((0.0, 0.1))]
    motion = mover_motion([box], t0=0.0)(*frames)
    flow, valid = rigid_flow(depth, depth, _pose(), _pose(), CAM, motion=motion)
    shift = 0.2 * np.sin(2 * np.pi * 0.1 / 4.0)  # metres the box travels
    assert np.allclose(flow[20, 30], [100 * shift / 1.9, 0.0], atol=1e-3)
    assert np.allclose(flow[2, 2], [0.0, 0.0])
    frames[0].gt_mask[0, 0] = True  # "mover" pixel no mover explains: no ground truth there
    _, valid = rigid_flow(depth, depth, _pose(), _pose(), CAM, motion=mover_motion([box], 0.0)(*frames))
    assert not valid[0, 0]


def test_composite_flow_follows_the_rendered_movers(tmp_path):
    from osslam.config import load_config
    from osslam.datasets import open_sequence
    from osslam.datasets.composite import CompositeConfig, composite_sequence
    from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
    from osslam.frontend.flow.data.composite import composite_flow_pairs

    room = SyntheticSequence(SyntheticConfig(n_frames=3, seed=4, depth_noise=False, dropout=0.0, holes=False))
    base = open_sequence(room.write_tum(tmp_path / "room"), load_config())
    folder = composite_sequence(base, tmp_path / "comp", CompositeConfig(seed=0, n_boxes=2, distance=(0.6, 0.8)))
    sample = composite_flow_pairs(open_sequence(folder, load_config()))[1]
    on = sample.movers & sample.valid
    assert on.sum() > 500 and sample.movers.mean() > 0.01
    h, w = on.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    grey1, grey2 = (cv2.cvtColor(im, cv2.COLOR_RGB2GRAY).astype(np.float32) for im in (sample.image1, sample.image2))
    back = cv2.remap(grey2, xs + sample.flow[..., 0], ys + sample.flow[..., 1], cv2.INTER_LINEAR)
    assert np.median(np.abs(back - grey1)[on]) < 0.15 * np.median(np.abs(grey2 - grey1)[on])  # static flow: ~0.4
