"""Rigid motion segmentation: flow that the camera's ego-motion cannot explain, grouped into objects.

Rigidmask's idea done with depth: back-project the current frame's pixels with their depth,
fit the camera motion to the flow robustly (PnP with MAGSAC++ on 3D-2D correspondences),
predict each pixel's rigid flow of a static world, and mark pixels whose flow departs from
it by more than the noise of flow and depth explains, or that lie in front of the surface
an earlier frame saw along their line of sight (space that was empty then). Connected
regions of such pixels are the moving objects, each with its own rigid motion, fitted
when asked for.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from osslam.config import MotionConfig
from osslam.geometry import pose_from_rvec, project_pinhole, row_lengths, transform_points
from osslam.imaging import grid_cells, grid_index, large_regions, nearest_depth, on_grid, rank_in_cells
from osslam.types import CameraIntrinsics, kinect_depth_sigma

from .flow import FlowField
from .row_motion import RowMotion, fit_row_motion

MIN_PNP_POINTS = 12
REMAP_ROWS = 32000  # cv2.remap takes maps of fewer than 32767 rows: points are looked up this many at a time
MIN_BACKGROUND_POINTS = 500  # grid points outside the suspect pixels that the ego-motion fit needs to leave them out
SUPPORT_GRID = (8, 6)  # columns, rows of the grid on which a rigid body's spread is counted
OBJECT_ITERATIONS = 50  # RANSAC iterations for one object's motion: its cells are mostly inliers by construction
SAMPLE_POINTS_PER_CELL = 4  # background points per fine-grid cell that check and refine a tracked ego-motion


@dataclass
class MovingObject:
    """One independently moving region of the current frame.

    ``fit`` is its rigid motion or the function that fits it; :attr:`motion` runs that fit
    on first use only, as nothing on the per-frame path needs it.
    """

    mask: np.ndarray  # (H, W) bool
    centre: tuple[float, float]  # (x, y) pixel centroid in the current frame
    fit: np.ndarray | Callable[[], np.ndarray | None] | None
    probability: float  # mean moving-object probability over the region
    area: int  # pixels

    @functools.cached_property
    def motion(self) -> np.ndarray | None:
        """4x4 transform of its points from the current to the previous camera; None when it did not fit."""
        return self.fit() if callable(self.fit) else self.fit


@dataclass
class DepthReference:
    """An earlier frame's depth on the motion grid and the camera's motion to it from the frame before the current one.

    The segmentation adds the ego-motion it settles on, from the current frame to the one before.
    """

    depth: np.ndarray  # (H / stride, W / stride) metres, 0 where missing
    T_reference_previous: np.ndarray  # 4x4


@dataclass
class MotionSegmentation:
    """Ego-motion, per-pixel moving probability and the moving objects of one frame pair."""

    ok: bool
    ego_motion: np.ndarray  # 4x4 T_previous_current of the camera
    shape: tuple[int, int]  # (H, W) of the frame
    probability_cells: np.ndarray  # (H / stride, W / stride) float32 in [0, 1]
    moving_cells: np.ndarray  # (H / stride, W / stride) bool: regions whose own flow departs from the rigid flow
    objects: list[MovingObject] = field(default_factory=list)
    n_points: int = 0
    n_inliers: int = 0
    map_only_cells: np.ndarray | None = None  # grid: surfaces the dense map leaves out besides the objects
    background: np.ndarray | None = None  # grid points of the check sample (MotionGrid.sample) that the result explains

    @functools.cached_property
    def probability(self) -> np.ndarray:
        """Per-pixel moving probability (H, W), float32 in [0, 1], interpolated from the grid's."""
        return cv2.resize(self.probability_cells, (self.shape[1], self.shape[0]), interpolation=cv2.INTER_LINEAR)

    @property
    def map_only_mask(self) -> np.ndarray:
        """Pixels of partly moving surfaces that only the dense map leaves out (see ``motion.map_*``)."""
        if self.map_only_cells is None:
            return np.zeros(self.shape, bool)
        return _to_pixels(self.map_only_cells, self.shape)

    @functools.cached_property
    def moving_mask(self) -> np.ndarray:
        """Pixels whose own flow shows motion in this frame (no memory, detection or dilation); made once."""
        return _to_pixels(self.moving_cells, self.shape)

    @property
    def mask(self) -> np.ndarray:
        """Union of the objects' masks."""
        out = np.zeros(self.shape, bool)
        for obj in self.objects:
            out |= obj.mask
        return out


def _fit_rigid(X: np.ndarray, uv: np.ndarray, K: np.ndarray, cfg: MotionConfig, flags: int = cv2.USAC_MAGSAC,
               iterations: int | None = None):
    """T mapping 3D points ``X`` onto pixels ``uv``: PnP with MAGSAC++ scoring, then LM refinement.

    MAGSAC++ scores hypotheses by likelihood rather than inlier count, so a mover covering
    a tenth of the image cannot win over the static background when the camera barely
    moves. USAC runs from its own fixed random state, so results repeat. ``flags`` and
    ``iterations`` choose another robust fit (OpenCV's RANSAC draws from its seeded
    generator) and override ``cfg.ransac_iterations``.
    """
    if len(X) < MIN_PNP_POINTS:
        return None, np.zeros(len(X), bool)
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        X.astype(np.float64), uv.astype(np.float64), K, None, iterationsCount=iterations or cfg.ransac_iterations,
        reprojectionError=cfg.ransac_threshold, confidence=0.99, flags=flags)
    if not ok or inl is None or len(inl) < MIN_PNP_POINTS:
        return None, np.zeros(len(X), bool)
    inliers = np.zeros(len(X), bool)
    inliers[inl.ravel()] = True
    rvec, tvec = cv2.solvePnPRefineLM(X[inliers].astype(np.float64), uv[inliers].astype(np.float64), K, None,
                                      rvec, tvec)
    return pose_from_rvec(rvec, tvec), inliers


def _to_pixels(cells: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A mask over grid cells brought to the full image ``shape`` (H, W)."""
    return cv2.resize(cells.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST).astype(bool)


def _balanced(pixels: np.ndarray, candidates: np.ndarray, size: tuple[int, int], per_cell: int) -> np.ndarray:
    """At most ``per_cell`` of the candidate points in each cell of a fine grid, so that area counts, not texture."""
    cell = grid_cells(pixels[candidates], size, (2 * SUPPORT_GRID[0], 2 * SUPPORT_GRID[1]))
    return candidates[rank_in_cells(cell) < per_cell]


def _background_candidates(usable: np.ndarray, suspect: np.ndarray | None, stride: int) -> np.ndarray:
    """The usable grid points outside the ``suspect`` pixels, or all of them where too few remain.

    Too few: under ``MIN_BACKGROUND_POINTS``, when a mover fills much of the image.
    """
    if suspect is not None:
        outside = usable & ~on_grid(suspect, stride).ravel()
        if np.count_nonzero(outside) >= MIN_BACKGROUND_POINTS:
            return outside
    return usable


def _fit_background(X: np.ndarray, uv: np.ndarray, usable: np.ndarray, pixels: np.ndarray, size: tuple[int, int],
                    K: np.ndarray, cfg: MotionConfig, guess: np.ndarray | None = None) -> tuple[np.ndarray | None, int]:
    """The camera's motion when tracking does not know it: the rigid body that is the background.

    Points are thinned to the same number per image cell, so that a densely textured
    mover cannot outvote a larger background. Up to ``cfg.max_bodies`` rigid motions are
    then fitted in turn, each to the points the previous ones leave unexplained; the
    background is told apart by its spread: it surrounds the movers, so its inliers reach
    the most cells of a coarse grid over the image. A ``guess`` (T_previous_current from
    an untrusted source) competes on the same terms. Fitting stops once the points left
    reach no more cells than the best body does: no body among them could beat it.
    """
    cell = grid_cells(pixels, size, SUPPORT_GRID)
    remaining = _balanced(pixels, np.flatnonzero(usable), size, cfg.points_per_cell)
    best, best_support, best_inliers = None, -1, 0
    if guess is not None:
        explained = row_lengths(project_pinhole(transform_points(guess, X[remaining]), K) - uv[remaining]) \
            < cfg.ransac_threshold
        best, best_support, best_inliers = guess, len(np.unique(cell[remaining[explained]])), int(explained.sum())
    for _ in range(max(1, cfg.max_bodies)):
        if len(np.unique(cell[remaining])) <= best_support:
            break
        T, inliers = _fit_rigid(X[remaining], uv[remaining], K, cfg)
        if T is None:
            break
        support = len(np.unique(cell[remaining[inliers]]))
        if support > best_support:
            best, best_support, best_inliers = T, support, int(inliers.sum())
        remaining = remaining[~inliers]
    return best, best_inliers


@functools.lru_cache(maxsize=4)
def _grid(intrinsics: CameraIntrinsics, h: int, w: int, s: int) -> tuple[np.ndarray, ...]:
    """Every ``s``-th pixel of an (h, w) image from ``s // 2``, as pixels (N, 2) and undistorted pixels.

    The same for every frame of a camera, so computed once (read-only arrays).
    """
    ys, xs = np.mgrid[s // 2 : h : s, s // 2 : w : s]
    raw = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    out = (raw, intrinsics.undistort(raw))
    for a in out:
        a.flags.writeable = False
    return out


@functools.lru_cache(maxsize=4)
def _undistortion_shifts(intrinsics: CameraIntrinsics, h: int, w: int) -> np.ndarray:
    """How far undistortion moves each pixel of an (h, w) image, (h, w, 2) float32 (read-only).

    The shift changes slowly over the image, so interpolating it undistorts points between
    pixels to far below a hundredth of a pixel.
    """
    ys, xs = np.mgrid[0:h, 0:w]
    raw = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    shifts = (intrinsics.undistort(raw) - raw).reshape(h, w, 2).astype(np.float32)
    shifts.flags.writeable = False
    return shifts


def _undistort(intrinsics: CameraIntrinsics, points: np.ndarray, h: int, w: int) -> np.ndarray:
    """Undistorted positions of points (N, 2) of an (h, w) image: the shift interpolated inside it, exact outside."""
    if not intrinsics.has_distortion or not len(points):
        return points.copy()
    shifts, at = _undistortion_shifts(intrinsics, h, w), points.astype(np.float32).reshape(-1, 1, 2)
    shift = np.concatenate([cv2.remap(shifts, at[i : i + REMAP_ROWS], None, cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
                            for i in range(0, len(at), REMAP_ROWS)]).reshape(-1, 2)
    out = points + shift
    outside = np.isnan(shift[:, 0])
    if outside.any():
        out[outside] = intrinsics.undistort(points[outside])
    return out


@dataclass
class MotionGrid:
    """The motion grid's points of one frame pair, before any ego-motion: what :func:`segment_motion` starts from."""

    shape: tuple[int, int]  # (H, W) of the frame
    stride: int
    raw: np.ndarray  # (N, 2) grid pixels
    px: np.ndarray  # (N, 2) the same, undistorted
    z: np.ndarray  # (N,) depth, metres
    has_depth: np.ndarray  # (N,) bool: depth within the configured range
    usable: np.ndarray  # (N,) bool: depth and reliable flow
    target: np.ndarray  # (N, 2) undistorted pixels of the previous frame the flow takes the points to (usable ones)
    X: np.ndarray  # (N, 3) points of the current camera
    surfaces: tuple[int, np.ndarray]  # :func:`_surfaces` of the grid's depth
    background: np.ndarray  # (N,) bool: usable points outside the suspect pixels (:func:`_background_candidates`)
    sample: np.ndarray  # indices of at most SAMPLE_POINTS_PER_CELL of those per fine-grid cell


def motion_grid(flow: FlowField, depth: np.ndarray, intrinsics: CameraIntrinsics, cfg: MotionConfig,
                suspect: np.ndarray | None = None, gray: np.ndarray | None = None) -> MotionGrid:
    """The grid of every ``cfg.stride``-th pixel with its depth, flow target and 3D point.

    Its background points, those an ego-motion is fitted to, leave out the ``suspect`` pixels
    (where movers may be); its sample, drawn from them, checks and refines a given ego-motion.
    Its surfaces are split at steps in depth and, with the frame's ``gray`` image, at steps of
    ``cfg.surface_grey_step`` grey levels. Needs no ego-motion, so the gate computes it on its
    worker thread while tracking runs.
    """
    h, w = depth.shape
    s = max(1, cfg.stride)
    raw, px = _grid(intrinsics, h, w, s)
    grid_depth = on_grid(depth, s)
    gh, gw = grid_depth.shape
    z = grid_depth.astype(np.float64).ravel()
    f = on_grid(flow.flow, s).reshape(-1, 2).astype(np.float64)
    has_depth = np.isfinite(z) & (z > cfg.min_depth) & (z < cfg.max_depth)
    usable = has_depth & on_grid(flow.valid, s).ravel()
    target = raw + f  # where the flow takes each point; only usable points count, so only they are undistorted
    if usable.any():
        target[usable] = _undistort(intrinsics, target[usable], h, w)
    X = intrinsics.backproject(px, z)
    background = _background_candidates(usable, suspect, s)
    sample = _balanced(raw, np.flatnonzero(background), (w, h), SAMPLE_POINTS_PER_CELL)
    return MotionGrid((h, w), s, raw, px, z, has_depth, usable, target, X,
                      _surfaces(z.reshape(gh, gw), has_depth.reshape(gh, gw), cfg.surface_step,
                                _grey_grid(gray, s) if gray is not None and cfg.surface_grey_step > 0 else None,
                                cfg.surface_grey_step),
                      background, sample)


def segment_motion(flow: FlowField, depth: np.ndarray, intrinsics: CameraIntrinsics, cfg: MotionConfig,
                   ego_motion: np.ndarray | None = None, remembered: np.ndarray | None = None,
                   guess: np.ndarray | None = None, reference: DepthReference | None = None,
                   suspect: np.ndarray | None = None, grid: MotionGrid | None = None) -> MotionSegmentation:
    """Segment independently moving regions of the current frame.

    ``flow`` goes from the current frame to the previous one and ``depth`` is the current
    frame's depth in metres; pixels are undistorted with ``intrinsics``. ``ego_motion``
    (T_previous_current), when known from tracking, replaces the robust fit, in which
    ``guess`` (an untrusted T_previous_current) is one candidate. Given or fitted, the
    ego-motion is then, with ``cfg.ego_refine``, refined on the flow of the background it
    explains, and with ``cfg.rolling_shutter`` let change over the image's rows (see
    :mod:`.row_motion`). A tracked ``ego_motion``
    that leaves more than ``cfg.ego_check`` of the background's usable points moving
    (counted on at most ``SAMPLE_POINTS_PER_CELL`` of them per fine-grid cell) is
    itself only that fit's candidate: a pose re-anchored after a stretch of drift carries
    the correction, which is no motion of the camera. ``remembered``
    marks grid cells that moved in recent frames (see :class:`MotionMemory`); they join the
    objects although they may be still right now. Points in front of what the ``reference``
    frame saw along their line of sight moved there since (a slow mover's motion adds up
    over the frames between). ``suspect`` marks pixels where movers may be (the previous
    frame's mask, grown): the ego-motion is fitted without them while at least
    ``MIN_BACKGROUND_POINTS`` usable grid points remain, so that a mover filling much of
    the image cannot pass for the background. Works on a grid of every ``cfg.stride``-th
    pixel (``grid``, :func:`motion_grid` of the same flow, depth and ``suspect`` when computed
    beforehand; only a grid given the frame's image splits surfaces at steps in grey level);
    masks come back at full resolution.
    """
    if grid is None:
        grid = motion_grid(flow, depth, intrinsics, cfg, suspect)
    (h, w), s = grid.shape, grid.stride
    raw, px, z, X, target = grid.raw, grid.px, grid.z, grid.X, grid.target
    has_depth, usable = grid.has_depth, grid.usable
    gh, gw = grid.surfaces[1].shape
    n_usable = np.count_nonzero(usable)
    K = intrinsics.K
    empty = MotionSegmentation(False, np.eye(4), (h, w), np.zeros((gh, gw), np.float32), np.zeros((gh, gw), bool),
                               n_points=n_usable)
    fit = grid.background
    row_motion = None  # the ego-motion changing over the rows, when fitted
    sample = grid.sample  # the points that check and refine the ego-motion
    T, n_inliers, sample_ratio = ego_motion, n_usable, None
    if T is not None:
        sample_ratio = _residual_ratio(RowMotion(T), X[sample], z[sample], target[sample], px[sample], K, cfg)
        if len(sample) and np.mean(sample_ratio > 1.0) > cfg.ego_check:
            T = None
    if T is None:
        T, n_inliers = _fit_background(X, target, fit, raw, (w, h), K, cfg, guess if ego_motion is None else ego_motion)
        if T is None:
            return empty
        sample_ratio = None
    if cfg.ego_refine > 0:
        for k in range(max(1, cfg.ego_refine_passes)):
            if k or sample_ratio is None:  # against the motion as the last pass left it
                sample_ratio = _residual_ratio(row_motion or RowMotion(T), X[sample], z[sample], target[sample],
                                               px[sample], K, cfg)
            background = sample[sample_ratio < cfg.ego_refine]
            if cfg.rolling_shutter:
                row_motion = fit_row_motion(row_motion or T, X[background], target[background], px[background, 1],
                                            h, K)
            T = _refine(T, X, target, background, K) if row_motion is None else row_motion.T
    ratio = np.zeros(len(X))
    idx = np.flatnonzero(usable)
    ratio[idx] = _residual_ratio(row_motion or RowMotion(T), X[idx], z[idx], target[idx], px[idx], K, cfg)

    prob_grid = (1.0 / (1.0 + np.exp(-4.0 * (ratio - 1.0)))).reshape(gh, gw)
    prob_grid[~usable.reshape(gh, gw)] = 0.0
    moving = ratio > 1.0
    if reference is not None:
        moving |= _in_free_space(X, has_depth, reference.depth, reference.T_reference_previous @ T, intrinsics, s,
                                 cfg.free_space_margin)
    moving = moving.reshape(gh, gw).astype(np.uint8)
    moving = large_regions(cv2.morphologyEx(moving, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)),
                           max(1, cfg.min_area // (s * s)))
    cells = moving if remembered is None else moving | remembered
    cells, map_only = _whole_surfaces(cells, grid.surfaces, cfg)
    objects = _objects(cells, X, target, usable, prob_grid, K, cfg, (h, w))
    background = sample[ratio[sample] <= 1.0]
    return MotionSegmentation(True, T, (h, w), prob_grid.astype(np.float32), moving, objects, n_usable, n_inliers,
                              map_only & ~cells, background)


def turned_to_the_flow(ego_motion: np.ndarray, grid: MotionGrid, intrinsics: CameraIntrinsics) -> np.ndarray:
    """A predicted ego-motion turned so that the background's median flow residual against it vanishes.

    A hand-held camera's motion changes from frame to frame mostly by turning, which shifts the
    whole image; the median over the grid's sample (:func:`motion_grid`) measures that shift.
    """
    sample = grid.sample
    if len(sample) < MIN_PNP_POINTS:
        return ego_motion
    K = intrinsics.K
    dx, dy = np.median(grid.target[sample] - project_pinhole(transform_points(ego_motion, grid.X[sample]), K), axis=0)
    turn = np.eye(4)
    turn[:3, :3] = cv2.Rodrigues(np.array([-dy / K[1, 1], dx / K[0, 0], 0.0]))[0]
    return turn @ ego_motion


def unexplained_share(segmentation: MotionSegmentation, grid: MotionGrid, ego_motion: np.ndarray,
                      intrinsics: CameraIntrinsics, cfg: MotionConfig) -> float:
    """The share of a segmentation's background (:attr:`MotionSegmentation.background`) that ``ego_motion`` moves.

    ``grid`` is the one the segmentation was made on; 1 when it has no background to check.
    """
    idx = segmentation.background
    if idx is None or not len(idx):
        return 1.0
    ratio = _residual_ratio(RowMotion(ego_motion), grid.X[idx], grid.z[idx], grid.target[idx], grid.px[idx],
                            intrinsics.K, cfg)
    return float(np.mean(ratio > 1.0))


def _refine(T: np.ndarray, X: np.ndarray, uv: np.ndarray, sel: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Tracked camera motion ``T`` refined on the flow of the points ``sel``, kept when it explains them better.

    A least-squares fit starts from ``T``; its result replaces ``T`` only when the median
    reprojection error of those points drops.
    """
    if len(sel) < MIN_BACKGROUND_POINTS // 4:
        return T
    X, uv = X[sel], uv[sel]
    rvec, tvec = cv2.solvePnPRefineLM(X, uv, K, None, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3].reshape(3, 1).copy())
    out = pose_from_rvec(rvec, tvec)
    before, after = (np.median(row_lengths(project_pinhole(transform_points(P, X), K) - uv)) for P in (T, out))
    return out if after < before else T


def _residual_ratio(ego: RowMotion, X: np.ndarray, z: np.ndarray, target: np.ndarray, px: np.ndarray, K: np.ndarray,
                    cfg: MotionConfig) -> np.ndarray:
    """Each point's flow residual against the rigid flow of camera motion ``ego``, over its noise threshold.

    Above 1 the point moved on its own. The threshold grows with the flow's length
    (``cfg.flow_relative``) and with the image shift that depth noise alone would cause
    (``cfg.depth_sigma_factor``). ``px`` are the points' undistorted pixels, whose rows
    choose the motion of a rolling shutter.
    """
    moved, moved_far = ego.apply_along_rays(X, px[:, 1], (z + kinect_depth_sigma(z)) / np.maximum(z, 1e-6))
    rigid = project_pinhole(moved, K)
    residual = row_lengths(target - rigid)
    depth_effect = row_lengths(project_pinhole(moved_far, K) - rigid)
    threshold = cfg.min_residual + cfg.flow_relative * row_lengths(rigid - px) + cfg.depth_sigma_factor * depth_effect
    return residual / threshold


def _in_free_space(X: np.ndarray, has_depth: np.ndarray, reference_depth: np.ndarray, T_reference_current: np.ndarray,
                   intrinsics: CameraIntrinsics, stride: int, margin: float) -> np.ndarray:
    """Grid points lying in front of the surface a reference frame saw along their line of sight.

    That space was empty then, so what is there now moved in. The reference surface is the
    nearest within one grid cell, so that depth edges of the static scene do not count.
    """
    Xr = transform_points(T_reference_current, X)
    ahead = np.flatnonzero(has_depth & (Xr[:, 2] > 0.05))
    out = np.zeros(len(X), bool)
    if not len(ahead):
        return out
    row, col, inside = grid_index(intrinsics.project(Xr[ahead]), stride, reference_depth.shape)
    surface = nearest_depth(reference_depth)
    seen = np.full(len(ahead), np.inf)
    seen[inside] = surface[row[inside], col[inside]]
    finite = np.isfinite(seen)
    z = Xr[ahead, 2]
    out[ahead[finite]] = z[finite] < seen[finite] - margin - 3 * kinect_depth_sigma(seen[finite])
    return out


def _surfaces(z: np.ndarray, has_depth: np.ndarray, step: float, grey: np.ndarray | None = None,
              grey_step: float = 0.0) -> tuple[int, np.ndarray]:
    """Connected surfaces of the grid: labels of regions without a relative depth step above ``step``.

    With the grid's ``grey`` levels, regions also end where neighbouring points' grey levels
    differ by more than ``grey_step``.
    """
    smooth = has_depth.copy()
    dx = np.abs(np.diff(z, axis=1)) > step * np.minimum(z[:, 1:], z[:, :-1])
    dy = np.abs(np.diff(z, axis=0)) > step * np.minimum(z[1:], z[:-1])
    if grey is not None:
        dx |= np.abs(np.diff(grey, axis=1)) > grey_step
        dy |= np.abs(np.diff(grey, axis=0)) > grey_step
    smooth[:, 1:] &= ~dx
    smooth[:, :-1] &= ~dx
    smooth[1:] &= ~dy
    smooth[:-1] &= ~dy
    return cv2.connectedComponents(smooth.astype(np.uint8), connectivity=4)


def _grey_grid(gray: np.ndarray, stride: int) -> np.ndarray:
    """The grid points' grey levels, smoothed over 5 x 5 pixels (float32)."""
    return on_grid(cv2.GaussianBlur(gray, (5, 5), 0), stride).astype(np.float32)


def _whole_surfaces(cells: np.ndarray, surfaces: tuple[int, np.ndarray],
                    cfg: MotionConfig) -> tuple[np.ndarray, np.ndarray]:
    """Moving cells completed to the surfaces (:func:`_surfaces`) they mostly cover, and the surfaces left to the map.

    A mover is a surface separated from the scene behind it by a step in depth, or, with
    ``cfg.surface_grey_step``, in grey level where it touches the scene without one (a box on
    a desk, a person's feet on the floor); where its own flow shows motion on part of it (its
    leading edge, or while it turns), the rest is the same object. Surfaces larger than
    ``cfg.surface_max_area`` of the image (the floor a person stands on, a desk) are left to
    the cells' own evidence. The second mask holds
    what the dense map leaves out besides: surfaces at least ``cfg.map_surface_fraction``
    moving, and surfaces cut off by the image border (a person leaving the view shows
    little of its outline, where motion shows) at least ``cfg.map_edge_fraction`` moving
    and covering at most ``cfg.map_edge_max_area`` of the image. Tracking, which a wrong
    guess there costs more than the map, keeps to the first mask.
    """
    if not cells.any():
        return cells, np.zeros_like(cells)
    n, labels = surfaces
    area = np.bincount(labels.ravel(), minlength=n)
    hit = np.bincount(labels.ravel(), weights=cells.ravel(), minlength=n)
    small = area <= cfg.surface_max_area * cells.size
    whole = small & (hit >= cfg.surface_fraction * area) & (cfg.surface_fraction > 0)
    whole[0] = False
    on_border = np.zeros(n, bool)
    on_border[np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])] = True
    for_map = on_border & (hit >= cfg.map_edge_fraction * area) & (area <= cfg.map_edge_max_area * cells.size)
    for_map |= small & (hit >= cfg.map_surface_fraction * area) & (cfg.map_surface_fraction > 0)
    for_map[0] = False
    return cells | _with_step_cells(whole[labels], labels), _with_step_cells(for_map[labels], labels)


def _with_step_cells(grown: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Surface cells joined by the cells next to them on the depth step around, or without depth (label 0)."""
    return grown | (cv2.dilate(grown.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & (labels == 0))


def _object_motion(X: np.ndarray, target: np.ndarray, K: np.ndarray, cfg: MotionConfig) -> np.ndarray | None:
    """One object's rigid motion from its points: EPnP RANSAC (its cells are mostly inliers), then LM."""
    return _fit_rigid(X, target, K, cfg, cv2.SOLVEPNP_EPNP, OBJECT_ITERATIONS)[0]


def _objects(cells: np.ndarray, X: np.ndarray, target: np.ndarray, usable: np.ndarray, prob_grid: np.ndarray,
             K: np.ndarray, cfg: MotionConfig, shape: tuple[int, int]) -> list[MovingObject]:
    """Connected regions of moving grid cells at full resolution, each with the fit of its rigid motion."""
    s = max(1, cfg.stride)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(cells.astype(np.uint8), connectivity=8)
    objects: list[MovingObject] = []
    if n == 1:
        return objects
    min_cells = max(1, cfg.min_area // (s * s))
    pixel_labels = cv2.resize(labels, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    for k in range(1, n):
        if stats[k, cv2.CC_STAT_AREA] < min_cells:
            continue
        region = labels == k
        mask = pixel_labels == k  # as _to_pixels(region) gives it: nearest-neighbour resizing commutes with labels
        sel = np.flatnonzero(region.ravel() & usable)
        if len(sel) > cfg.object_fit_points:  # evenly thinned: a rigid motion needs few points
            sel = sel[np.linspace(0, len(sel) - 1, cfg.object_fit_points).astype(int)]
        fit = functools.partial(_object_motion, X[sel], target[sel], K, cfg)
        cx, cy = centroids[k]
        objects.append(MovingObject(mask, (float(cx * s + s // 2), float(cy * s + s // 2)), fit,
                                    float(prob_grid[region].mean()), np.count_nonzero(mask)))
    return objects
