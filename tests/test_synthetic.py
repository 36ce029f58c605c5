"""The synthetic room: reproducibility, exact geometry, texture, motion, noise and the TUM round trip."""

import time

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from osslam.config import CameraConfig, Config, DatasetConfig
from osslam.datasets import open_sequence
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.datasets.synthetic_scene import OBJECTS, ROOM, RoomRenderer
from osslam.datasets.tum import TumSequence

CLEAN = dict(depth_noise=False, dropout=0.0, holes=False, image_noise=0.0)


def _on_surface(box, points, tol=1e-3):
    """Which of the (N, 3) points lie on a face of the box, within tol metres."""
    near_plane = (np.abs(points - box.lo) < tol) | (np.abs(points - box.hi) < tol)
    return near_plane.any(axis=1) & box.contains(points, tol)


def _backproject(frame, v, u):
    """World points of pixels (v, u) of a frame, from its depth and ground-truth pose."""
    K = frame.intrinsics
    z = frame.depth[v, u].astype(np.float64)
    pc = np.column_stack([(u - K.cx) / K.fx * z, (v - K.cy) / K.fy * z, z])
    return pc @ frame.gt_pose[:3, :3].T + frame.gt_pose[:3, 3]


def _reference_depth(pose, rays):
    """Depth along camera rays (N, 3, z = 1) by brute-force float64 slab tests against every box."""
    o, d = pose[:3, 3], rays @ pose[:3, :3].T
    with np.errstate(divide="ignore"):
        inv = 1.0 / d
    t1, t2 = (np.array(ROOM.lo) - o) * inv, (np.array(ROOM.hi) - o) * inv
    best = np.maximum(t1, t2).min(axis=1)
    for box in OBJECTS:
        t1, t2 = (np.array(box.lo) - o) * inv, (np.array(box.hi) - o) * inv
        near, far = np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)
        hit = (near <= far) & (near > 0)
        best = np.where(hit, np.minimum(best, near), best)
    return best


def test_same_seed_same_frames_different_seed_different_frames():
    a = SyntheticSequence(SyntheticConfig(n_frames=5, seed=1))
    b = SyntheticSequence(SyntheticConfig(n_frames=5, seed=1))
    c = SyntheticSequence(SyntheticConfig(n_frames=5, seed=2))
    a1 = a[1]
    fa, fb, fc = a[3], b[3], c[3]
    assert np.array_equal(fa.rgb, fb.rgb) and np.array_equal(fa.depth, fb.depth)
    assert np.array_equal(fa.gt_pose, fb.gt_pose) and fa.timestamp == fb.timestamp
    assert np.array_equal(a1.rgb, b[1].rgb)  # noise is seeded per frame, not by access order
    assert not np.array_equal(fa.rgb, fc.rgb)
    assert not np.array_equal(fa.depth, fc.depth)
    assert not np.allclose(fa.gt_pose, fc.gt_pose)
    assert not np.array_equal(fa.rgb, a1.rgb)


def test_depth_is_exact_ray_geometry():
    seq = SyntheticSequence(SyntheticConfig(n_frames=60, seed=4, **CLEAN))
    K = seq.intrinsics
    rng = np.random.default_rng(0)
    on_objects = 0
    for i in (0, 30, 59):
        f = seq[i]
        assert np.all(f.depth > 0)
        v, u = rng.integers(0, K.height, 400), rng.integers(0, K.width, 400)
        points = _backproject(f, v, u)
        on_room = _on_surface(ROOM, points)
        on_object = np.zeros(len(points), bool)
        for box in OBJECTS:
            on_object |= _on_surface(box, points)
        assert np.all(on_room | on_object)
        on_objects += on_object.sum()
        rays = np.column_stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(len(u))])
        reference = _reference_depth(f.gt_pose, rays)
        assert np.mean(np.abs(f.depth[v, u] - reference) < 1e-4) >= 0.995  # float32 may disagree at an edge
    assert on_objects > 50  # the boxes are in view: there is parallax


def test_texture_is_fixed_to_the_surfaces():
    seq = SyntheticSequence(SyntheticConfig(n_frames=60, seed=6, **CLEAN))
    a, b = seq[0], seq[59]  # 0.22 m apart
    K = a.intrinsics
    v, u = np.mgrid[40 : K.height - 40 : 7, 40 : K.width - 40 : 7].reshape(2, -1)
    pw = _backproject(a, v, u)
    pb = (pw - b.gt_pose[:3, 3]) @ b.gt_pose[:3, :3]
    ub, vb = K.fx * pb[:, 0] / pb[:, 2] + K.cx, K.fy * pb[:, 1] / pb[:, 2] + K.cy
    inside = (ub > 1) & (ub < K.width - 2) & (vb > 1) & (vb < K.height - 2)
    gray_a = cv2.cvtColor(a.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    gray_b = cv2.cvtColor(b.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    seen_b = cv2.remap(gray_b, ub.astype(np.float32)[None], vb.astype(np.float32)[None], cv2.INTER_LINEAR)[0]
    depth_b = b.depth[np.round(vb).astype(int).clip(0, K.height - 1), np.round(ub).astype(int).clip(0, K.width - 1)]
    visible = inside & (np.abs(depth_b - pb[:, 2]) < 0.01)
    assert visible.sum() > 1000
    diff = np.abs(gray_a[v, u] - seen_b)[visible]
    assert np.mean(diff) < 1.0 and np.percentile(diff, 90) < 2.5  # grey levels, after resampling twice
    assert np.std(gray_a[v, u][visible]) > 25  # and it is textured, so the check means something


def test_frames_have_texture_for_orb():
    seq = SyntheticSequence(SyntheticConfig(n_frames=150, seed=0))
    orb = cv2.ORB_create(1000)
    for i in (0, 75, 149):
        assert len(orb.detect(cv2.cvtColor(seq[i].rgb, cv2.COLOR_RGB2GRAY))) > 500


def test_camera_motion_is_smooth_inside_the_room_and_fr1_xyz_like():
    for seed in range(4):
        seq = SyntheticSequence(SyntheticConfig(n_frames=900, seed=seed))  # 30 s; poses only, nothing rendered
        poses = seq.groundtruth.poses
        assert np.allclose(seq.groundtruth.timestamps, seq.timestamps)
        assert np.all(ROOM.contains(poses[:, :3, 3], tol=-0.5))
        assert not any(box.contains(poses[:, :3, 3], tol=0.4).any() for box in OBJECTS)
        speed = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) * seq.cfg.fps
        assert 0.1 < speed.mean() < 0.3 and speed.max() < 0.4
        relative = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
        turn = np.degrees(np.linalg.norm(Rotation.from_matrix(relative).as_rotvec(), axis=1)) * seq.cfg.fps
        assert 2 < turn.mean() and turn.max() < 18
        forward = poses[:, :3, 2]  # optical axis in the world
        assert np.all(forward[:, 2] > 0.8)  # always facing the far wall


def test_walls_in_view_are_at_room_distances():
    seq = SyntheticSequence(SyntheticConfig(n_frames=150, seed=2, **CLEAN))
    for i in (0, 50, 100, 149):
        depth = seq[i].depth
        assert 0.5 < depth.min() and np.percentile(depth, 90) < 4.5 and 1.5 < np.median(depth) < 4.0


def test_sensor_noise_dropouts_and_holes():
    clean = SyntheticSequence(SyntheticConfig(n_frames=3, seed=3, **CLEAN))[1]
    noisy = SyntheticSequence(SyntheticConfig(n_frames=3, seed=3, depth_noise=True, dropout=0.0, holes=False,
                                              image_noise=2.0))[1]
    residual = noisy.depth - clean.depth
    sigma = 0.0012 + 0.0019 * (clean.depth - 0.4) ** 2
    assert np.std(residual / sigma) == pytest.approx(1.0, abs=0.05)
    assert np.std(noisy.rgb.astype(float) - clean.rgb) == pytest.approx(2.0, abs=0.3)
    dropped = SyntheticSequence(SyntheticConfig(n_frames=3, seed=3, depth_noise=False, dropout=0.1, holes=False))[1]
    assert np.mean(dropped.depth == 0) == pytest.approx(0.1, abs=0.01)
    holed = SyntheticSequence(SyntheticConfig(n_frames=3, seed=3, depth_noise=False, dropout=0.0, holes=True))[1]
    lost = holed.depth == 0
    assert 0 < lost.mean() < 0.05
    assert np.array_equal(holed.depth[~lost], clean.depth[~lost])
    # depth goes missing on the far side of occluding edges
    jump = np.diff(clean.depth, axis=1)
    assert (jump > 0.1).any() and lost[:, 1:][jump > 0.1].all() and lost[:, :-1][jump < -0.1].all()


def test_image_size_and_intrinsics_are_configurable():
    seq = SyntheticSequence(SyntheticConfig(n_frames=2, width=320, height=240, fx=260, fy=262, cx=159.5, cy=119.5))
    f = seq[0]
    assert f.rgb.shape == (240, 320, 3) and f.depth.shape == (240, 320)
    assert (seq.intrinsics.fx, seq.intrinsics.fy, seq.intrinsics.width) == (260, 262, 320)
    assert f.intrinsics == seq.intrinsics and not seq.intrinsics.has_distortion
    with pytest.raises(ValueError):
        SyntheticConfig(n_frames=0)
    with pytest.raises(ValueError):
        SyntheticConfig(dropout=1.5)
    with pytest.raises(IndexError):
        seq[2]


def test_renderer_refuses_a_camera_inside_an_object():
    renderer = RoomRenderer(SyntheticSequence(SyntheticConfig(n_frames=1)).intrinsics, np.random.default_rng(0))
    pose = np.eye(4)
    pose[:3, 3] = np.add(OBJECTS[0].lo, OBJECTS[0].hi) / 2
    with pytest.raises(ValueError, match="inside an object"):
        renderer.render(pose)


def test_rendering_is_vectorised_fast():
    seq = SyntheticSequence(SyntheticConfig(n_frames=10, seed=1))
    seq[0]
    start = time.perf_counter()
    for i in range(1, 10):
        seq[i]
    assert (time.perf_counter() - start) / 9 < 0.2  # about 15-20 ms on a 2-core machine


def test_write_tum_round_trips_through_the_tum_reader(tmp_path):
    seq = SyntheticSequence(SyntheticConfig(n_frames=4, seed=5, fx=500.0, cy=241.0))
    folder = seq.write_tum(tmp_path / "synthetic_run")  # no freiburg in the name: camera.yaml must be used
    assert {p.name for p in folder.iterdir()} >= {"rgb", "depth", "rgb.txt", "depth.txt", "groundtruth.txt",
                                                   "camera.yaml"}
    back = TumSequence(folder, DatasetConfig(), CameraConfig())
    assert back.intrinsics == seq.intrinsics
    assert np.array_equal(back.timestamps, seq.timestamps)
    assert back.groundtruth_path == folder / "groundtruth.txt"
    for a, b in zip(seq, back):
        assert b.gt_pose is not None and np.allclose(a.gt_pose, b.gt_pose, rtol=0, atol=1e-6)
        assert np.array_equal(a.rgb, b.rgb)
        assert np.array_equal(a.depth == 0, b.depth == 0)
        assert np.abs(a.depth - b.depth).max() <= 0.5 / 5000 + 1e-6
    assert len(open_sequence(folder, Config())) == 4
