"""Algorithm 1 on hand-made masks: each branch of the fusion, and the BFS it relies on."""

from collections import deque

import cv2
import numpy as np
import pytest

from osslam.config import FusionConfig
from osslam.frontend.fusion import Detection, fuse, nearest_marked
from osslam.frontend.motion import MovingObject
from osslam.imaging import grow, grow_in_blocks, grow_square

SHAPE = (120, 160)


def _rect(x0, y0, x1, y1):
    m = np.zeros(SHAPE, bool)
    m[y0:y1, x0:x1] = True
    return m


def _object(mask):
    ys, xs = np.nonzero(mask)
    return MovingObject(mask, (float(xs.mean()), float(ys.mean())), None, 0.9, int(mask.sum()))


def _bfs(mask, start):
    """Algorithm 1's queue-based search, literally."""
    h, w = mask.shape
    seen = np.zeros_like(mask)
    q = deque([start])
    seen[start[1], start[0]] = True
    while q:
        x, y = q.popleft()
        if mask[y, x]:
            return x, y
        for dx, dy in ((0, -1), (-1, 0), (1, 0), (0, 1)):
            nx, ny = x + dx, y + dy
            if 0 <= nx < w and 0 <= ny < h and not seen[ny, nx]:
                seen[ny, nx] = True
                q.append((nx, ny))
    return None


def test_nearest_marked_is_at_the_bfs_distance():
    rng = np.random.default_rng(0)
    for _ in range(20):
        mask = rng.random(SHAPE) < 0.002
        start = (int(rng.integers(0, 160)), int(rng.integers(0, 120)))
        got, ref = nearest_marked(mask, start), _bfs(mask, start)
        dist = lambda p: abs(p[0] - start[0]) + abs(p[1] - start[1])  # noqa: E731
        assert mask[got[1], got[0]] and dist(got) == dist(ref)
    assert nearest_marked(np.zeros(SHAPE, bool), (3, 3)) is None


def test_a_search_with_a_reach_finds_the_same_pixel_or_none_beyond_it():
    rng = np.random.default_rng(1)
    found = missed = 0
    for _ in range(200):
        mask = rng.random(SHAPE) < 0.0005
        start = (float(rng.uniform(0, 159)), float(rng.uniform(0, 119)))
        reach = float(rng.uniform(1, 40))
        whole, near = nearest_marked(mask, start), nearest_marked(mask, start, reach)
        centre = (round(start[0]), round(start[1]))
        if whole is not None and abs(whole[0] - centre[0]) + abs(whole[1] - centre[1]) <= reach:
            assert near == whole
            found += 1
        else:
            assert near is None
            missed += 1
    assert found > 20 and missed > 20


CFG = FusionConfig(inclusion_rate=0.9, max_centre_distance=40, dilation=0, detection_dilation=0)


def test_detection_inside_motion_mask_replaces_it():
    motion = _rect(20, 20, 80, 100)  # a person plus leaked background
    person = _rect(30, 25, 70, 95)
    out = fuse([_object(motion)], [Detection(person, "person", 0.9, dynamic=True)], CFG, SHAPE)
    assert out.replaced == [(0, 0)]
    assert out.inclusion_rates[(0, 0)] == 1.0
    assert np.array_equal(out.mask, person)


def test_a_replaced_motion_mask_keeps_a_mover_the_detection_does_not_explain():
    person = _rect(30, 25, 70, 95)
    box = _rect(72, 40, 110, 80)  # a box moving against the person: one connected motion region
    motion = _rect(24, 20, 76, 100) | box  # the person, leaked background, the box
    out = fuse([_object(motion)], [Detection(person, "person", 0.9, dynamic=True)], CFG, SHAPE)
    assert out.replaced == [(0, 0)]
    beyond = box & ~_rect(22, 17, 78, 103)  # the box beyond the margin of 8 px around the person
    assert out.mask[_rect(80, 48, 102, 72)].all()  # its core
    assert out.mask[beyond].mean() > 0.9  # and all but its corners, which the opening rounds
    assert not out.mask[20:100, 24:30].any()  # the leaked strip left of the person stays dropped
    assert out.mask.sum() < (person | box).sum()  # no more than person and box
    small = FusionConfig(**{**CFG.__dict__, "remainder_area": int(beyond.sum()) + 1})
    assert np.array_equal(fuse([_object(motion)], [Detection(person, "person", 0.9, True)], small, SHAPE).mask,
                          person)


def test_low_inclusion_rate_keeps_the_motion_mask():
    motion = _rect(20, 20, 60, 60)
    chair = _rect(40, 40, 100, 100)  # overlaps only a corner: R = 400 / 3600
    out = fuse([_object(motion)], [Detection(chair, "chair", 0.8, dynamic=False)], CFG, SHAPE)
    assert out.replaced == []
    assert out.inclusion_rates[(0, 0)] < 0.9
    assert np.array_equal(out.mask, motion)  # the chair is not dynamic by default: not added


def test_motion_without_detection_stays_and_dynamic_detection_without_motion_stays():
    box = _rect(100, 10, 140, 40)  # a moving box no detector knows
    person = _rect(10, 60, 40, 110)  # a person standing still
    cup = _rect(60, 70, 70, 80)  # a static cup (not dynamic)
    dets = [Detection(person, "person", 0.9, True), Detection(cup, "cup", 0.7, False)]
    out = fuse([_object(box)], dets, CFG, SHAPE)
    assert out.replaced == []
    assert np.array_equal(out.mask, box | person)


def test_far_detection_is_not_associated():
    motion = _rect(10, 10, 50, 50)
    far = _rect(120, 80, 130, 90)  # nearest marked pixel far beyond max_centre_distance
    out = fuse([_object(motion)], [Detection(far, "person", 0.9, True)], CFG, SHAPE)
    assert (0, 0) not in out.inclusion_rates and out.replaced == []
    assert np.array_equal(out.mask, motion | far)


def test_dilation_adds_a_margin():
    motion = _rect(50, 50, 60, 60)
    out = fuse([_object(motion)], [], FusionConfig(dilation=3), SHAPE)
    assert out.mask.sum() > motion.sum()
    assert out.mask[50:60, 47].all() and not out.mask[55, 45]
    assert np.array_equal(fuse([], [], FusionConfig(dilation=3), SHAPE).mask, np.zeros(SHAPE, bool))


def test_motion_and_detector_masks_grow_by_their_own_margins():
    motion = _rect(50, 50, 60, 60)
    person = _rect(100, 50, 110, 60)  # far from the motion: stays as a dynamic detection
    out = fuse([_object(motion)], [Detection(person, "person", 0.9, True)],
               FusionConfig(dilation=3, detection_dilation=1), SHAPE).mask
    assert out[50:60, 47].all() and not out[50:60, 46].any()  # motion grown by 3
    assert out[50:60, 99].all() and not out[50:60, 98].any()  # the person by 1


def test_a_detection_seen_moving_keeps_only_its_pixels_near_the_motion():
    walking = _rect(10, 10, 50, 110)  # a person's segmentation spilling onto the desk below its moving torso
    torso = _rect(12, 10, 48, 50)
    sitting = _rect(110, 10, 150, 60)  # a person without motion
    dets = [Detection(walking, "person", 0.9, True), Detection(sitting, "person", 0.8, True)]
    cfg = FusionConfig(max_centre_distance=0, dilation=0, detection_dilation=0, detection_motion_radius=12)
    out = fuse([_object(torso)], dets, cfg, SHAPE).mask
    assert out[10:50, 10:50].all() and out[50:58, 12:48].all()  # within 12 px of the motion, give or take 4 ...
    assert not out[70:110, 10:50].any()  # ... and not beyond
    assert np.array_equal(out[:, 100:], sitting[:, 100:])  # not seen moving: whole
    off = fuse([_object(torso)], dets, FusionConfig(**{**cfg.__dict__, "detection_motion_radius": 0}), SHAPE).mask
    assert np.array_equal(off, walking | sitting)
    grazed = _rect(40, 10, 50, 110)  # the motion covers under 5 % of this one: not seen moving
    barely = Detection(_rect(47, 10, 100, 110), "person", 0.9, True)
    assert np.array_equal(fuse([_object(grazed & _rect(47, 10, 50, 20))], [barely], cfg, SHAPE).mask,
                          barely.mask)


def test_a_detection_at_exactly_the_centre_distance_is_associated_and_one_pixel_beyond_is_not():
    motion = _rect(20, 20, 41, 41)  # centre (30, 30)
    for x0, associated in ((30 + int(CFG.max_centre_distance), True), (31 + int(CFG.max_centre_distance), False)):
        det = Detection(_rect(x0, 25, x0 + 10, 36), "person", 0.9, True)
        assert ((0, 0) in fuse([_object(motion)], [det], CFG, SHAPE).inclusion_rates) is associated


@pytest.mark.parametrize("radius", [1, 5, 10])
def test_growing_a_mask_equals_dilating_the_whole_image(radius):
    rng = np.random.default_rng(radius)
    for _ in range(20):
        mask = np.zeros(SHAPE, bool)
        for _ in range(int(rng.integers(0, 4))):
            x, y = int(rng.integers(-5, SHAPE[1])), int(rng.integers(-5, SHAPE[0]))
            mask[max(0, y):y + int(rng.integers(1, 30)), max(0, x):x + int(rng.integers(1, 30))] = True
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        assert np.array_equal(grow(mask, radius), cv2.dilate(mask.astype(np.uint8), disc).astype(bool))


@pytest.mark.parametrize("radius, block", [(24, 4), (12, 4), (9, 3)])
def test_growing_in_blocks_stays_within_a_block_or_two_of_growing(radius, block):
    rng = np.random.default_rng(radius)
    for _ in range(10):
        mask = np.zeros(SHAPE, bool)
        for x, y, w, h in rng.integers(0, [150, 110, 30, 30], size=(3, 4)):
            mask[y:y + h, x:x + w] = True
        mask[rng.integers(0, SHAPE[0], 5), rng.integers(0, SHAPE[1], 5)] = True
        out = grow_in_blocks(mask, radius, block)
        assert out.shape == SHAPE and not (grow(mask, radius - block) & ~out).any()
        assert not (out & ~grow(mask, radius + 2 * block)).any()


def test_growing_by_a_square_marks_exactly_the_pixels_within_the_radius_in_x_and_y():
    mask = np.zeros(SHAPE, bool)
    mask[40, 50] = mask[90, 10] = True
    out = grow_square(mask, 6)
    ys, xs = np.mgrid[: SHAPE[0], : SHAPE[1]]
    near = ((np.abs(ys - 40) <= 6) & (np.abs(xs - 50) <= 6)) | ((np.abs(ys - 90) <= 6) & (np.abs(xs - 10) <= 6))
    assert np.array_equal(out, near)
    assert np.array_equal(grow_square(mask, 0), mask)
