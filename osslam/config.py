"""Typed configuration: one dataclass section per stage, YAML presets, ``key=value`` overrides."""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml


class ConfigError(ValueError):
    """A configuration file, preset name or override that cannot be used."""


@dataclass
class DatasetConfig:
    """How sequences are read."""

    max_time_diff: float = 0.02
    depth_scale: float = 5000.0
    max_frames: int = 0
    start_frame: int = 0
    stride: int = 1


@dataclass
class CameraConfig:
    """Intrinsics override and usable depth range.

    ``model``: ``auto`` takes the intrinsics from the sequence (its ``camera.yaml``, else
    the TUM sensor its folder name names), ``freiburg1/2/3`` TUM's calibration, and
    ``custom`` the fx, fy, cx, cy, dist, width and height below.
    """

    model: str = "auto"
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    dist: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0])
    width: int = 640
    height: int = 480
    min_depth: float = 0.1
    max_depth: float = 4.0


@dataclass
class FeaturesConfig:
    """ORB extraction spread over an image grid."""

    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 7
    candidates: int = 10  # keypoints ORB keeps before the grid picks, in multiples of n_features
    grid_rows: int = 8
    grid_cols: int = 10
    edge_margin: int = 16


@dataclass
class TrackingConfig:
    """Local-map tracking, pose refinement and relocalisation."""

    search_radius: float = 15.0
    refine_radius: float = 4.0
    max_descriptor_distance: int = 64
    ratio: float = 0.8
    min_matches: int = 20
    min_inliers: int = 15
    pnp_reprojection_error: float = 3.0
    pnp_iterations: int = 200
    virtual_baseline: float = 0.08
    local_keyframes: int = 40  # the local map: landmarks of the keyframes most covisible with the reference
    pose_iterations: int = 10
    consensus: bool = True  # a robust rigid consensus (PnP, MAGSAC++) before the first pose refinement of a frame
    consensus_threshold: float = 2.0  # pixels
    mature_observations: int = 5  # keyframes that must have seen a landmark before it votes in the consensus
    mature_frames: int = 30  # ... and frames since it was mapped
    arbiter_mature: int = 5  # fewer mature matches than min_matches, but this many, pick among rigid fits (0: off)


@dataclass
class KeyframeConfig:
    """When a frame becomes a keyframe and how it seeds new landmarks."""

    min_tracked_ratio: float = 0.75
    min_translation: float = 0.08
    min_rotation_deg: float = 8.0
    max_interval: int = 30
    min_interval: int = 0
    max_new_landmarks: int = 400


@dataclass
class BackendConfig:
    """GTSAM iSAM2 factor graph.

    ``relinearize_skip`` counts keyframes: every that many keyframes the back-end runs
    ``extra_updates`` relinearising iSAM2 updates without new factors (whose free variable
    ordering keeps the Bayes tree small); updates that add factors never relinearise. On a
    synthetic 130-keyframe run 2-3 was fastest; 1 was about twice as slow.
    Depths outside ``[min_depth, max_depth]`` count as missing; ``min_depth`` is also the
    closest a landmark may lie in front of a camera that keeps an observation of it.
    """

    pixel_sigma: float = 1.0
    huber_k: float = 1.345
    relinearize_threshold: float = 0.01
    relinearize_skip: int = 3
    wildfire_threshold: float = 0.001
    prior_rotation_sigma: float = 1e-3
    prior_translation_sigma: float = 1e-3
    odometry_rotation_sigma: float = 0.1
    odometry_translation_sigma: float = 0.1
    min_observations: int = 2
    min_depth: float = 0.05
    max_depth: float = 10.0
    chi2_threshold: float = 7.815
    chi2_threshold_mono: float = 5.991
    max_bad_observations: int = 2
    extra_updates: int = 1
    pending_max_age: int = 10
    report_window: int = 10
    finish_iterations: int = 3


@dataclass
class GatingConfig:
    """Whether moving pixels are found and kept out of tracking and mapping.

    While the current frame's mask is computed, its features are extracted outside the
    previous frame's mask grown by ``prior_margin`` pixels in x and y (how far a mover may
    travel), and a camera motion fitted to the flow is fitted outside it too. The mask is
    computed beside tracking in a child process (``worker: process``), or on a thread of the
    tracker's own process (``thread``), where the two share Python's interpreter lock.
    """

    enabled: bool = False
    prior_margin: int = 10
    worker: str = "process"


@dataclass
class DetectionConfig:
    """Yolo-Fastest detections of potentially dynamic objects, as pixel masks."""

    enabled: bool = True
    model: str = "yolo-fastest-1.1"  # or yolo-fastest-1.1-body (person only)
    classes: list[str] = field(default_factory=lambda: ["person"])
    score: float = 0.5
    depth_layer: float = 0.4  # metres around the box's dominant depth that belong to the object
    person_segmentation: bool = True  # people masked by the selfie segmentation model when it is present
    runtime: str = "opencv"  # opencv: the network's ONNX export (cached per user) in OpenCV's DNN; or torch
    threads: int = 1  # torch runtime: CPU threads (OpenCV's DNN uses OpenCV's threads, run.threads)
    interval: int = 3  # the detector runs on every this-many-th frame; its masks follow the flow in between
    person_interval: int = 2  # people segmented on every this-many-th detection; between, their masks follow the flow
    input_size: list[int] = field(default_factory=lambda: [256, 192])  # network input [w, h], multiples of 32; []: cfg's


@dataclass
class FlowConfig:
    """Dense optical flow between consecutive frames."""

    backend: str = "dis"
    dis_preset: str = "medium"
    dis_iterations: int = 12  # gradient-descent iterations per scale instead of the preset's (0: the preset's)
    dis_patch_stride: int = 4  # pixels between DIS patches instead of the preset's (0: the preset's)
    dis_refinement: int = 2  # variational refinement iterations of the forward flow (-1: the preset's)
    dis_check_refinement: int = 0  # variational refinement iterations of the checking backward flow (-1: as forward)
    dis_check_patch_stride: int = 6  # pixels between the checking backward flow's patches (0: as forward)
    working_width: int = 320
    fb_threshold: float = 1.5  # forward-backward disagreement (working-resolution px) that marks flow unreliable
    min_texture: float = 1e-4  # smallest structure-tensor eigenvalue (working resolution) where flow is trusted
    learned_preset: str = "small"  # learned backend: bundled weights (frontend/flow/weights/NAME.pt)
    weights: str = ""  # learned backend: a weights file from `osslam flow train` instead of the bundled preset
    iterations: list[int] = field(default_factory=list)  # learned backend: steps per scale; empty: the weights file's
    threads: int = 1  # learned backend: CPU threads


@dataclass
class MotionConfig:
    """Rigid motion segmentation of the flow against the camera's ego-motion."""

    enabled: bool = True
    stride: int = 4
    ransac_threshold: float = 2.0
    ransac_iterations: int = 200
    ego_check: float = 0.5  # tracked ego-motion leaving more of the background points moving is re-fitted (1: off)
    ego_refine: float = 1.5  # ego-motion (given or fitted) refined on background flow below this residual ratio (0: off)
    rolling_shutter: bool = True  # ... and let change over the image's rows (rows exposed one after the other)
    ego_refine_passes: int = 2  # refinements, each on the background the last one explains
    predict: bool = True  # segment beside tracking with the last frame's anchored ego-motion as prediction, ...
    predict_check: float = 0.2  # ... kept when the tracked one moves at most this share of its background
    max_bodies: int = 3  # rigid motions fitted when the ego-motion comes from the flow alone
    points_per_cell: int = 12  # points per cell of a 16 x 12 grid used in that fit
    object_fit_points: int = 200  # at most this many points fit each moving object's rigid motion
    min_residual: float = 1.5
    flow_relative: float = 0.10  # residual threshold grows by this fraction of the rigid flow's length
    depth_sigma_factor: float = 3.0
    min_area: int = 600
    memory_frames: int = 30  # frames a cell that moved stays dynamic after it stops
    memory_per_move: int = 3  # ... at most this many frames per frame it was seen moving (0: memory_frames)
    surface_fraction: float = 0.3  # a depth-connected surface this much moving is moving as a whole (0: off)
    surface_max_area: float = 0.2  # ... unless it covers more than this fraction of the image (floor, desk, walls)
    surface_step: float = 0.04  # relative depth step between neighbouring grid cells that separates surfaces
    surface_grey_step: float = 0.0  # ... and step in grey levels (5 x 5 smoothed) that does too (0: off; 40 tried)
    map_surface_fraction: float = 0.3  # dense map only: a surface this much moving is left out whole (0: off), ...
    map_edge_fraction: float = 0.05  # ... or this much when cut off by the image border ...
    map_edge_max_area: float = 0.12  # ... and covering at most this fraction of the image (0: off)
    free_space_frames: int = 10  # frames back to the depth whose free space a point may not occupy (0: off)
    free_space_margin: float = 0.05  # metres in front of that surface, beyond depth noise, that count as moved in
    min_depth: float = 0.1
    max_depth: float = 6.0


@dataclass
class FusionConfig:
    """Algorithm 1: when a detector mask replaces a motion mask, and the final dilation."""

    inclusion_rate: float = 0.9
    max_centre_distance: float = 60.0
    remainder_margin: int = 8  # pixels around a replacing detection that its motion mask may leak into
    remainder_area: int = 600  # pixels a region of the replaced motion mask beyond that margin needs to stay
    dilation: int = 5  # pixels the motion masks grow by
    detection_dilation: int = 0  # pixels the detector masks grow by
    detection_motion_radius: int = 24  # a detection seen moving keeps its pixels this near the motion masks (0: all)


@dataclass
class MappingConfig:
    """Dense static map: the depth of map views back-projected, fused on a voxel grid and cleaned.

    A tracked frame becomes a map view when ``view_interval`` seconds have passed since the
    last one (0: every keyframe is one); on a clock, the views do not depend on which
    frames movers made keyframes. Of each view, every ``stride``-th pixel is kept that has
    depth in ``[min_depth, max_depth]``, lies outside the frame's dynamic mask (joined with
    the masks of the ``mask_frames`` frames before it and of the ``mask_frames_after``
    frames after it, for which the view waits: a mover the gate lost for a frame or two is
    masked just before or just after; grown by ``mask_dilation`` pixels), at least
    ``image_border`` pixels from the image's edge (depth is least reliable there, and a
    mover entering the frame is cut off, which the gate segments worst), and off depth
    edges (a depth within ``depth_edge_radius`` pixels differing by more than
    ``depth_edge`` times its own; 0 turns it off). Fusion deduplicates on ``voxel_size``;
    ``support_voxel`` is the coarser grid on which the number of views seeing a region is
    counted. Cleaning: Open3D's statistical outlier removal (``sor_neighbors``,
    ``sor_std_ratio``; 0 neighbours turns it off), then the residue step: points
    back-projected within ``residue_mask_radius`` pixels of their view's dynamic mask (0:
    every point; where no mask was, nothing is a mover's residue) and seen by fewer than
    ``residue_min_support`` views are clustered (``residue_cluster_radius``) and clusters
    whose mean neighbour distance lies more than ``residue_std_ratio`` standard deviations
    above the map's mean (below it, when negative) are dropped (``residue_min_support: 0``
    turns it off). Before both, points in space that at least ``free_space_views`` views
    saw through (their static depth reaching more than ``free_space_margin`` plus depth
    noise beyond the point), and more views than saw them there, are dropped as the residue
    of objects that moved away (0 turns it off); at most ``free_space_max_views`` views,
    spread over the run, are kept for it.
    ``tsdf`` also integrates the views into Open3D's scalable TSDF volume for a mesh.
    """

    enabled: bool = True
    view_interval: float = 0.4
    voxel_size: float = 0.01
    min_depth: float = 0.1
    max_depth: float = 4.0
    stride: int = 4
    mask_frames: int = 2
    mask_frames_after: int = 2
    mask_dilation: int = 5
    image_border: int = 16
    depth_edge: float = 0.1
    depth_edge_radius: int = 2
    support_voxel: float = 0.05
    sor_neighbors: int = 20
    sor_std_ratio: float = 2.0
    residue_mask_radius: int = 30
    residue_min_support: int = 8
    residue_cluster_radius: float = 0.03
    residue_neighbors: int = 8
    residue_std_ratio: float = -1.0
    free_space_views: int = 2
    free_space_margin: float = 0.05
    free_space_max_views: int = 256
    tsdf: bool = False
    tsdf_voxel: float = 0.01
    tsdf_trunc: float = 0.04
    preview: bool = True
    preview_points: int = 60000


@dataclass
class ModelsConfig:
    """Where pretrained model files are kept (empty: $OSSLAM_MODELS, else the user cache)."""

    dir: str = ""


@dataclass
class EvalConfig:
    """Trajectory evaluation."""

    rpe_delta_frames: int = 1
    max_time_diff: float = 0.01
    plots: bool = True


@dataclass
class RunConfig:
    """Whole-run settings."""

    seed: int = 0
    threads: int = 1


@dataclass
class Config:
    """The complete configuration of a run."""

    dataset: DatasetConfig = field(default_factory=DatasetConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    features: FeaturesConfig = field(default_factory=FeaturesConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    backend: BackendConfig = field(default_factory=BackendConfig)
    gating: GatingConfig = field(default_factory=GatingConfig)
    detection: DetectionConfig = field(default_factory=DetectionConfig)
    flow: FlowConfig = field(default_factory=FlowConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    models: ModelsConfig = field(default_factory=ModelsConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    run: RunConfig = field(default_factory=RunConfig)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dictionary, ready for YAML."""
        return dataclasses.asdict(self)


#: Bounds (inclusive; None: open) of the dynamic gating's numeric settings. Settings that are
#: counts or sizes start at 0 where 0 turns them off and at 1 where nothing turns them off.
RANGES: dict[str, tuple[float | None, float | None]] = {
    "gating.prior_margin": (0, None),
    "detection.score": (0.0, 1.0),
    "detection.depth_layer": (0.0, None),
    "detection.threads": (1, None),
    "flow.dis_iterations": (0, None),
    "flow.dis_patch_stride": (0, None),
    "flow.dis_refinement": (-1, None),
    "flow.dis_check_refinement": (-1, None),
    "flow.dis_check_patch_stride": (0, None),
    "flow.working_width": (32, None),
    "flow.fb_threshold": (0.0, None),
    "flow.min_texture": (0.0, None),
    "flow.threads": (1, None),
    "motion.stride": (1, None),
    "motion.ransac_threshold": (0.0, None),
    "motion.ransac_iterations": (1, None),
    "motion.ego_check": (0.0, 1.0),
    "motion.ego_refine": (0.0, None),
    "motion.ego_refine_passes": (1, None),
    "motion.predict_check": (0.0, 1.0),
    "motion.max_bodies": (1, None),
    "motion.points_per_cell": (1, None),
    "motion.object_fit_points": (12, None),  # the fewest points a rigid fit takes
    "motion.min_residual": (0.0, None),
    "motion.flow_relative": (0.0, None),
    "motion.depth_sigma_factor": (0.0, None),
    "motion.min_area": (0, None),
    "motion.memory_frames": (0, None),
    "motion.memory_per_move": (0, None),
    "motion.surface_fraction": (0.0, 1.0),
    "motion.surface_max_area": (0.0, 1.0),
    "motion.surface_step": (0.0, None),
    "motion.surface_grey_step": (0.0, None),
    "motion.map_surface_fraction": (0.0, 1.0),
    "motion.map_edge_fraction": (0.0, 1.0),
    "motion.map_edge_max_area": (0.0, 1.0),
    "motion.free_space_frames": (0, None),
    "motion.free_space_margin": (0.0, None),
    "motion.min_depth": (0.0, None),
    "motion.max_depth": (0.0, None),
    "fusion.inclusion_rate": (0.0, 1.0),
    "fusion.max_centre_distance": (0.0, None),
    "fusion.remainder_margin": (0, None),
    "fusion.remainder_area": (0, None),
    "fusion.dilation": (0, None),
    "fusion.detection_dilation": (0, None),
    "fusion.detection_motion_radius": (0, None),
}
#: Pairs of settings whose first must be below the second.
ORDERED = [("motion.min_depth", "motion.max_depth")]


def out_of_range(key: str, value: Any) -> str | None:
    """What is wrong with ``value`` for the setting ``key`` (``section.name``) by :data:`RANGES`; None when nothing."""
    low, high = RANGES.get(key, (None, None))
    if (low is not None and value < low) or (high is not None and value > high):
        bounds = f"within [{low}, {high}]" if low is not None and high is not None else (
            f"at least {low}" if low is not None else f"at most {high}")
        return f"{key} must be {bounds}, got {value!r}"
    return None


def check_config(cfg: Config) -> None:
    """Raise :class:`ConfigError` for the first setting outside :data:`RANGES` or pair out of :data:`ORDERED` order."""
    def value(key: str) -> Any:
        section, name = key.split(".")
        return getattr(getattr(cfg, section), name)

    for key in RANGES:
        problem = out_of_range(key, value(key))
        if problem:
            raise ConfigError(problem)
    for first, second in ORDERED:
        if not value(first) < value(second):
            raise ConfigError(f"{first} ({value(first)!r}) must be below {second} ({value(second)!r})")


def preset_names() -> list[str]:
    """Names of the YAML presets shipped in ``osslam.configs``."""
    folder = resources.files("osslam.configs")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def _coerce(value: Any, annotation: Any, where: str) -> Any:
    """Convert ``value`` to the type named by a dataclass field annotation."""
    if isinstance(annotation, str):
        annotation = eval(annotation, {"list": list, "float": float, "int": int, "str": str, "bool": bool})
    origin = typing.get_origin(annotation)
    if origin in (list, tuple):
        (item,) = typing.get_args(annotation)[:1]
        if isinstance(value, str):
            value = yaml.safe_load(value)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        return [_coerce(v, item, where) for v in value]
    if origin is types.UnionType or origin is typing.Union:
        return value
    if annotation is bool:
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower()
        if text in ("1", "true", "yes", "on"):
            return True
        if text in ("0", "false", "no", "off"):
            return False
        raise ConfigError(f"{where}: expected true/false, got {value!r}")
    if annotation in (int, float, str):
        try:
            if annotation is int and isinstance(value, float) and not value.is_integer():
                raise ValueError
            return annotation(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: expected {annotation.__name__}, got {value!r}") from None
    return value


def _apply(cfg: Config, data: dict[str, Any], origin: str) -> None:
    """Apply a nested mapping of section -> {key: value} onto ``cfg`` in place."""
    if not isinstance(data, dict):
        raise ConfigError(f"{origin}: expected a mapping of sections, got {type(data).__name__}")
    sections = {f.name: f for f in dataclasses.fields(cfg)}
    for name, values in data.items():
        if name not in sections:
            raise ConfigError(f"{origin}: unknown section '{name}' (known: {', '.join(sections)})")
        section = getattr(cfg, name)
        if not isinstance(values, dict):
            raise ConfigError(f"{origin}: section '{name}' must be a mapping")
        known = {f.name: f for f in dataclasses.fields(section)}
        hints = typing.get_type_hints(type(section))
        for key, value in values.items():
            if key not in known:
                raise ConfigError(f"{origin}: unknown key '{name}.{key}' (known: {', '.join(known)})")
            value = _coerce(value, hints[key], f"{origin}: {name}.{key}")
            problem = out_of_range(f"{name}.{key}", value)
            if problem:
                raise ConfigError(f"{origin}: {problem}")
            setattr(section, key, value)


def load_config(source: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """Build a Config from defaults, an optional preset name or YAML path, and overrides.

    ``source`` is a preset name (see :func:`preset_names`), a path to a YAML file, or None.
    Each override is ``section.key=value``; the value is parsed as YAML and coerced to the
    field's type.
    """
    cfg = Config()
    if source is not None:
        path = Path(source)
        if path.suffix in (".yaml", ".yml") or path.exists():
            if not path.is_file():
                raise ConfigError(f"{path}: config file not found")
            text = path.read_text()
            origin = str(path)
        else:
            name = str(source)
            if name not in preset_names():
                raise ConfigError(f"unknown config preset '{name}' (presets: {', '.join(preset_names())})")
            text = resources.files("osslam.configs").joinpath(f"{name}.yaml").read_text()
            origin = f"preset {name}"
        try:
            data = yaml.safe_load(text) or {}
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = f" line {mark.line + 1}" if mark is not None else ""
            raise ConfigError(f"{origin}:{line} invalid YAML") from None
        _apply(cfg, data, origin)
    for item in overrides or []:
        key, sep, value = item.partition("=")
        if not sep or "." not in key:
            raise ConfigError(f"override '{item}': expected section.key=value")
        section, _, name = key.strip().partition(".")
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError:
            parsed = value
        _apply(cfg, {section: {name: parsed}}, f"override '{item}'")
    check_config(cfg)
    return cfg


def save_config(cfg: Config, path: str | Path) -> None:
    """Write the effective configuration as YAML."""
    Path(path).write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
