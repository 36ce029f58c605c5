"""Tests of the iSAM2 back-end on synthetic scenes with a known answer."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from osslam.backend.factors import FactorFactory
from osslam.backend.isam import IsamBackend
from osslam.backend.observations import Observation
from osslam.backend.reprojection import reprojection_chi2
from osslam.backend.solver import offending_key
from osslam.backend.types import KeyframeObservations
from osslam.config import BackendConfig
from osslam.geometry import invert, se3_exp, transform_points
from osslam.types import CameraIntrinsics

INTR = CameraIntrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5)
BASELINE = 0.08


@dataclasses.dataclass
class Scene:
    """Ground truth and the observations a perfect front-end would send."""

    poses: list[np.ndarray]
    points: np.ndarray
    frames: list[KeyframeObservations]


def make_scene(n_kf: int = 10, n_points: int = 500, seed: int = 0, step: float = 0.12) -> Scene:
    """Landmarks in a slab 2-5 m in front of a camera translating sideways with small rotations."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-2.0, 2.0 + step * n_kf, n_points), rng.uniform(-1.2, 1.2, n_points),
                              rng.uniform(2.0, 5.0, n_points)])
    poses, frames, created = [], [], set()
    for k in range(n_kf):
        twist = [step * k, 0.03 * np.sin(k), 0.02 * k, 0.02 * np.sin(0.7 * k), 0.03 * np.cos(k), 0.01 * k]
        T = se3_exp(np.array(twist))
        poses.append(T)
        pc = transform_points(invert(T), points)
        uv = pc[:, :2] / pc[:, 2:3] * [INTR.fx, INTR.fy] + [INTR.cx, INTR.cy]
        vis = np.flatnonzero((pc[:, 2] > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 480))
        new = {int(i): points[i].copy() for i in vis if int(i) not in created}
        created.update(new)
        frames.append(KeyframeObservations(keyframe_id=2 * k + 1, pose_guess=T.copy(),
                                           landmark_ids=vis.astype(np.int64), uv=uv[vis], depth=pc[vis, 2].copy(),
                                           sigma_scale=np.ones(len(vis)), new_landmarks=new))
    return Scene(poses, points, frames)


def exact_config(**changes) -> BackendConfig:
    """Back-end settings that converge tightly on noise-free data."""
    cfg = BackendConfig(relinearize_threshold=1e-6, wildfire_threshold=1e-9, relinearize_skip=1, extra_updates=2,
                        finish_iterations=4)
    return dataclasses.replace(cfg, **changes)


def run(frames: list[KeyframeObservations], cfg: BackendConfig) -> tuple[IsamBackend, list]:
    """A fresh back-end fed with all frames, and its updates."""
    backend = IsamBackend(INTR, cfg, BASELINE)
    return backend, [backend.add_keyframe(f) for f in frames]


def pose_errors(estimated: dict[int, np.ndarray], scene: Scene) -> tuple[float, float]:
    """Largest translation error (m) and rotation error (rad) over the scene's keyframes."""
    dt, dr = 0.0, 0.0
    for k, T in enumerate(scene.poses):
        E = invert(T) @ estimated[2 * k + 1]
        dt = max(dt, float(np.linalg.norm(T[:3, 3] - estimated[2 * k + 1][:3, 3])))
        dr = max(dr, float(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1))))
    return dt, dr


def with_obs(frame: KeyframeObservations, **arrays) -> KeyframeObservations:
    """A copy of a keyframe with some observation arrays replaced."""
    return dataclasses.replace(frame, **arrays)


def test_exact_observations_recover_ground_truth():
    scene = make_scene()
    backend, updates = run(scene.frames, exact_config())
    assert all(u.ok for u in updates)
    dt, dr = pose_errors(updates[-1].poses, scene)
    assert dt < 1e-6 and dr < 1e-6
    newest = {lid for lid in scene.frames[-1].landmark_ids.tolist() if backend.in_graph(lid)}
    assert len(newest) > 100 and newest <= updates[-1].landmarks.keys()
    est = backend.estimate()
    assert len(est.landmarks) > 200
    err = max(np.linalg.norm(p - scene.points[lid]) for lid, p in est.landmarks.items())
    assert err < 1e-5


def test_perturbed_guesses_converge_with_exact_observations():
    scene = make_scene(seed=1)
    rng = np.random.default_rng(1)
    frames = [scene.frames[0]] + [with_obs(f, pose_guess=f.pose_guess @ se3_exp(rng.normal(0, [0.03] * 3 + [0.02] * 3)))
                                  for f in scene.frames[1:]]
    backend, updates = run(frames, exact_config())
    final = backend.finish()
    dt, dr = pose_errors(final.poses, scene)
    assert dt < 1e-4 and dr < 1e-5
    assert len(final.landmarks) == backend.n_landmarks


def test_noisy_observations_beat_perturbed_guesses():
    scene = make_scene(seed=2)
    rng = np.random.default_rng(2)
    frames = []
    for k, f in enumerate(scene.frames):
        guess = f.pose_guess if k == 0 else f.pose_guess @ se3_exp(rng.normal(0, [0.04] * 3 + [0.02] * 3))
        frames.append(with_obs(f, pose_guess=guess, uv=f.uv + rng.normal(0, 0.5, f.uv.shape),
                               depth=f.depth * (1 + rng.normal(0, 0.005, f.depth.shape))))
    guess_dt, guess_dr = pose_errors({f.keyframe_id: f.pose_guess for f in frames}, scene)
    backend, updates = run(frames, BackendConfig())
    online_dt, online_dr = pose_errors(updates[-1].poses, scene)
    dt, dr = pose_errors(backend.finish().poses, scene)
    assert guess_dt > 0.05 and guess_dr > 0.03
    assert online_dt < guess_dt / 10 and online_dr < guess_dr / 10
    assert dt < 0.005 and dr < 0.002


def test_outlier_observation_is_removed_and_reported():
    scene = make_scene(seed=3)
    k = 6
    frame = scene.frames[k]
    seen_before = set(scene.frames[k - 1].landmark_ids.tolist()) & set(scene.frames[k - 2].landmark_ids.tolist())
    j = next(i for i, lid in enumerate(frame.landmark_ids.tolist()) if lid in seen_before)
    lid = int(frame.landmark_ids[j])
    uv = frame.uv.copy()
    uv[j] += [40.0, -25.0]
    frames = list(scene.frames)
    frames[k] = with_obs(frame, uv=uv)
    backend, updates = run(frames, BackendConfig())
    assert updates[k].outlier_observations == [(frame.keyframe_id, lid)]
    assert updates[k].retired_landmarks == []
    assert all(not u.outlier_observations for i, u in enumerate(updates) if i != k)
    assert backend.in_graph(lid)
    np.testing.assert_allclose(backend.landmark(lid), scene.points[lid], atol=1e-3)


def test_landmark_with_only_bad_observations_is_retired():
    scene = make_scene(seed=4)
    rng = np.random.default_rng(4)
    lid = int(scene.frames[0].landmark_ids[0])
    frames = []
    for f in scene.frames:
        uv, depth = f.uv.copy(), f.depth.copy()
        hit = f.landmark_ids == lid
        uv[hit] = rng.uniform([0, 0], [640, 480], (int(hit.sum()), 2))
        depth[hit] = rng.uniform(1.0, 6.0, int(hit.sum()))
        frames.append(with_obs(f, uv=uv, depth=depth))
    backend, updates = run(frames, BackendConfig())
    retired = [u.retired_landmarks for u in updates]
    assert sum(retired, []) == [lid]
    assert all(u.ok for u in updates)
    assert not backend.in_graph(lid) and backend.landmark(lid) is None
    assert lid not in backend.estimate().landmarks
    assert lid not in updates[-1].landmarks
    assert sum(len(u.outlier_observations) for u in updates) >= 2


def test_invalid_observations_never_crash():
    scene = make_scene(n_kf=6, seed=5)
    frames = list(scene.frames)
    f = frames[3]
    n = len(f.landmark_ids)
    uv, depth, scale = f.uv.copy(), f.depth.copy(), f.sigma_scale.copy()
    uv[0] = np.nan
    uv[1, 0] = np.inf
    depth[2] = np.nan
    depth[3] = -1.0
    depth[4] = 1e9
    scale[5] = np.nan
    scale[6] = 0.0
    ids = f.landmark_ids.copy()
    ids[8] = ids[7]  # a repeated landmark: only its first observation counts
    frames[3] = with_obs(f, uv=uv, depth=depth, sigma_scale=scale, landmark_ids=ids)
    frames[4] = with_obs(frames[4], pose_guess=np.full((4, 4), np.nan))
    backend, updates = run(frames, BackendConfig())
    assert n > 20
    assert all(u.ok for u in updates)
    assert all(np.isfinite(T).all() for T in updates[-1].poses.values())
    assert all(np.isfinite(p).all() for p in updates[-1].landmarks.values())
    dt, _ = pose_errors(backend.finish().poses, scene)
    assert dt < 1e-4


def test_landmark_behind_camera_is_not_added():
    rng = np.random.default_rng(6)
    pts = np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-1, 1, 30), rng.uniform(2, 4, 30)])
    frames = []
    for k in range(2):
        T = se3_exp(np.array([0.1 * k, 0, 0, 0, 0, 0]))
        pc = transform_points(invert(T), pts)
        uv = pc[:, :2] / pc[:, 2:3] * [INTR.fx, INTR.fy] + [INTR.cx, INTR.cy]
        frames.append(KeyframeObservations(k, T, np.arange(30), uv, pc[:, 2].copy(), np.ones(30)))
    behind = np.eye(4)
    behind[:3, :3] = np.diag([-1.0, 1.0, -1.0])  # same position, looking backwards
    # keyframe 2 claims to see landmarks 0 (mono) and 1 (with depth), which lie behind it, and a
    # new landmark 100 whose only other observation (keyframe 3) puts it behind keyframe 2
    frames.append(KeyframeObservations(2, behind, np.array([0, 1, 100]), frames[1].uv[:3],
                                       np.array([np.nan, 3.0, 2.0]), np.ones(3)))
    frames.append(KeyframeObservations(3, np.eye(4), np.array([100]), frames[1].uv[2:3], np.array([3.0]),
                                       np.ones(1)))
    backend, updates = run(frames, BackendConfig())
    assert all(u.ok for u in updates)
    assert updates[1].n_landmarks == 30 and updates[1].n_factors == 2 + 60
    assert updates[2].n_factors == updates[1].n_factors + 1  # only the odometry factor was added
    assert updates[3].n_factors == updates[2].n_factors + 1
    assert not backend.in_graph(100)
    assert all(not u.outlier_observations and not u.retired_landmarks for u in updates)  # filtered, not culled
    np.testing.assert_allclose(updates[2].poses[2], behind, atol=1e-6)
    for lid in (0, 1):
        np.testing.assert_allclose(backend.landmark(lid), pts[lid], atol=1e-6)


def test_keyframe_without_observations_gets_a_pose():
    scene = make_scene(seed=7)
    frames = list(scene.frames)
    empty = np.zeros(0)
    frames[5] = with_obs(frames[5], landmark_ids=np.zeros(0, np.int64), uv=np.zeros((0, 2)), depth=empty,
                         sigma_scale=empty, new_landmarks={})
    backend, updates = run(frames, exact_config())
    assert all(u.ok for u in updates)
    assert frames[5].keyframe_id in updates[5].poses
    assert backend.keyframe_ids == [f.keyframe_id for f in frames]
    dt, dr = pose_errors(updates[-1].poses, scene)
    assert dt < 1e-6 and dr < 1e-6


def append_observation(frame: KeyframeObservations, lid: int, point: np.ndarray, T_wc: np.ndarray,
                       with_depth: bool) -> KeyframeObservations:
    """A copy of a keyframe that also observes ``point`` as landmark ``lid``."""
    pc = transform_points(invert(T_wc), point[None])[0]
    uv = pc[:2] / pc[2] * [INTR.fx, INTR.fy] + [INTR.cx, INTR.cy]
    return with_obs(frame, landmark_ids=np.append(frame.landmark_ids, lid), uv=np.vstack([frame.uv, uv]),
                    depth=np.append(frame.depth, pc[2] if with_depth else 0.0),
                    sigma_scale=np.append(frame.sigma_scale, 1.0))


def test_landmark_needs_two_observations_and_depth():
    scene = make_scene(n_kf=4, seed=8)
    frames = list(scene.frames)
    point = np.array([0.2, 0.1, 3.0])
    frames[3] = append_observation(frames[3], 10_000, point, scene.poses[3], True)  # seen once
    for k in (0, 1):
        frames[k] = append_observation(frames[k], 10_001, point, scene.poses[k], False)  # never with depth
        frames[k] = append_observation(frames[k], 10_002, point, scene.poses[k], k == 1)  # control
    backend, updates = run(frames, BackendConfig())
    for lid in (10_000, 10_001):
        assert not backend.in_graph(lid) and backend.landmark(lid) is None
        assert all(lid not in u.landmarks for u in updates)
    assert backend.in_graph(10_002)
    np.testing.assert_allclose(backend.landmark(10_002), point, atol=1e-6)


def test_same_inputs_give_identical_outputs():
    scene = make_scene(n_kf=8, seed=9)
    rng = np.random.default_rng(9)
    frames = [with_obs(f, uv=f.uv + rng.normal(0, 1.0, f.uv.shape)) for f in scene.frames]
    _, a = run(frames, BackendConfig())
    _, b = run(frames, BackendConfig())
    for ua, ub in zip(a, b):
        assert ua.poses.keys() == ub.poses.keys() and ua.landmarks.keys() == ub.landmarks.keys()
        assert all(np.array_equal(ua.poses[k], ub.poses[k]) for k in ua.poses)
        assert all(np.array_equal(ua.landmarks[k], ub.landmarks[k]) for k in ua.landmarks)
        assert (ua.retired_landmarks, ua.outlier_observations, ua.n_factors) == \
               (ub.retired_landmarks, ub.outlier_observations, ub.n_factors)


def test_chi2_matches_gtsam_factor_errors():
    cfg = BackendConfig(pixel_sigma=1.5)
    factory = FactorFactory(INTR, cfg, BASELINE)
    rng = np.random.default_rng(10)
    T = se3_exp(np.array([0.1, -0.2, 0.05, 0.1, -0.05, 0.2]))
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3(T))
    rows, expected = [], []
    for i in range(6):
        point = transform_points(T, np.array([[rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(1, 4)]]))[0]
        values.insertPoint3(L(i), point)
        depth = rng.uniform(1, 4) if i % 2 == 0 else np.nan
        obs = Observation(0, i, rng.uniform(0, 640), rng.uniform(0, 480), depth, 1.2 ** i)
        e = factory.observation(obs, X(0), L(i)).unwhitenedError(values)
        expected.append(float(e @ e) / (cfg.pixel_sigma * obs.sigma_scale) ** 2)
        rows.append((point, [obs.u, obs.v, obs.u - factory.fx_baseline / depth], cfg.pixel_sigma * obs.sigma_scale))
    chi2 = reprojection_chi2(np.stack([T] * 6), np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                             np.array([r[2] for r in rows]), INTR, factory.fx_baseline)
    np.testing.assert_allclose(chi2, expected, rtol=1e-9)


def test_offending_key_parses_a_real_gtsam_exception():
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    graph.add(gtsam.GenericProjectionFactorCal3_S2(np.array([300.0, 200.0]), gtsam.noiseModel.Isotropic.Sigma(2, 1.0),
                                                   X(0), L(42), gtsam.Cal3_S2(525, 525, 0, 319.5, 239.5)))
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    values.insertPoint3(L(42), np.array([0.0, 0.0, 3.0]))
    with pytest.raises(RuntimeError) as info:
        gtsam.ISAM2().update(graph, values)
    key = offending_key(info.value)
    assert key is not None and chr(key.chr()) == "l" and key.index() == 42


def fail_first_update(backend: IsamBackend, message: str) -> None:
    """Make the back-end's next solver update raise like GTSAM does; later ones run normally."""
    real_update = backend._solver.update
    calls = []

    def failing_update(*args, **kwargs):
        if not calls:
            calls.append(1)
            raise RuntimeError(message)
        return real_update(*args, **kwargs)

    backend._solver.update = failing_update


def test_failed_update_drops_the_named_landmark():
    scene = make_scene(seed=11)
    backend = IsamBackend(INTR, BackendConfig(), BASELINE)
    updates = [backend.add_keyframe(f) for f in scene.frames[:5]]
    victim = int(next(iter(updates[-1].landmarks)))
    assert victim in scene.frames[5].landmark_ids
    fail_first_update(backend, f"Indeterminate linear system detected while working near variable\n{L(victim)} "
                               f"(Symbol: l{victim}).")
    failed = backend.add_keyframe(scene.frames[5])
    assert not failed.ok
    assert failed.retired_landmarks == [victim] and not backend.in_graph(victim)
    assert scene.frames[5].keyframe_id in failed.poses
    later = [backend.add_keyframe(f) for f in scene.frames[6:]]
    assert all(u.ok for u in later)
    dt, dr = pose_errors(later[-1].poses, scene)
    assert dt < 1e-3 and dr < 1e-3
    assert backend.n_landmarks > 200


def test_failed_update_without_a_name_keeps_the_pose_only():
    scene = make_scene(seed=12)
    backend = IsamBackend(INTR, BackendConfig(), BASELINE)
    before = [backend.add_keyframe(f) for f in scene.frames[:5]][-1]
    fail_first_update(backend, "something went wrong")
    failed = backend.add_keyframe(scene.frames[5])
    assert not failed.ok and failed.retired_landmarks == []
    assert failed.n_factors == before.n_factors + 1  # only the odometry factor went in
    np.testing.assert_allclose(failed.poses[scene.frames[5].keyframe_id], scene.poses[5], atol=1e-6)
    later = [backend.add_keyframe(f) for f in scene.frames[6:]]
    assert all(u.ok for u in later)
    assert later[-1].n_factors > failed.n_factors + 500
