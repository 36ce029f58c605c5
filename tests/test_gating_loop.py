"""The gating loop: motion memory, the background fit, and the tracker's use of masks and consensus."""

import subprocess
import sys

import cv2
import numpy as np
import pytest

from osslam.config import Config, MotionConfig, load_config
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.frontend.motion import _fit_background
from osslam.frontend.motion_memory import MotionMemory
from osslam.frontend.tracker import Tracker
from osslam.geometry import invert, transform_points
from osslam.types import CameraIntrinsics

from conftest import MODELS


def _depth(value_inside, value_outside=2.0, block=(slice(16, 32), slice(16, 32))):
    depth = np.full((48, 64), value_outside, np.float32)
    depth[block] = value_inside
    return depth


def _image():
    return (np.random.default_rng(7).random((48, 64)) * 255).astype(np.uint8)


def test_memory_keeps_a_paused_mover_then_forgets_it():
    memory = MotionMemory(frames=3, stride=4)
    moving = np.zeros((12, 16), bool)
    moving[4:8, 4:8] = True
    depth, image = _depth(1.0), _image()
    zero_flow, valid = np.zeros((48, 64, 2), np.float32), np.ones((48, 64), bool)
    memory.store(moving, depth)
    for _ in range(3):  # the mover pauses: no flow of its own, same depth, same look
        recalled = memory.recall(zero_flow, valid, depth, image, image)
        assert recalled[4:8, 4:8].all() and recalled.sum() == 16
        memory.store(np.zeros_like(moving), depth)
    assert not memory.recall(zero_flow, valid, depth, image, image).any()


def test_memory_keeps_a_cell_the_longer_the_more_frames_it_was_seen_moving():
    memory = MotionMemory(frames=10, stride=4, per_move=2)
    once, thrice = np.zeros((12, 16), bool), np.zeros((12, 16), bool)
    once[1:3, 1:3] = True  # a flicker of flow
    thrice[6:10, 8:12] = True  # a mover seen moving for three frames, then pausing
    depth, image = _depth(1.0), _image()
    zero_flow, valid = np.zeros((48, 64, 2), np.float32), np.ones((48, 64), bool)
    memory.store(once | thrice, depth)
    for _ in range(2):
        memory.recall(zero_flow, valid, depth, image, image)
        memory.store(thrice, depth)
    kept = []
    for _ in range(8):
        recalled = memory.recall(zero_flow, valid, depth, image, image)
        kept.append((bool(recalled[1:3, 1:3].all()), bool(recalled[6:10, 8:12].all())))
        assert not (recalled[1:3, 1:3].any() and not recalled[1:3, 1:3].all())
        memory.store(np.zeros_like(once), depth)
    # seen moving once: kept 2 frames, both past by now; seen moving three times: 6 frames after the last
    assert [k[0] for k in kept] == [False] * 8
    assert [k[1] for k in kept] == [True] * 6 + [False] * 2


def test_memory_follows_the_flow_and_drops_uncovered_background():
    memory = MotionMemory(frames=5, stride=4)
    moving = np.zeros((12, 16), bool)
    moving[4:8, 4:8] = True
    memory.store(moving, _depth(1.0))
    before = _image()
    # the mover went 8 px (two cells) right: its pixels' flow back to the previous frame is -8 px
    flow = np.zeros((48, 64, 2), np.float32)
    flow[16:32, 24:40, 0] = -8.0
    now = _depth(1.0, block=(slice(16, 32), slice(24, 40)))
    after = np.roll(before, 8, axis=1)
    recalled = memory.recall(flow, np.ones((48, 64), bool), now, after, before)
    assert recalled[4:8, 6:10].all()
    assert not recalled[4:8, 4:6].any()  # uncovered background is 1 m farther: not the mover

    memory.store(np.zeros_like(moving), now)
    invalid = np.ones((48, 64), bool)
    invalid[16:32, 24:40] = False  # flow failing its forward-backward check carries nothing
    assert not memory.recall(np.zeros_like(flow), invalid, now, after, after).any()
    moved = np.zeros_like(moving)
    moved[4:8, 6:10] = True
    memory.store(moved, now)
    changed = after.copy()
    changed[16:32, 24:40] = 255 - changed[16:32, 24:40]  # something else is seen there now
    assert not memory.recall(np.zeros_like(flow), np.ones((48, 64), bool), now, changed, after).any()
    memory.store(moved, now)
    assert memory.recall(np.zeros_like(flow), np.ones((48, 64), bool), now, after, after)[4:8, 6:10].all()


def _mover_over_background():
    """Points spread over a cluttered background moving with the camera, and a denser box moving on its own."""
    intr = CameraIntrinsics(fx=500.0, fy=500.0, cx=320.0, cy=240.0)
    bg = np.mgrid[8:480:16, 8:640:16].reshape(2, -1).T[:, ::-1].astype(float)  # spread over the image
    box = np.mgrid[180:300:3, 250:400:3].reshape(2, -1).T[:, ::-1].astype(float)  # dense, compact
    pixels = np.vstack([bg, box])
    rng = np.random.default_rng(0)  # a cluttered background: two depth planes alone are ambiguous
    z = np.concatenate([rng.uniform(1.5, 4.0, len(bg)), np.full(len(box), 1.0)])
    X = intr.backproject(pixels, z)
    camera, mover = np.eye(4), np.eye(4)
    camera[:3, 3] = [0.03, -0.01, 0.02]
    mover[:3, 3] = [-0.04, 0.03, 0.0]
    uv = np.vstack([intr.project(transform_points(camera, X[: len(bg)])),
                    intr.project(transform_points(camera @ mover, X[len(bg):]))])
    return intr.K, X, uv, pixels, len(bg), camera, mover


def test_background_fit_prefers_the_spread_body_over_a_denser_mover():
    K, X, uv, pixels, n_bg, camera, _ = _mover_over_background()
    assert len(X) - n_bg > n_bg
    T, n_inliers = _fit_background(X, uv, np.ones(len(X), bool), pixels, (640, 480), K, MotionConfig())
    assert T is not None and n_inliers >= 0.9 * n_bg
    np.testing.assert_allclose(T[:3, 3], camera[:3, 3], atol=2e-3)


def test_background_fit_weighs_a_guess_by_the_same_spread():
    K, X, uv, pixels, _, camera, mover = _mover_over_background()
    usable = np.ones(len(X), bool)
    T, _ = _fit_background(X, uv, usable, pixels, (640, 480), K, MotionConfig(), guess=camera)
    np.testing.assert_array_equal(T, camera)  # the right guess is kept as it is
    T, _ = _fit_background(X, uv, usable, pixels, (640, 480), K, MotionConfig(), guess=camera @ mover)
    np.testing.assert_allclose(T[:3, 3], camera[:3, 3], atol=2e-3)  # a guess that follows the box loses


def test_background_fit_stops_when_the_points_left_cannot_spread_further(monkeypatch):
    from osslam.frontend import motion

    K, X, uv, pixels, _, camera, _ = _mover_over_background()
    calls = []
    fit = motion._fit_rigid
    monkeypatch.setattr(motion, "_fit_rigid", lambda *a, **k: calls.append(len(a[0])) or fit(*a, **k))
    usable = np.ones(len(X), bool)
    T, n = motion._fit_background(X, uv, usable, pixels, (640, 480), K, MotionConfig(max_bodies=3))
    # the background reaches every cell; the box left over reaches a few, so it is not fitted
    assert len(calls) == 1
    np.testing.assert_allclose(T[:3, 3], camera[:3, 3], atol=2e-3)
    T1, n1 = motion._fit_background(X, uv, usable, pixels, (640, 480), K, MotionConfig(max_bodies=1))
    assert np.array_equal(T, T1) and n == n1
    calls.clear()
    T, _ = motion._fit_background(X, uv, usable, pixels, (640, 480), K, MotionConfig(), guess=camera)
    assert not calls and np.array_equal(T, camera)  # a guess that explains every cell leaves nothing to fit


@pytest.fixture(scope="module")
def room():
    return SyntheticSequence(SyntheticConfig(n_frames=3, seed=1))


def test_tracker_ignores_a_moved_object_and_retires_its_landmarks(room):
    cfg = load_config("synthetic")
    tracker = Tracker(cfg, room.intrinsics)
    f0, f1, f2 = room[0], room[1], room[2]
    gray = lambda f: f.rgb.mean(axis=2).astype(np.uint8)  # noqa: E731
    tracker.commit(tracker.estimate(0, f0.timestamp, gray(f0), f0.depth))
    kf = tracker.map.keyframes[0]
    ids = kf.landmark_ids
    # an "object": the 40 % of landmarks seen leftmost in frame 0, moved 4 cm since they were mapped
    pc = transform_points(invert(kf.pose), tracker.map.positions[ids])
    u = pc[:, 0] / pc[:, 2] * room.intrinsics.fx + room.intrinsics.cx
    edge = np.quantile(u, 0.4)
    on_object = ids[u < edge]
    tracker.map.positions[on_object] += [0.04, 0.0, 0.0]

    pending = tracker.estimate(1, f1.timestamp, gray(f1), f1.depth)
    matched = pending.ids[pending.matches.query[pending.estimate.inliers]]
    T_true = invert(f0.gt_pose) @ f1.gt_pose
    assert np.linalg.norm(invert(pending.estimate.T_cw)[:3, 3] - T_true[:3, 3]) < 0.01
    np.testing.assert_allclose(pending.tracked_motion, T_true, atol=0.01)
    assert pending.ego_motion is None  # a map one frame old has no mature landmarks to anchor the pose

    dynamic = np.zeros((room.intrinsics.height, room.intrinsics.width), bool)
    dynamic[:, : int(edge) + 20] = True
    out = tracker.commit(pending, dynamic, dynamic)
    assert out.state.value == "ok"
    assert out.timings_ms["masked"] > 0  # the pose refined without the masked observations, timed
    assert tracker.map.alive[on_object].mean() > 0.9  # seen on a moving surface once: not yet retired
    pending = tracker.estimate(2, f2.timestamp, gray(f2), f2.depth)
    explained = pending.ids[pending.matches.query[pending.estimate.inliers]]
    out = tracker.commit(pending, dynamic, dynamic)
    assert out.state.value == "ok"
    # the object's landmarks retire, but for a few the pose explains within their coarse octave's noise
    kept = on_object[tracker.map.alive[on_object]]
    assert len(kept) <= 0.05 * len(on_object) and np.isin(kept, np.union1d(matched, explained)).all()
    # only landmarks seen inside the mask are retired: the object's, and static ones on the masked strip
    u2 = room.intrinsics.project(transform_points(invert(f2.gt_pose), tracker.map.positions[ids]))[:, 0]
    retired = ids[~tracker.map.alive[ids]]
    assert set(retired.tolist()) <= set(on_object.tolist()) | set(ids[u2 < edge + 25].tolist())
    assert tracker.map.alive[ids[u2 > edge + 40]].all()
    # static landmarks on the masked strip that the pose explains are not taken for the mover
    explained_on_strip = np.intersect1d(explained, ids[(u2 < edge + 15) & ~np.isin(ids, on_object)])
    assert len(explained_on_strip) > 10 and tracker.map.alive[explained_on_strip].all()
    assert set(tracker._take_moving().tolist()) == set(retired.tolist())
    # the local map kept through the retirements is the one its keyframes give afresh
    kept_local = tracker._local_landmarks().copy()
    tracker._local_ids = None
    assert len(kept_local) and np.array_equal(kept_local, tracker._local_landmarks())
    assert not np.isin(retired, kept_local).any()


def test_first_keyframe_takes_no_landmarks_from_the_mask(room):
    tracker = Tracker(load_config("synthetic"), room.intrinsics)
    f0 = room[0]
    pending = tracker.estimate(0, f0.timestamp, f0.rgb.mean(axis=2).astype(np.uint8), f0.depth)
    dynamic = np.zeros((room.intrinsics.height, room.intrinsics.width), bool)
    dynamic[:, 320:] = True
    out = tracker.commit(pending, dynamic)
    assert out.is_keyframe and len(out.keyframe.uv) > 100
    assert (out.keyframe.uv[:, 0] < 322).all()


def test_gate_start_and_finish_come_in_pairs(room):
    from osslam.frontend.gating import DynamicGate

    cfg = Config()
    cfg.detection.enabled = False
    gate = DynamicGate(cfg, room.intrinsics)
    with pytest.raises(RuntimeError, match="before start"):
        gate.finish()
    f = room[0]
    gray = f.rgb.mean(axis=2).astype(np.uint8)
    gate.start(f.rgb, gray, f.depth)
    with pytest.raises(RuntimeError, match="twice"):
        gate.start(f.rgb, gray, f.depth)
    assert gate.finish().segmentation is None  # the first frame has nothing to compare with
    g1 = room[1].rgb.mean(axis=2).astype(np.uint8)
    result = gate.process(room[1].rgb, g1, room[1].depth, np.linalg.inv(f.gt_pose) @ room[1].gt_pose)
    assert result.segmentation.ok and result.mask.mean() < 0.01
    gate.close()


def _box_frames(room, shifts):
    """Room frame 0 seen by a still camera, with a textured box in front at each x shift: (rgb, gray, depth, box)."""
    f = room[0]
    rng = np.random.default_rng(3)
    texture = rng.integers(0, 255, (12, 10), np.uint8).repeat(8, 0).repeat(8, 1)
    near = float(np.nanmin(f.depth[f.depth > 0])) * 0.7
    frames = []
    for dx in shifts:
        rgb, depth = f.rgb.copy(), f.depth.copy()
        box = np.zeros(depth.shape, bool)
        box[180:276, 200 + dx : 280 + dx] = True
        rgb[box] = np.repeat(texture.ravel()[:, None], 3, axis=1)
        depth[box] = near
        frames.append((rgb, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), depth, box))
    return frames


@pytest.mark.parametrize("memory_frames", [30, 0])
def test_the_gate_keeps_a_paused_mover_masked_while_its_memory_lasts(room, memory_frames):
    cfg = Config()
    cfg.detection.enabled = False
    cfg.motion.memory_frames = memory_frames
    from osslam.frontend.gating import DynamicGate

    gate = DynamicGate(cfg, room.intrinsics)
    covered = []
    for rgb, gray, depth, box in _box_frames(room, [0, 6, 12, 18, 18, 18]):  # moves, then pauses
        result = gate.process(rgb, gray, depth, np.eye(4))
        covered.append(result.mask[box].mean())
    gate.close()
    assert min(covered[1:4]) > 0.8  # seen moving
    if memory_frames:
        assert min(covered[4:]) > 0.8  # paused: recalled by the memory
    else:
        assert max(covered[4:]) < 0.2


def test_the_gate_segments_with_the_predicted_ego_motion_and_redoes_it_where_tracking_disagrees(room):
    from osslam.frontend.gating import DynamicGate

    frames = _box_frames(room, [0, 6, 12, 18, 24, 30])
    results = {}
    for predict in (True, False):
        cfg = Config()
        cfg.detection.enabled = False
        cfg.motion.predict = predict
        gate = DynamicGate(cfg, room.intrinsics)
        results[predict] = [gate.process(rgb, gray, depth, np.eye(4)) for rgb, gray, depth, _ in frames]
        gate.close()
    # from the second frame on (the first has no flow), the last tracked ego-motion predicts the next
    # and the tracked one confirms it
    assert [r.predicted for r in results[True]] == [False, True, True, True, True, True]
    assert not any(r.predicted for r in results[False])
    for ahead, after, (*_, box) in zip(results[True][1:], results[False][1:], frames[1:]):
        assert ahead.mask[box].mean() > 0.8
        assert (ahead.mask ^ after.mask).sum() <= 0.02 * after.mask.sum()

    cfg = Config()
    cfg.detection.enabled = False
    gate = DynamicGate(cfg, room.intrinsics)
    # without an anchored ego-motion nothing confirms a prediction: the flow's own fit is redone
    assert not any(gate.process(rgb, gray, depth).predicted for rgb, gray, depth, _ in frames[:4])
    jumped = np.eye(4)
    jumped[0, 3] = 0.05  # tracking says the camera moved 5 cm: the prediction is not confirmed
    rgb, gray, depth, box = frames[4]
    result = gate.process(rgb, gray, depth, jumped)
    gate.close()
    assert not result.predicted
    assert result.mask[box].mean() > 0.8  # redone: the flow contradicts the jump, so the background is re-fitted


def test_a_mask_carried_within_its_reach_equals_the_whole_images_warp():
    from osslam.frontend.flow.base import flow_targets
    from osslam.frontend.gating import _carried, _reach

    rng = np.random.default_rng(1)
    for _ in range(20):
        flow = cv2.resize(rng.normal(0, 8, (12, 16, 2)).astype(np.float32), (640, 480))  # smooth, up to ~25 px
        mask = np.zeros((480, 640), bool)
        x, y = rng.integers(0, 600), rng.integers(0, 440)
        mask[y:y + rng.integers(1, 200), x:x + rng.integers(1, 200)] = True
        mask &= rng.random((480, 640)) > 0.3
        whole = cv2.remap(mask.view(np.uint8), flow_targets(flow), None, cv2.INTER_NEAREST) > 0
        assert whole.any()
        np.testing.assert_array_equal(_carried(mask, flow, _reach(flow)), whole)
    assert not _carried(np.zeros((480, 640), bool), flow, _reach(flow)).any()


def test_the_detector_runs_every_interval_frames_and_people_are_carried_between_segmentations(room, tmp_path):
    from osslam.frontend.flow import FlowField
    from osslam.frontend.fusion import Detection
    from osslam.frontend.gating import DynamicGate, carried_detections, carried_people

    h, w = room[0].depth.shape
    box = np.zeros((h, w), bool)
    box[100:200, 50:150] = True
    shift = np.zeros((h, w, 2), np.float32)
    shift[..., 0] = -3.0  # each pixel of the current frame was 3 px to its left in the previous one
    moved = carried_detections([Detection(box, "person", 0.9, True)], FlowField(shift, np.ones((h, w), bool)))
    assert (moved[0].label, moved[0].score, moved[0].dynamic) == ("person", 0.9, True)
    assert np.array_equal(moved[0].mask, np.roll(box, 3, axis=1))
    chair = np.zeros((h, w), bool)
    chair[10:20, 200:220] = True
    field = FlowField(shift, np.ones((h, w), bool))
    people = carried_people([Detection(box, "person", 0.9, True), Detection(chair, "chair", 0.8, False)], field)
    assert np.array_equal(people, np.roll(box, 3, axis=1))  # people only, moved by the flow
    assert carried_people([Detection(chair, "chair", 0.8, False)], field) is None

    class CountingDetector:
        """Records the frames it runs on and whether it was given people's masks."""

        def __init__(self):
            self.frame, self.calls = 0, []

        def detect(self, rgb, depth, people=None):
            self.calls.append((self.frame, people is not None))
            return [Detection(box, "person", 0.9, True)]

    def detector_calls(*settings):
        cfg = load_config("synthetic", ["gating.enabled=true", *settings, f"models.dir={tmp_path}"])
        gate = DynamicGate(cfg, room.intrinsics)
        gate.detector = CountingDetector()
        for index in range(len(room)):
            f = room[index]
            gate.detector.frame = index
            result = gate.process(f.rgb, f.rgb.mean(axis=2).astype(np.uint8), f.depth)
            assert result.mask[box].mean() > 0.9  # carried masks keep the person masked between detections
        gate.close()
        return gate.detector.calls

    for interval, expected in ((1, [0, 1, 2]), (2, [0, 2]), (3, [0])):
        assert [frame for frame, _ in detector_calls(f"detection.interval={interval}")] == expected
    for person_interval, expected in ((1, [False] * 3), (2, [False, True, False]), (3, [False, True, True])):
        # people segmented on every person_interval-th detection, their masks carried between
        assert [given for _, given in detector_calls("detection.interval=1",
                                                      f"detection.person_interval={person_interval}")] == expected


def test_a_pose_is_anchored_once_the_map_holds_mature_landmarks(room):
    cfg = load_config("synthetic", ["tracking.mature_frames=0", "tracking.mature_observations=1"])
    tracker = Tracker(cfg, room.intrinsics)
    f0, f1 = room[0], room[1]
    gray = lambda f: f.rgb.mean(axis=2).astype(np.uint8)  # noqa: E731
    tracker.commit(tracker.estimate(0, f0.timestamp, gray(f0), f0.depth))
    pending = tracker.estimate(1, f1.timestamp, gray(f1), f1.depth)
    assert pending.anchored
    np.testing.assert_allclose(pending.ego_motion, invert(f0.gt_pose) @ f1.gt_pose, atol=0.01)
    assert "masked" not in tracker.commit(pending).timings_ms  # no mask, nothing timed for one


@pytest.mark.parametrize("arbiter", [5, 0])
def test_a_few_mature_landmarks_pick_the_static_scene_over_a_larger_mover(room, arbiter):
    cfg = load_config("synthetic", ["tracking.mature_frames=1", "tracking.mature_observations=1",
                                    f"tracking.arbiter_mature={arbiter}"])
    tracker = Tracker(cfg, room.intrinsics)
    f0, f1 = room[0], room[1]
    gray = lambda f: f.rgb.mean(axis=2).astype(np.uint8)  # noqa: E731
    tracker.commit(tracker.estimate(0, f0.timestamp, gray(f0), f0.depth))
    ids = tracker.map.keyframes[0].landmark_ids
    u = room.intrinsics.project(transform_points(invert(f0.gt_pose), tracker.map.positions[ids]))[:, 0]
    order = ids[np.argsort(u)]
    mover, static = order[: int(0.7 * len(order))], order[int(0.7 * len(order)):]
    tracker.map.positions[mover] += [0.04, 0.0, 0.0]  # 70 % of the map moved 4 cm since it was mapped
    tracker.map.born[ids] = 1  # mapped just now: none of them mature at frame 1 ...
    tracker.map.born[static[::4][:12]] = 0  # ... but for a dozen static ones, too few for a consensus of their own
    assert 12 < cfg.tracking.min_matches

    pending = tracker.estimate(1, f1.timestamp, gray(f1), f1.depth)
    error = np.linalg.norm(invert(pending.estimate.T_cw)[:3, 3] - (invert(f0.gt_pose) @ f1.gt_pose)[:3, 3])
    assert not pending.anchored
    if arbiter:
        assert error < 0.01
    else:  # the fit of all matches follows the majority, the mover
        assert error > 0.02


def test_the_keyframe_observing_most_landmarks_is_found():
    from osslam.frontend.local_map import Keyframe, LandmarkMap

    lmap = LandmarkMap()
    ids = lmap.add_landmarks(np.zeros((6, 3)), np.zeros((6, 32), np.uint8), np.zeros(6, np.int32), frame_index=7)
    assert (lmap.born[ids] == 7).all()
    lmap.add_keyframe(Keyframe(0, 0, 0.0, np.eye(4), ids[:2]))
    lmap.add_keyframe(Keyframe(1, 5, 0.1, np.eye(4), ids[1:]))
    assert lmap.most_observing(ids[2:4]) == 1
    assert lmap.most_observing(np.zeros(0, np.int64)) is None
    assert lmap.seen[ids].tolist() == [1, 2, 1, 1, 1, 1]
    lmap.drop_observation(1, ids[1])
    lmap.drop_observation(1, ids[1])  # an observation already dropped is not counted twice
    assert lmap.seen[ids].tolist() == [1, 1, 1, 1, 1, 1]


def test_a_mask_leaving_too_few_observations_keeps_the_pose_it_had(room):
    tracker = Tracker(load_config("synthetic"), room.intrinsics)
    f0, f1 = room[0], room[1]
    gray = lambda f: f.rgb.mean(axis=2).astype(np.uint8)  # noqa: E731
    tracker.commit(tracker.estimate(0, f0.timestamp, gray(f0), f0.depth))
    pending = tracker.estimate(1, f1.timestamp, gray(f1), f1.depth)
    before = pending.estimate.T_cw.copy()
    dynamic = np.ones((room.intrinsics.height, room.intrinsics.width), bool)
    dynamic[:, :4] = False  # a strip too thin to hold a pose
    out = tracker.commit(pending, dynamic)
    np.testing.assert_allclose(invert(out.pose), before)
    assert out.n_inliers < tracker.cfg.tracking.min_inliers


def test_the_gate_in_a_child_process_gives_what_the_gate_on_a_thread_gives(room):
    from osslam.frontend.gate_process import GateProcess
    from osslam.frontend.gating import DynamicGate

    frames = _box_frames(room, [0, 6, 12, 18, 24, 30])
    cfg = Config()
    cfg.detection.enabled = False
    here, there = DynamicGate(cfg, room.intrinsics), GateProcess(cfg, room.intrinsics)
    for i, (rgb, gray, depth, box) in enumerate(frames):
        depth = depth.astype(np.float64) if i % 2 else depth  # both depth types pass
        ego = None if i == 3 else np.eye(4)  # one frame without a tracked ego-motion
        for gate in (here, there):
            gate.start(rgb, gray, depth)
        ours, theirs = here.finish(ego, None, np.eye(4)), there.finish(ego, None, np.eye(4))
        assert (ours.segmented, ours.predicted) == (theirs.segmented, theirs.predicted)
        for name in ("mask", "map_mask", "moving_now"):
            a, b = getattr(ours, name), getattr(theirs, name)
            assert (a is None) == (b is None) and (a is None or np.array_equal(a, b)), name
        assert (here.prior() is None) == (there.prior() is None)
        assert here.prior() is None or np.array_equal(here.prior(), there.prior())
        assert set(ours.timings_ms) == set(theirs.timings_ms) and theirs.cost_ms > 0
    assert ours.mask[box].mean() > 0.8  # the mover was found
    here.close()
    there.start(rgb, gray, depth)  # a caller interrupted between start and finish still closes it
    there.close()
    assert there._process.returncode == 0


@pytest.mark.skipif(not (MODELS / "yolo-fastest-1.1" / "yolo-fastest-1.1.weights").is_file(),
                    reason=f"{MODELS} not present")
def test_the_gate_process_sends_the_colour_image_only_to_frames_it_detects_in(room):
    from osslam.frontend.detection.detector import PERSON
    from osslam.frontend.gate_process import GateProcess
    from osslam.frontend.gating import DynamicGate

    photo = cv2.imread(str(MODELS / "samples" / "person.jpg"))[:, 140:320]  # the person and some field around
    photo = cv2.cvtColor(cv2.resize(photo, (300 * photo.shape[1] // photo.shape[0], 300)), cv2.COLOR_BGR2RGB)
    f = room[0]
    near = float(np.nanmin(f.depth[f.depth > 0])) * 0.7
    frames = []
    for dx in range(0, 280, 40):  # the person moves 40 px a frame: a stale colour image would show it elsewhere
        rgb, depth = f.rgb.copy(), f.depth.copy()
        x0 = 20 + dx
        rgb[90:390, x0 : x0 + photo.shape[1]] = photo
        depth[90:390, x0 : x0 + photo.shape[1]] = near
        frames.append((rgb, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), depth, x0))
    cfg = Config()
    cfg.models.dir = str(MODELS)
    cfg.detection.interval = 3
    here, there = DynamicGate(cfg, room.intrinsics), GateProcess(cfg, room.intrinsics)
    with pytest.raises(ValueError, match="needs the colour image"):
        here.start(None, frames[0][1], frames[0][2])  # the first frame is detected in
    wanted, people = [], []
    for rgb, gray, depth, x0 in frames:
        wanted.append(here.wants_colour)
        for gate in (here, there):
            gate.start(rgb, gray, depth)
        ours, theirs = here.finish(np.eye(4), None, np.eye(4)), there.finish(np.eye(4), None, np.eye(4))
        assert np.array_equal(ours.mask, theirs.mask)
        people.append(any(d.label == PERSON and d.mask[200:300, x0 + 40 : x0 + 80].mean() > 0.5
                          for d in here._detections))
    here.close()
    there.close()
    assert wanted == [True, False, False, True, False, False, True]
    assert all(people)  # detected or carried by the flow to where the person is in each frame


def test_the_gate_process_raises_what_its_child_raises_and_says_when_the_child_is_gone(room, tmp_path, caplog):
    from osslam.frontend.gate_process import GateProcess, GateWorkerError, open_gate

    cfg = Config()
    cfg.flow.dis_preset = "fastest"
    with pytest.raises(ValueError, match="flow.dis_preset 'fastest' unknown"):
        GateProcess(cfg, room.intrinsics)
    cfg = Config()
    cfg.gating.worker = "fibre"
    with pytest.raises(ValueError, match="gating.worker 'fibre' unknown"):
        open_gate(cfg, room.intrinsics)
    cfg = Config()
    cfg.models.dir = str(tmp_path)  # no models: the child says so, through this process's log
    with caplog.at_level("WARNING"):
        gate = GateProcess(cfg, room.intrinsics)
    assert "flow and geometry only" in caplog.text
    gate._process.kill()
    gate._process.wait()
    rgb, gray, depth, _ = _box_frames(room, [0])[0]
    with pytest.raises(GateWorkerError, match=r"ended without answering \(exit code -9\)"):
        gate.start(rgb, gray, depth)
        gate.finish()
    gate.close()  # and it still closes


def test_a_program_that_ends_without_closing_the_gate_process_ends_quietly(tmp_path):
    script = f"""
from osslam.config import Config
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.frontend.gate_process import GateProcess
import cv2, numpy as np
room = SyntheticSequence(SyntheticConfig(n_frames=2, seed=1))
cfg = Config()
cfg.models.dir = {str(tmp_path)!r}
gate = GateProcess(cfg, room.intrinsics)
for i in range(2):
    f = room[i]
    gate.start(f.rgb, cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY), f.depth)
    gate.finish(np.eye(4), None, np.eye(4))
print("ended")
"""
    # the child writes to the same stderr, so this returns once the child has ended too
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith("ended"), done.stderr
    assert "Traceback" not in done.stderr, done.stderr


def test_a_failure_in_the_bookkeeping_after_a_mask_is_raised_by_the_next_finish(room, monkeypatch):
    from osslam.frontend.gating import DynamicGate

    def broken(self, depth, pose):
        raise RuntimeError("depth history broke")

    cfg = Config()
    cfg.detection.enabled = False
    gate = DynamicGate(cfg, room.intrinsics)
    monkeypatch.setattr(DynamicGate, "_remember_depth", broken)
    rgb, gray, depth, _ = _box_frames(room, [0])[0]
    gate.process(rgb, gray, depth, np.eye(4))  # its bookkeeping fails on the worker, after the mask
    with pytest.raises(RuntimeError, match="depth history broke"):
        gate.process(rgb, gray, depth, np.eye(4))  # nobody asked for the prior in between
    gate.close()
