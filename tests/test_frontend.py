"""Front-end pieces: ORB extraction, matching, motion-only pose refinement, keyframe policy."""

import cv2
import numpy as np
import pytest

from osslam.config import Config, KeyframeConfig
from osslam.frontend.features import FeatureExtractor, _points
from osslam.frontend.keyframe_policy import KeyframePolicy
from osslam.frontend.matching import hamming, match_brute_force, match_by_projection
from osslam.frontend.pose_optimizer import optimize_pose
from osslam.geometry import invert, se3_exp, transform_points
from osslam.types import CameraIntrinsics

K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])


def _textured_image(seed=0, h=480, w=640):
    rng = np.random.default_rng(seed)
    img = np.full((h, w), 128, np.uint8)
    for _ in range(400):
        x, y = rng.integers(0, w - 20), rng.integers(0, h - 20)
        s = rng.integers(5, 20)
        img[y : y + s, x : x + s] = rng.integers(0, 255)
    return img


def test_hamming_counts_differing_bits():
    a = np.zeros(32, np.uint8)
    b = a.copy()
    b[0], b[5] = 0b1011, 0xFF
    assert hamming(a, b) == 3 + 8
    assert hamming(a, a) == 0


def test_features_spread_and_respect_ignore_mask():
    cfg = Config()
    intr = CameraIntrinsics(525, 525, 319.5, 239.5)
    fe = FeatureExtractor(cfg.features, cfg.camera, intr)
    img = _textured_image()
    depth = np.full(img.shape, 2.0, np.float32)
    depth[:, :100] = 0.0
    feats = fe.extract(img, depth)
    assert 500 <= len(feats) <= cfg.features.n_features
    # every quarter of the image gets features
    for qx in (0, 1):
        for qy in (0, 1):
            inq = (feats.pixels[:, 0] // 320 == qx) & (feats.pixels[:, 1] // 240 == qy)
            assert inq.sum() > 50
    assert np.all(feats.depth[feats.pixels[:, 0] < 99] == 0)
    assert np.all(feats.depth[feats.pixels[:, 0] > 101] == 2.0)
    ignore = np.zeros(img.shape, bool)
    ignore[:, 320:] = True
    masked = fe.extract(img, depth, ignore)
    assert len(masked) > 100
    assert masked.pixels[:, 0].max() < 320


def test_keypoint_coordinates_are_converted_exactly_and_in_order():
    cfg = Config()
    fe = FeatureExtractor(cfg.features, cfg.camera, CameraIntrinsics(525, 525, 319.5, 239.5))
    kps = fe._orb.detect(_textured_image(1), None)
    assert len(kps) > 1000
    assert np.array_equal(_points(kps), np.array([k.pt for k in kps], np.float64))
    assert _points([]).shape == (0, 2)


def test_a_densely_textured_region_leaves_the_rest_of_the_image_its_features():
    cfg = Config()
    fe = FeatureExtractor(cfg.features, cfg.camera, CameraIntrinsics(525, 525, 319.5, 239.5))
    rng = np.random.default_rng(3)
    # a faint texture over the image and a crisp checkerboard on its left third
    faint = cv2.GaussianBlur(rng.integers(0, 255, (480, 640)).astype(np.float32), (0, 0), 2.0)
    img = (128 + 0.5 * (faint - faint.mean())).clip(0, 255).astype(np.uint8)
    yy, xx = np.mgrid[0:480, 0:213]
    img[:, :213] = np.where(((yy // 6) + (xx // 6)) % 2 == 1, 255, 0)
    feats = fe.extract(img, np.full(img.shape, 2.0, np.float32))
    rest = feats.pixels[:, 0] >= 213
    # the two thirds outside the board hold 48 of the 80 grid cells, and so about 60 % of the features
    assert rest.sum() >= 0.5 * len(feats)
    assert len(feats) >= 0.9 * cfg.features.n_features
    cfg.features.candidates = 0
    with pytest.raises(ValueError, match="features.candidates"):
        FeatureExtractor(cfg.features, cfg.camera, CameraIntrinsics(525, 525, 319.5, 239.5))


def test_undistortion_applied_for_distorted_camera():
    cfg = Config()
    intr = CameraIntrinsics(517.3, 516.5, 318.6, 255.3, dist=(0.2624, -0.9531, -0.0054, 0.0026, 1.1633))
    fe = FeatureExtractor(cfg.features, cfg.camera, intr)
    feats = fe.extract(_textured_image(1), np.ones((480, 640), np.float32))
    shift = np.linalg.norm(feats.uv - feats.pixels, axis=1)
    corner = np.linalg.norm(feats.pixels - [318.6, 255.3], axis=1) > 300
    assert shift[corner].mean() > 1.0
    assert shift[~corner].min() < 0.5


def test_projection_matching_finds_nearby_identical_descriptors():
    rng = np.random.default_rng(3)
    desc = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    uv = rng.uniform([0, 0], [640, 480], (200, 2))
    perm = rng.permutation(200)
    projected = uv[perm] + rng.normal(0, 2.0, (200, 2))
    m = match_by_projection(projected, desc[perm], uv, desc, radius=10.0, max_distance=50, ratio=0.8)
    assert len(m) > 190
    assert np.all(perm[m.query] == m.feature)
    # projections far from their features find nothing: random descriptors differ by ~128 bits
    m_far = match_by_projection(projected + 100.0, desc[perm], uv, desc, radius=5.0, max_distance=50, ratio=0.8)
    assert len(m_far) == 0
    bf = match_brute_force(desc[perm], desc, max_distance=50, ratio=0.8)
    assert len(bf) == 200 and np.all(perm[bf.query] == bf.feature)


def _scene(rng, n=300):
    pts = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(1.5, 4.0, n)])
    return pts


@pytest.mark.parametrize("with_depth", [True, False])
def test_pose_optimizer_recovers_pose_despite_outliers(with_depth):
    rng = np.random.default_rng(7)
    pts_w = _scene(rng)
    T_cw = se3_exp(np.array([0.05, -0.03, 0.02, 0.02, -0.03, 0.01]))
    pc = transform_points(T_cw, pts_w)
    uv = pc[:, :2] / pc[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]] + rng.normal(0, 0.5, (len(pc), 2))
    depth = pc[:, 2] if with_depth else np.zeros(len(pc))
    outliers = rng.choice(len(pc), 30, replace=False)
    uv[outliers] += rng.uniform(20, 60, (30, 2))
    init = se3_exp(np.array([0.03, 0.03, -0.03, -0.02, 0.02, 0.02])) @ T_cw
    est = optimize_pose(init, pts_w, uv, depth, np.ones(len(pc)), K, 0.08)
    err = invert(est.T_cw) @ T_cw
    assert np.linalg.norm(err[:3, 3]) < 5e-3
    assert not est.inliers[outliers].any()
    assert est.n_inliers > 250


def test_keyframe_policy():
    pol = KeyframePolicy(KeyframeConfig(min_tracked_ratio=0.75, min_translation=0.1, min_rotation_deg=10,
                                        max_interval=30, min_interval=0))
    still = np.eye(4)
    assert not pol.is_keyframe(5, 90, 100, still)
    assert pol.is_keyframe(5, 60, 100, still)
    assert pol.is_keyframe(30, 100, 100, still)
    moved = np.eye(4)
    moved[0, 3] = 0.2
    assert pol.is_keyframe(5, 100, 100, moved)
    turned = se3_exp(np.array([0, 0, 0, 0, np.radians(15), 0]))
    assert pol.is_keyframe(5, 100, 100, turned)


def test_new_landmarks_are_spread_over_the_image_before_a_near_object_takes_more():
    from osslam.frontend.tracker import _spread_order

    rng = np.random.default_rng(0)
    near = np.column_stack([rng.uniform(0, 80, 300), rng.uniform(0, 80, 300)])  # one cell of the grid, listed first
    far = np.column_stack([rng.uniform(0, 640, 100), rng.uniform(0, 480, 100)])
    uv = np.vstack([near, far])
    order = _spread_order(uv, (640, 480))
    assert sorted(order.tolist()) == list(range(len(uv)))
    first = order[:100]
    assert (first >= 300).sum() > 60  # the far points, spread over many cells, come before most near ones
    in_near_cell = order[np.isin(order, np.arange(300))]
    assert (np.diff(in_near_cell) > 0).all()  # within a cell the given (nearest-first) order is kept
