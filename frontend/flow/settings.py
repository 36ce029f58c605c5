"""Typed training presets (``configs/flow/*.yaml``): model sizes, loss, data mix and optimisation."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from osslam.config import ConfigError

from .data.procedural import ProceduralConfig
from .loss import LossConfig
from .network import FlowNetConfig


@dataclass
class DataConfig:
    """The training mix: source -> weight, and how the sources here are made.

    Sources: ``procedural`` (AutoFlow-like pairs), ``room`` (rigid flow of the synthetic
    room, ``room_seeds`` sequences of ``room_frames`` frames at ``room_size`` (W, H),
    frame gaps ``room_gaps``), and the standard layouts ``chairs``, ``things``, ``sintel``,
    ``kitti``, ``hd1k`` with their folders in ``roots``. ``cache`` keeps up to that many
    made samples in memory.
    """

    weights: dict[str, float] = field(default_factory=lambda: {"procedural": 0.5, "room": 0.5})
    procedural: ProceduralConfig = field(default_factory=ProceduralConfig)
    room_seeds: list[int] = field(default_factory=lambda: [101, 102, 103, 104])
    room_frames: int = 120
    room_size: list[int] = field(default_factory=lambda: [320, 240])
    room_gaps: list[int] = field(default_factory=lambda: [1, 2, 3])
    roots: dict[str, str] = field(default_factory=dict)
    cache: int = 400


@dataclass
class OptimConfig:
    """Steps, batch, crop (H, W), AdamW with a one-cycle schedule, checkpoints and logging."""

    steps: int = 3000
    batch: int = 4
    crop: list[int] = field(default_factory=lambda: [192, 256])
    lr: float = 4e-4
    weight_decay: float = 1e-4
    clip: float = 1.0
    seed: int = 0
    grayscale: bool = True  # the runtime sees grey images (replicated to 3 channels); train on the same
    flip: bool = True
    checkpoint_every: int = 200
    log_every: int = 10
    threads: int = 1


@dataclass
class TrainConfig:
    """A complete training preset."""

    model: FlowNetConfig = field(default_factory=FlowNetConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dictionary, ready for YAML."""
        return dataclasses.asdict(self)


def preset_path(name: str) -> Path:
    """The file of a built-in training preset (``configs/flow/NAME.yaml``)."""
    folder = resources.files("osslam.configs").joinpath("flow")
    path = Path(str(folder.joinpath(f"{name}.yaml")))
    if not path.is_file():
        names = sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))
        raise ConfigError(f"unknown flow preset '{name}' (presets: {', '.join(names)})")
    return path


def load_train_config(source: str | Path, overrides: list[str] | None = None) -> TrainConfig:
    """A preset name or YAML file, then ``section.key=value`` overrides (``data.procedural.noise=2`` nests)."""
    path = Path(source)
    if path.suffix not in (".yaml", ".yml") and not path.exists():
        path = preset_path(str(source))
    if not path.is_file():
        raise ConfigError(f"{path}: flow training config not found")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError:
        raise ConfigError(f"{path}: invalid YAML") from None
    for item in overrides or []:
        key, sep, value = item.partition("=")
        if not sep or "." not in key:
            raise ConfigError(f"override '{item}': expected section.key=value")
        *parents, leaf = key.strip().split(".")
        node = data
        for name in parents:
            node = node.setdefault(name, {})
        node[leaf] = yaml.safe_load(value)
    return _build(TrainConfig, data, str(path))


def _build(cls, data: Any, where: str):
    """Instance of dataclass ``cls`` from a mapping, nested dataclasses included; unknown keys are errors."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping for {cls.__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in data.items():
        if key not in fields:
            raise ConfigError(f"{where}: unknown key '{key}' in {cls.__name__} (known: {', '.join(fields)})")
        default = fields[key].default_factory() if fields[key].default_factory is not dataclasses.MISSING else None
        kwargs[key] = _build(type(default), value, f"{where}: {key}") if dataclasses.is_dataclass(default) else value
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None
