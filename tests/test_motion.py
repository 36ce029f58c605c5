"""Dense flow and rigid motion segmentation: quiet on static scenes, finds a pasted mover."""

import cv2
import numpy as np
import pytest

from osslam.config import Config, FlowConfig, load_config
from osslam.datasets import open_sequence
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.errors import OsslamError
from osslam.frontend.flow import forward_backward_valid, make_flow_estimator
from osslam.frontend.motion import motion_grid, segment_motion, turned_to_the_flow, unexplained_share
from osslam.imaging import depth_grid

from conftest import FR1_XYZ


def _gray(frame):
    return cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)


def _patch(seed=0, h=140, w=110):
    rng = np.random.default_rng(seed)
    patch = np.full((h, w), 120, np.uint8)
    for _ in range(60):
        x, y, s = int(rng.integers(0, w - 10)), int(rng.integers(0, h - 10)), int(rng.integers(4, 15))
        cv2.rectangle(patch, (x, y), (x + s, y + s), int(rng.integers(0, 255)), -1)
    return patch


@pytest.mark.parametrize("cfg", [FlowConfig(), FlowConfig(dis_iterations=0, dis_patch_stride=0, dis_refinement=-1,
                                                          dis_check_patch_stride=0),
                                 FlowConfig(dis_check_refinement=-1, dis_check_patch_stride=0)],
                         ids=["default", "medium-preset", "check-as-forward"])
def test_dis_flow_recovers_a_known_shift(cfg):
    seq = SyntheticSequence(SyntheticConfig(n_frames=1, image_noise=0))
    img = _gray(seq[0])
    M = np.float32([[1, 0, 5], [0, 1, -3]])
    shifted = cv2.warpAffine(img, M, (640, 480), borderMode=cv2.BORDER_REFLECT)
    field = make_flow_estimator(cfg).compute(img, shifted)
    inner = field.valid[40:-40, 40:-40]
    assert inner.mean() > 0.3
    fx = field.flow[40:-40, 40:-40, 0][inner]
    fy = field.flow[40:-40, 40:-40, 1][inner]
    assert abs(np.median(fx) - 5) < 0.3 and abs(np.median(fy) + 3) < 0.3


def test_dis_settings_replace_the_presets_and_bad_ones_are_refused():
    dis = make_flow_estimator(FlowConfig(dis_iterations=7, dis_patch_stride=3))._dis
    assert dis.getGradientDescentIterations() == 7 and dis.getPatchStride() == 3
    preset = make_flow_estimator(FlowConfig(dis_iterations=0, dis_patch_stride=0, dis_refinement=-1))._dis
    assert preset.getGradientDescentIterations() == 25 and preset.getPatchStride() == 3  # OpenCV's medium
    assert preset.getVariationalRefinementIterations() == 5
    flow = make_flow_estimator(FlowConfig(dis_refinement=3, dis_check_refinement=1, dis_check_patch_stride=5))
    assert flow._dis.getVariationalRefinementIterations() == 3 and flow._dis.getPatchStride() == 4
    assert flow._check.getVariationalRefinementIterations() == 1 and flow._check.getPatchStride() == 5
    same = make_flow_estimator(FlowConfig(dis_check_refinement=-1, dis_check_patch_stride=0))
    assert same._check is same._dis  # nothing of its own: the forward flow's instance checks itself
    follows = make_flow_estimator(FlowConfig(dis_refinement=4, dis_check_refinement=-1))._check
    assert follows.getVariationalRefinementIterations() == 4 and follows.getPatchStride() == 6
    with pytest.raises(ValueError, match="flow.dis_patch_stride 9 exceeds"):
        make_flow_estimator(FlowConfig(dis_patch_stride=9))
    with pytest.raises(ValueError, match="dis_check_patch_stride"):
        make_flow_estimator(FlowConfig(dis_check_patch_stride=-1))
    with pytest.raises(ValueError, match="flow.dis_check_patch_stride 9 exceeds"):
        make_flow_estimator(FlowConfig(dis_check_patch_stride=9))
    with pytest.raises(ValueError, match="dis_iterations"):
        make_flow_estimator(FlowConfig(dis_iterations=-1))


def test_forward_backward_check_flags_inconsistent_flow():
    fwd = np.full((20, 30, 2), 2.0, np.float32)
    bwd = -fwd.copy()
    assert forward_backward_valid(fwd, bwd, 0.5)[5:15, 5:25].all()
    bwd[:, :, 0] = 1.0  # backward flow does not return
    assert not forward_backward_valid(fwd, bwd, 0.5).any()


def test_unknown_and_learned_backends_give_clear_errors():
    with pytest.raises(OsslamError, match="learned"):
        make_flow_estimator(FlowConfig(backend="learned", learned_preset="missing"))
    with pytest.raises(OsslamError, match="unknown"):
        make_flow_estimator(FlowConfig(backend="farneback"))


def test_static_synthetic_scene_with_moving_camera_stays_quiet():
    cfg = Config()
    seq = SyntheticSequence(SyntheticConfig(n_frames=40, seed=2))
    flow = make_flow_estimator(cfg.flow)
    for i in (5, 20, 35):
        cur, prev = seq[i], seq[i - 1]
        seg = segment_motion(flow.compute(_gray(cur), _gray(prev)), cur.depth, seq.intrinsics, cfg.motion)
        assert seg.ok
        assert seg.mask.mean() < 0.005
        # the ego-motion matches the ground truth relative pose
        T_true = np.linalg.inv(prev.gt_pose) @ cur.gt_pose
        assert np.linalg.norm(seg.ego_motion[:3, 3] - T_true[:3, 3]) < 0.01


def _paste_mover(cur, prev, shift, depth=0.9, x0=250, y0=200):
    patch = _patch()
    h, w = patch.shape
    g, pg, d = _gray(cur), _gray(prev), cur.depth.copy()
    dx, dy = shift
    pg[y0 : y0 + h, x0 : x0 + w] = patch
    g[y0 + dy : y0 + dy + h, x0 + dx : x0 + dx + w] = patch
    d[y0 + dy : y0 + dy + h, x0 + dx : x0 + dx + w] = depth
    truth = np.zeros(d.shape, bool)
    truth[y0 + dy : y0 + dy + h, x0 + dx : x0 + dx + w] = True
    return g, pg, d, truth


def test_pasted_mover_is_segmented_with_its_centre():
    cfg = Config()
    seq = SyntheticSequence(SyntheticConfig(n_frames=12, seed=4))
    g, pg, d, truth = _paste_mover(seq[10], seq[9], (14, 4))
    seg = segment_motion(make_flow_estimator(cfg.flow).compute(g, pg), d, seq.intrinsics, cfg.motion)
    mask = seg.mask
    assert (mask & truth).sum() / truth.sum() > 0.7
    assert (mask & truth).sum() / mask.sum() > 0.85
    biggest = max(seg.objects, key=lambda o: o.area)
    ys, xs = np.nonzero(truth)
    assert abs(biggest.centre[0] - xs.mean()) < 15 and abs(biggest.centre[1] - ys.mean()) < 15
    assert biggest.probability > 0.5 and biggest.motion is not None


@pytest.mark.skipif(not (FR1_XYZ / "rgb.txt").is_file(), reason=f"{FR1_XYZ} not present")
def test_fr1_xyz_static_pairs_stay_quiet_and_pasted_mover_is_found():
    cfg = load_config("tum_fr1")
    seq = open_sequence(FR1_XYZ, cfg)
    flow = make_flow_estimator(cfg.flow)
    fractions = []
    for i in range(1, len(seq), 40):
        cur, prev = seq[i], seq[i - 1]
        seg = segment_motion(flow.compute(_gray(cur), _gray(prev)), cur.depth, seq.intrinsics, cfg.motion)
        fractions.append(seg.mask.mean())
    assert np.mean(fractions) < 0.003 and max(fractions) < 0.02
    g, pg, d, truth = _paste_mover(seq[300], seq[299], (0, 8))
    seg = segment_motion(flow.compute(g, pg), d, seq.intrinsics, cfg.motion)
    assert (seg.mask & truth).sum() / truth.sum() > 0.7


def test_dynamic_gate_masks_the_mover_and_system_runs_gated():
    from osslam.frontend.gating import DynamicGate
    from osslam.system import System

    cfg = Config()
    cfg.detection.enabled = False
    seq = SyntheticSequence(SyntheticConfig(n_frames=12, seed=3))
    g, pg, d, truth = _paste_mover(seq[10], seq[9], (14, 4))
    gate = DynamicGate(cfg, seq.intrinsics)
    rgb = lambda gray: np.repeat(gray[:, :, None], 3, axis=2)  # noqa: E731
    first = gate.process(rgb(pg), pg, seq[9].depth)
    assert not first.mask.any() and first.segmentation is None and gate.prior() is None
    second = gate.process(rgb(g), g, d)
    assert (second.mask & truth).sum() / truth.sum() > 0.8
    prior = gate.prior()  # where the mover may be in the next frame: its mask grown
    assert prior[second.mask].all() and prior.sum() > second.mask.sum()
    assert {"flow", "motion", "fusion"} <= set(second.timings_ms)

    # without the consensus of mature landmarks every pose counts as anchored, as a long run's do
    gated = load_config("synthetic", ["gating.enabled=true", "detection.enabled=false", "tracking.consensus=false"])
    with System(gated, seq.intrinsics) as slam:
        results = [slam.track(f.rgb, f.depth, f.timestamp) for f in seq]
    # the map starts at the second frame, the first with flow to tell movers from the scene
    assert results[0].state == "initializing" and results[1].is_keyframe
    assert all(r.state == "ok" for r in results[1:])
    stats = slam.stats()
    assert {"segmentation", "finish"} <= set(stats["timings_ms"])
    # from the third frame on the gate segments beside tracking (the second gives the first
    # ego-motion to predict from), and the anchored tracked motion confirms it
    assert len(seq) - 2 >= stats["gate_predicted_frames"] >= 0.7 * (len(seq) - 2)
    assert stats["gate_process_peak_rss_mb"] > 0  # the gate ran in its own process, whose memory is counted apart


def test_a_partly_moving_surface_is_completed_but_not_the_large_one_behind():
    from osslam.config import MotionConfig
    from osslam.frontend.motion import _surfaces, _whole_surfaces

    z = np.full((60, 80), 3.0)
    z[20:40, 10:30] = 1.0  # a box floating in front of a wall
    has_depth = np.ones_like(z, bool)
    cells = np.zeros_like(z, bool)
    cells[20:40, 10:18] = True  # only its leading edge moved
    cells[0:10, 50:80] = True  # a patch of the wall too: flow errors, say
    cfg = MotionConfig()
    surfaces = _surfaces(z, has_depth, cfg.surface_step)
    out, cut_off = _whole_surfaces(cells, surfaces, cfg)
    assert out[20:40, 10:30].all()
    assert not out[45:, :].any() and out[0:10, 50:80].all()  # the wall is too large to be taken whole
    assert not (cut_off & ~out).any()  # the map adds nothing: the wall is too large, the box inside the view
    cfg.surface_fraction = 0.0
    np.testing.assert_array_equal(_whole_surfaces(cells, surfaces, cfg)[0], cells)


def test_a_dark_mover_touching_the_scene_without_a_depth_step_is_completed_by_its_grey_step():
    from osslam.config import MotionConfig
    from osslam.frontend.motion import _surfaces, _whole_surfaces

    z = np.full((60, 80), 2.0)  # a person's legs meeting the desk: no step in depth
    has_depth = np.ones_like(z, bool)
    grey = np.full(z.shape, 200.0, np.float32)
    grey[20:40, 10:30] = 30.0  # dark trousers, untextured: only their edge shows motion
    cells = np.zeros_like(z, bool)
    cells[20:40, 10:18] = True
    cfg = MotionConfig(surface_grey_step=40.0)
    by_depth = _surfaces(z, has_depth, cfg.surface_step)
    np.testing.assert_array_equal(_whole_surfaces(cells, by_depth, cfg)[0], cells)  # one surface, too large
    by_grey = _surfaces(z, has_depth, cfg.surface_step, grey, cfg.surface_grey_step)
    out = _whole_surfaces(cells, by_grey, cfg)[0]
    assert out[21:39, 11:29].all() and not out[:, 31:].any() and not out[42:].any()
    grey[20:40, 10:30] = 200.0 - 0.9 * cfg.surface_grey_step  # a step below the threshold splits nothing
    np.testing.assert_array_equal(_surfaces(z, has_depth, cfg.surface_step, grey, cfg.surface_grey_step)[1],
                                  by_depth[1])


def test_a_surface_cut_off_by_the_image_border_is_left_to_the_map_with_less_of_it_moving():
    from osslam.config import MotionConfig
    from osslam.frontend.motion import _surfaces, _whole_surfaces

    z = np.full((60, 80), 3.0)
    z[20:40, 0:20] = 1.0  # a box leaving the view at its left border
    z[20:40, 50:70] = 1.0  # the same box inside the view
    has_depth = np.ones_like(z, bool)
    cells = np.zeros_like(z, bool)
    cells[20:40, 17:20] = True  # 15 % of each moved: their trailing edges
    cells[20:40, 67:70] = True
    cfg = MotionConfig()
    assert cfg.map_edge_fraction < 0.15 < cfg.surface_fraction
    surfaces = _surfaces(z, has_depth, cfg.surface_step)
    out, cut_off = _whole_surfaces(cells, surfaces, cfg)
    np.testing.assert_array_equal(out, cells)  # neither is completed for tracking
    assert cut_off[20:40, 0:20].all()  # the cut-off one is, for the map
    assert not cut_off[20:40, 50:70].any() and not cut_off[45:].any()
    cfg.surface_fraction = 0.0  # the gate's own rule off, the map's stays
    assert _whole_surfaces(cells, surfaces, cfg)[1][20:40, 0:20].all()
    cfg.map_edge_max_area = 0.0
    assert not _whole_surfaces(cells, surfaces, cfg)[1].any()
    cfg.map_surface_fraction = 0.1  # for the map, any surface this much moving, wherever it lies
    out, cut_off = _whole_surfaces(cells, surfaces, cfg)
    np.testing.assert_array_equal(out, cells)
    assert cut_off[20:40, 0:20].all() and cut_off[20:40, 50:70].all() and not cut_off[45:].any()


def test_the_map_mask_adds_the_surfaces_left_to_the_map_grown_to_the_tracking_mask():
    from osslam.frontend.fusion import FusedMask
    from osslam.frontend.gating import GateResult
    from osslam.frontend.motion import MotionSegmentation

    h, w, s = 48, 64, 4
    mask = np.zeros((h, w), bool)
    mask[20:30, 40:50] = True  # what tracking ignores
    cut_off = np.zeros((h // s, w // s), bool)
    cut_off[4:8, 0:2] = True  # a surface at the left border, pixels 16-31 x 0-7
    seg = MotionSegmentation(True, np.eye(4), (h, w), np.zeros(cut_off.shape, np.float32), np.zeros_like(cut_off),
                             map_only_cells=cut_off)
    result = GateResult(mask, seg, FusedMask(mask, []), dilation=2)
    assert (result.map_mask & mask).sum() == mask.sum()
    assert result.map_mask[16:32, 0:8].all() and result.map_mask[16:32, 8:10].all()  # grown by 2 pixels
    assert not result.map_mask[:, 11:40].any() and not result.map_mask[:13].any()
    assert result.mask is mask  # tracking's mask is untouched
    no_cut = GateResult(mask, MotionSegmentation(True, np.eye(4), (h, w), np.zeros(cut_off.shape, np.float32),
                                                 np.zeros_like(cut_off)), FusedMask(mask, []), dilation=2)
    np.testing.assert_array_equal(no_cut.map_mask, mask)


def test_the_system_gives_the_map_the_map_mask_and_tracking_the_gate_mask(monkeypatch):
    from osslam.frontend import gating
    from osslam.mapping.mapper import DenseMapper
    from osslam.system import System

    seq = SyntheticSequence(SyntheticConfig(n_frames=6, seed=3))
    finish = gating.DynamicGate.finish

    def with_map_only(self, *args):  # every frame: a surface left to the map in the top-left corner
        result = finish(self, *args)
        if result.segmentation is not None:
            cells = np.zeros_like(result.segmentation.moving_cells)
            cells[:3, :3] = True
            result.segmentation.map_only_cells = cells
        return result

    given = []
    add_view = DenseMapper.add_view
    monkeypatch.setattr(gating.DynamicGate, "finish", with_map_only)
    monkeypatch.setattr(DenseMapper, "add_view",
                        lambda self, *a: given.append(a[-1].copy()) or add_view(self, *a))
    # the gate on a thread of this process, where the patched finish runs
    cfg = load_config("synthetic", ["gating.enabled=true", "gating.worker=thread", "detection.enabled=false",
                                    "mapping.enabled=true", "mapping.view_interval=0"])
    with System(cfg, seq.intrinsics) as slam:
        results = [slam.track(f.rgb, f.depth, f.timestamp) for f in seq]
    corner = (slice(0, 8), slice(0, 8))
    assert given and all(m[corner].all() for m in given)  # the map left the corner out ...
    assert not any(r.mask[corner].any() for r in results[1:] if r.mask is not None)  # ... tracking did not


def test_a_point_in_space_an_earlier_frame_saw_empty_has_moved_in():
    from osslam.frontend.motion import DepthReference

    cfg = Config()
    # the pasted box keeps its pixels while the camera moves, so it has a little flow of its own;
    # a residual floor above that leaves the free space as the only way to see it moved
    cfg.motion.min_residual = 3.0
    seq = SyntheticSequence(SyntheticConfig(n_frames=40, seed=2))
    ref, cur, prev = seq[20], seq[30], seq[29]
    reference = DepthReference(depth_grid(ref.depth, cfg.motion.stride), np.linalg.inv(ref.gt_pose) @ prev.gt_pose)
    flow = make_flow_estimator(cfg.flow)
    quiet = segment_motion(flow.compute(_gray(cur), _gray(prev)), cur.depth, seq.intrinsics, cfg.motion,
                           np.linalg.inv(prev.gt_pose) @ cur.gt_pose, reference=reference)
    assert quiet.moving_mask.mean() < 0.005
    # a box that arrived slowly: no flow of its own between the last two frames, but it stands
    # where the reference frame saw the scene farther away
    g, pg, d, truth = _paste_mover(cur, prev, (0, 0), depth=float(np.nanmin(cur.depth[cur.depth > 0])) * 0.7)
    seg = segment_motion(flow.compute(g, pg), d, seq.intrinsics, cfg.motion, np.linalg.inv(prev.gt_pose) @ cur.gt_pose)
    assert (seg.moving_mask & truth).sum() / truth.sum() < 0.1
    seg = segment_motion(flow.compute(g, pg), d, seq.intrinsics, cfg.motion, np.linalg.inv(prev.gt_pose) @ cur.gt_pose,
                         reference=reference)
    assert (seg.moving_mask & truth).sum() / truth.sum() > 0.8
    assert (seg.moving_mask & ~truth).mean() < 0.005


def _mover_with_true_ego(cfg):
    """A synthetic frame pair with a pasted mover: the sequence, flow, depth, mover mask and true ego-motion."""
    seq = SyntheticSequence(SyntheticConfig(n_frames=12, seed=4))
    g, pg, d, truth = _paste_mover(seq[10], seq[9], (14, 4))
    field = make_flow_estimator(cfg.flow).compute(g, pg)
    return seq, field, d, truth, np.linalg.inv(seq[9].gt_pose) @ seq[10].gt_pose


def test_a_tracked_ego_motion_the_flow_contradicts_is_refitted():
    from dataclasses import replace

    cfg = Config()
    seq, field, d, truth, ego = _mover_with_true_ego(cfg)
    jumped = ego.copy()
    jumped[:3, 3] += (0.12, -0.05, 0.0)  # a re-anchored pose: the correction is no motion of the camera
    static = ~truth & field.valid
    off = segment_motion(field, d, seq.intrinsics, replace(cfg.motion, ego_check=1.0), jumped)
    assert off.moving_mask[static].mean() > 0.5  # taken as given, it sets the static scene moving
    seg = segment_motion(field, d, seq.intrinsics, cfg.motion, jumped)
    assert seg.moving_mask[static].mean() < 0.02
    assert (seg.mask & truth).sum() / truth.sum() > 0.7
    assert np.linalg.norm(seg.ego_motion[:3, 3] - ego[:3, 3]) < 0.01
    right = segment_motion(field, d, seq.intrinsics, replace(cfg.motion, ego_refine=0.0), ego)
    assert right.ego_motion is ego  # unrefined, a tracked motion the flow agrees with is kept as it is


def test_a_tracked_ego_motion_7_mm_off_is_refined_on_the_flow():
    from dataclasses import replace

    cfg = Config()
    seq, field, d, truth, ego = _mover_with_true_ego(cfg)
    off = ego.copy()
    off[0, 3] += 0.007  # tracking's frame-to-frame error, too small for the re-fit (8 mm is not)
    static = ~truth & field.valid
    given = segment_motion(field, d, seq.intrinsics, replace(cfg.motion, ego_refine=0.0), off)
    assert given.moving_mask[static].mean() > 0.05
    seg = segment_motion(field, d, seq.intrinsics, cfg.motion, off)  # refined by default
    assert seg.moving_mask[static].mean() < 0.02
    assert np.linalg.norm(seg.ego_motion[:3, 3] - ego[:3, 3]) < 0.002
    assert (seg.mask & truth).sum() / truth.sum() > 0.9


def test_a_segmentations_background_is_what_its_ego_motion_explains_and_checks_another():
    cfg = Config()
    seq, field, d, truth, ego = _mover_with_true_ego(cfg)
    grid = motion_grid(field, d, seq.intrinsics, cfg.motion)
    seg = segment_motion(field, d, seq.intrinsics, cfg.motion, ego, grid=grid)
    u, v = grid.raw[seg.background].astype(int).T
    assert len(seg.background) > 300 and truth[v, u].mean() < 0.02  # the static scene, not the mover
    assert unexplained_share(seg, grid, ego, seq.intrinsics, cfg.motion) < 0.05
    off = ego.copy()
    off[0, 3] += 0.03
    assert unexplained_share(seg, grid, off, seq.intrinsics, cfg.motion) > 0.5
    fitted = segment_motion(field, d, seq.intrinsics, cfg.motion, grid=grid)  # no ego-motion given: fitted, checked
    u, v = grid.raw[fitted.background].astype(int).T
    assert len(fitted.background) > 300 and truth[v, u].mean() < 0.02
    assert unexplained_share(fitted, grid, ego, seq.intrinsics, cfg.motion) < 0.05


def test_a_predicted_ego_motion_is_turned_back_onto_the_flow():
    cfg = Config()
    seq, field, d, truth, ego = _mover_with_true_ego(cfg)
    turn = np.eye(4)
    turn[:3, :3] = cv2.Rodrigues(np.array([0.01, -0.015, 0.0]))[0]  # the hand turned the camera 1 degree more

    def angle(T):
        return np.linalg.norm(cv2.Rodrigues(T[:3, :3] @ ego[:3, :3].T)[0])

    for suspect in (truth, None):
        grid = motion_grid(field, d, seq.intrinsics, cfg.motion, suspect)
        u, v = grid.raw[grid.sample].astype(int).T
        assert len(grid.sample) > 300 and (suspect is None or not suspect[v, u].any())
        back = turned_to_the_flow(turn @ ego, grid, seq.intrinsics)
        assert angle(turn @ ego) > 0.017 and angle(back) < 0.002
        np.testing.assert_allclose(back[:3, 3], ego[:3, 3], atol=0.005)


def test_an_objects_motion_is_fitted_on_first_use_only(monkeypatch):
    from osslam.frontend import motion

    cfg = Config()
    seq = SyntheticSequence(SyntheticConfig(n_frames=12, seed=4))
    g, pg, d, truth = _paste_mover(seq[10], seq[9], (14, 4))
    calls = []
    fit = motion._fit_rigid
    monkeypatch.setattr(motion, "_fit_rigid", lambda *a, **k: calls.append(len(a[0])) or fit(*a, **k))
    ego = np.linalg.inv(seq[9].gt_pose) @ seq[10].gt_pose
    seg = segment_motion(make_flow_estimator(cfg.flow).compute(g, pg), d, seq.intrinsics, cfg.motion, ego)
    assert seg.objects and not calls  # the camera's motion was given: nothing fitted yet
    biggest = max(seg.objects, key=lambda o: o.area)
    first = biggest.motion
    assert first is not None and len(calls) == 1
    assert biggest.motion is first and len(calls) == 1
    # the box moved 14 px right more than the camera explains: its centre goes back left
    from osslam.geometry import transform_points

    X = seq.intrinsics.backproject(np.array([[319.0, 274.0]]), np.array([0.9]))
    du, dv = (seq.intrinsics.project(transform_points(first, X)) - seq.intrinsics.project(transform_points(ego, X)))[0]
    assert du < -5 and abs(dv) < abs(du)
    assert motion.MovingObject(truth, (0.0, 0.0), None, 1.0, int(truth.sum())).motion is None


def test_undistorting_by_the_interpolated_shift_matches_opencv_inside_and_is_exact_outside():
    from osslam.frontend.motion import _undistort
    from osslam.types import CameraIntrinsics

    camera = CameraIntrinsics(517.3, 516.5, 318.6, 255.3, dist=(0.2624, -0.9531, -0.0054, 0.0026, 1.1633))  # fr1
    # more points than one cv2.remap takes (a grid of stride 1 has 307,200)
    points = np.random.default_rng(0).uniform([-20, -20], [660, 500], (70000, 2))
    exact = camera.undistort(points)
    fast = _undistort(camera, points, 480, 640)
    inside = (points >= 0).all(axis=1) & (points <= [639, 479]).all(axis=1)
    # cv2.remap looks up at 1/32 px, so a point less than that past the last pixel still counts as on it
    outside = (points < -0.1).any(axis=1) | (points > [639.1, 479.1]).any(axis=1)
    assert 0 < inside.sum() < len(points) and outside.sum() > 1000
    assert np.abs(fast[inside] - exact[inside]).max() < 0.01
    np.testing.assert_array_equal(fast[outside], exact[outside])
    assert _undistort(camera, points[:0], 480, 640).shape == (0, 2)
    pinhole = CameraIntrinsics(517.3, 516.5, 318.6, 255.3)
    np.testing.assert_array_equal(_undistort(pinhole, points, 480, 640), points)


def test_row_lengths_match_numpys_norm_exactly():
    from osslam.geometry import row_lengths

    d = np.random.default_rng(0).normal(0, 50, (1000, 2))
    np.testing.assert_array_equal(row_lengths(d), np.linalg.norm(d, axis=1))


def test_a_mover_filling_most_of_the_image_is_left_out_of_the_ego_motion_fit_where_it_was():
    from osslam.frontend.flow import FlowField
    from osslam.frontend.flow.data.rigid import rigid_flow
    from osslam.geometry import invert, se3_exp
    from osslam.types import CameraIntrinsics

    intrinsics = CameraIntrinsics(525.0, 525.0, 319.5, 239.5)
    depth = np.full((480, 640), 2.5, np.float32)
    depth[:, :400] = 1.2  # a wall-sized board in front, over the left 60 % of the image
    camera = se3_exp(np.array([0.012, -0.004, 0.002, 0.001, 0.002, 0.0]))
    board = se3_exp(np.array([-0.03, 0.01, 0.0, 0.0, -0.01, 0.004])) @ camera
    # flow from the current frame (at the origin) to the previous one, T_previous_current away
    flow, valid = rigid_flow(depth, depth, np.eye(4), invert(camera), intrinsics, occlusion_tol=1.0)
    board_flow, board_valid = rigid_flow(depth, depth, np.eye(4), invert(board), intrinsics, occlusion_tol=1.0)
    flow[:, :400], valid[:, :400] = board_flow[:, :400], board_valid[:, :400]
    field = FlowField(flow, valid)
    cfg = Config().motion

    def error(seg):
        return np.linalg.norm(seg.ego_motion[:3, 3] - camera[:3, 3])

    fooled = segment_motion(field, depth, intrinsics, cfg)
    assert error(fooled) > 0.01  # the board reaches more of the image than the scene behind it
    suspect = np.zeros(depth.shape, bool)
    suspect[:, :410] = True  # where the board was in the previous frame
    seg = segment_motion(field, depth, intrinsics, cfg, suspect=suspect)
    assert error(seg) < 1e-3
    assert seg.moving_mask[:, :390].mean() > 0.9 and seg.moving_mask[:, 420:].mean() < 0.01
    # a suspect region leaving too few points for a fit is not trusted
    everything = np.ones(depth.shape, bool)
    np.testing.assert_array_equal(segment_motion(field, depth, intrinsics, cfg, suspect=everything).ego_motion,
                                  fooled.ego_motion)


def test_a_rolling_shutter_row_motion_is_recovered_exactly_and_needs_enough_points():
    from osslam.frontend.row_motion import MIN_POINTS, RowMotion, fit_row_motion
    from osslam.geometry import pose_from_rvec, project_pinhole

    rng = np.random.default_rng(0)
    K = np.array([[517.0, 0.0, 320.0], [0.0, 516.0, 240.0], [0.0, 0.0, 1.0]])
    pixels = rng.random((400, 2)) * [640, 480]
    z = rng.uniform(0.8, 3.0, 400)
    X = np.column_stack([(pixels[:, 0] - 320) / 517 * z, (pixels[:, 1] - 240) / 516 * z, z])
    T = pose_from_rvec(np.array([0.01, -0.02, 0.005]), np.array([0.01, -0.005, 0.02]))
    truth = RowMotion(T, np.array([0.01, 0.005, 0.0, 0.003, -0.002, 0.001]), 480)
    uv = project_pinhole(truth.apply(X, pixels[:, 1]), K)
    fit = fit_row_motion(T, X, uv, pixels[:, 1], 480, K)
    assert np.allclose(fit.change, truth.change, atol=1e-6) and np.allclose(fit.T, T, atol=1e-6)
    assert np.allclose(RowMotion(T).apply(X, pixels[:, 1]), X @ T[:3, :3].T + T[:3, 3])  # no change: rigid
    near = RowMotion(pose_from_rvec(np.array([0.0102, -0.0198, 0.005]), np.array([0.0101, -0.005, 0.0202])),
                     truth.change * 0.9, 480)  # a fit to nearly the same points: fewer steps from there
    warm = fit_row_motion(near, X, uv, pixels[:, 1], 480, K)
    assert np.allclose(warm.change, truth.change, atol=1e-6) and np.allclose(warm.T, T, atol=1e-6)
    n = MIN_POINTS - 1
    assert fit_row_motion(T, X[:n], uv[:n], pixels[:n, 1], 480, K) is None


def test_an_ego_motion_changing_over_the_rows_leaves_the_static_scene_quiet_tracked_or_fitted():
    """A rolling shutter under a turn that speeds up: the rows' flow departs from any single rigid motion's."""
    from dataclasses import replace

    from osslam.frontend.flow import FlowField
    from osslam.frontend.row_motion import RowMotion

    cfg = Config()
    seq = SyntheticSequence(SyntheticConfig(n_frames=12, seed=4))
    cur, prev = seq[10], seq[9]
    ego = np.linalg.inv(prev.gt_pose) @ cur.gt_pose
    h, w = cur.depth.shape
    ys, xs = np.mgrid[0:h, 0:w]
    pixels = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)
    z = cur.depth.ravel().astype(float)
    known = np.isfinite(z) & (z > 0)
    px = seq.intrinsics.undistort(pixels[known])
    shutter = RowMotion(ego, np.array([0.0, 0.012, 0.0, 0.0, 0.0, 0.0]), h)  # 0.7 degrees more yaw, top to bottom
    flow = np.zeros((h * w, 2), np.float32)
    flow[known] = seq.intrinsics.project(shutter.apply(seq.intrinsics.backproject(px, z[known]), px[:, 1])) \
        - pixels[known]
    field = FlowField(flow.reshape(h, w, 2), known.reshape(h, w))
    static = known.reshape(h, w)
    rigid = segment_motion(field, cur.depth, seq.intrinsics, replace(cfg.motion, rolling_shutter=False), ego)
    assert rigid.moving_mask[static].mean() > 0.05
    rolling = segment_motion(field, cur.depth, seq.intrinsics, cfg.motion, ego)
    assert rolling.moving_mask[static].mean() < 0.005
    assert np.abs(rolling.ego_motion - ego).max() < 1e-4  # the middle row's motion
    # without a given ego-motion the fitted rigid one is refined the same way
    unrefined = segment_motion(field, cur.depth, seq.intrinsics, replace(cfg.motion, ego_refine=0.0))
    assert unrefined.moving_mask[static].mean() > 0.05
    fitted = segment_motion(field, cur.depth, seq.intrinsics, cfg.motion)
    assert fitted.moving_mask[static].mean() < 0.005
    assert np.abs(fitted.ego_motion - ego).max() < 1e-4
