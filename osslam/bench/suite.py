"""A benchmark suite: sequences, configurations, repeats and external estimates, read from YAML.

Sequences are written as text:

* ``synthetic:seed=3,frames=150`` - the built-in synthetic room (any ``SyntheticConfig``
  field; ``frames`` stands for ``n_frames``), rendered in the job, nothing on disk;
* ``tum:fr3/walking_xyz`` - a catalogued TUM sequence inside the data folder (where
  ``osslam download tum`` puts it);
* ``composite:base=FOLDER,seed=1`` - the movers of ``osslam synth`` composited into a TUM
  sequence, with ground-truth masks. Keys: ``base`` (a TUM folder or ``tum:NAME``, required),
  ``seed`` (0), ``boxes`` (2), ``frames`` (0: all), ``person`` and ``person_model`` (a photo
  and MediaPipe's selfie segmentation ``.tflite``, together). Labelled after the base,
  ``fr1/xyz+synth-s1`` (``-b3``, ``-f100``, ``-person`` where they apply); built once into
  ``<output>/composites/`` (see :mod:`osslam.bench.composites`) and run like a folder;
  paths cannot contain commas;
* anything else - a TUM-layout sequence folder.

Relative paths are taken from the working directory. Each configuration has a name (its
output folder), a preset (``auto``: ``tum_frN`` from the sequence's folder name - the base's
for composites -, ``synthetic`` for synthetic sequences) and overrides.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from osslam.config import ConfigError
from osslam.datasets.catalogue import CatalogueError, tum_entry
from osslam.datasets.intrinsics import sensor_from_name

from .composites import COMPOSITES_DIR, CompositeSpec, parse_composite

AUTO_PRESET = "auto"
SYNTHETIC_PREFIX = "synthetic:"
TUM_PREFIX = "tum:"
COMPOSITE_PREFIX = "composite:"
_SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
_TUM_FOLDER = re.compile(r"^rgbd_dataset_freiburg([123])_(.+)$")
_SUITE_KEYS = {"name", "description", "sequences", "configs", "repeats", "external", "data"}


def _folder_label(path: Path) -> str:
    """``fr1/xyz`` for a TUM folder name, else the folder's name."""
    match = _TUM_FOLDER.match(path.name)
    return f"fr{match.group(1)}/{match.group(2)}" if match else path.name


@dataclass(frozen=True)
class SequenceSpec:
    """One sequence of a suite: a TUM-layout folder (``path``), a synthetic scene (``synthetic``) or a ``composite``."""

    text: str
    path: Path | None = None
    synthetic: tuple[tuple[str, Any], ...] = ()
    composite: CompositeSpec | None = None

    @property
    def label(self) -> str:
        """The row name in tables: ``fr1/xyz`` for TUM folders, ``fr1/xyz+synth-s1``, ``synth-s3-f150``, else the folder name."""
        if self.composite is not None:
            return f"{_folder_label(self.composite.base)}+{self.composite.suffix}"
        if self.path is None:
            params = dict(self.synthetic)
            return f"synth-s{params.get('seed', 0)}-f{params.get('n_frames', 150)}"
        return _folder_label(self.path)

    @property
    def key(self) -> str:
        """The output folder name: the label with ``/`` replaced."""
        return self.label.replace("/", "_")

    @property
    def default_preset(self) -> str | None:
        """The preset an ``auto`` configuration uses for this sequence (a composite's is its base's)."""
        folder = self.composite.base if self.composite is not None else self.path
        if folder is None:
            return "synthetic"
        sensor = sensor_from_name(folder.resolve().name)
        return f"tum_fr{sensor[-1]}" if sensor else None

    def folder(self, root: Path) -> Path | None:
        """The TUM folder a job reads (a composite's in the cache below the suite output ``root``); None if synthetic."""
        if self.composite is not None:
            return root / COMPOSITES_DIR / f"{self.key}-{self.composite.digest}"
        return self.path

    def groundtruth(self, root: Path, run_dir: Path) -> Path | None:
        """The ground-truth file of a run of this sequence in ``run_dir`` (synthetic runs write their own)."""
        candidate = (self.folder(root) or run_dir) / "groundtruth.txt"
        return candidate if candidate.is_file() else None


@dataclass(frozen=True)
class ConfigSpec:
    """A named configuration: a preset (``auto`` picks one per sequence) plus ``section.key=value`` overrides."""

    name: str
    preset: str = AUTO_PRESET
    overrides: tuple[str, ...] = ()

    def preset_for(self, sequence: SequenceSpec) -> str | None:
        """The preset used on ``sequence``."""
        return sequence.default_preset if self.preset == AUTO_PRESET else self.preset


@dataclass(frozen=True)
class Suite:
    """Sequences x configurations x repeats, plus external estimates (name -> folder of TUM files)."""

    name: str
    sequences: tuple[SequenceSpec, ...]
    configs: tuple[ConfigSpec, ...]
    repeats: int = 1
    external: tuple[tuple[str, Path], ...] = ()
    description: str = ""


def _synthetic_params(text: str) -> tuple[tuple[str, Any], ...]:
    """Parse ``seed=3,frames=150`` into SyntheticConfig fields, checked against its names."""
    from osslam.datasets.synthetic import SyntheticConfig

    known = {f.name: f.type for f in fields(SyntheticConfig)}
    params: dict[str, Any] = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = item.partition("=")
        key = {"frames": "n_frames"}.get(key.strip(), key.strip())
        if not sep or key not in known:
            raise ConfigError(f"expected key=value with keys frames, {', '.join(k for k in known if k != 'n_frames')}")
        params[key] = yaml.safe_load(value)
    return tuple(sorted(params.items()))


def parse_sequence(text: str, data_dir: Path, origin: str) -> SequenceSpec:
    """A :class:`SequenceSpec` from its text (see the module docstring); ``tum:`` names look in ``data_dir``.

    Raises ConfigError naming ``origin`` (the suite file) and the entry for text it cannot read.
    """
    text = str(text).strip()
    try:
        if text.startswith(COMPOSITE_PREFIX):
            return SequenceSpec(text, composite=parse_composite(text[len(COMPOSITE_PREFIX):], data_dir))
        if text.startswith(SYNTHETIC_PREFIX):
            return SequenceSpec(text, synthetic=_synthetic_params(text[len(SYNTHETIC_PREFIX):]))
        if text.startswith(TUM_PREFIX):
            return SequenceSpec(text, path=data_dir / tum_entry(text[len(TUM_PREFIX):]).folder)
    except (ConfigError, CatalogueError) as exc:
        raise ConfigError(f"{origin}: sequence '{text}': {exc}") from None
    return SequenceSpec(text, path=Path(text))


def parse_config(item: Any, where: str) -> ConfigSpec:
    """A :class:`ConfigSpec` from a preset name or a mapping ``{name, preset, set}``."""
    if isinstance(item, str):
        item = {"name": Path(item).stem, "preset": item}
    if not isinstance(item, dict) or "name" not in item or set(item) - {"name", "preset", "set"}:
        raise ConfigError(f"{where}: a config is a preset name or a mapping with name, preset, set")
    name = str(item["name"])
    if not _SAFE_NAME.match(name):
        raise ConfigError(f"{where}: config name '{name}' must be letters, digits, '_', '.', '+' or '-'")
    overrides = item.get("set") or []
    if isinstance(overrides, str) or not isinstance(overrides, list):
        raise ConfigError(f"{where}: 'set' of config '{name}' must be a list of section.key=value")
    return ConfigSpec(name, str(item.get("preset") or AUTO_PRESET), tuple(str(o) for o in overrides))


def suite_from_dict(data: dict, origin: str, data_dir: Path | None = None) -> Suite:
    """Build and check a Suite from the mapping of a suite file (``origin`` names it in errors)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{origin}: a suite is a mapping")
    unknown = set(data) - _SUITE_KEYS
    if unknown:
        raise ConfigError(f"{origin}: unknown key(s) {', '.join(sorted(unknown))} (known: {', '.join(sorted(_SUITE_KEYS))})")
    data_dir = data_dir or Path(data.get("data", "data/tum"))
    sequences = tuple(parse_sequence(s, data_dir, origin) for s in data.get("sequences") or [])
    configs = tuple(parse_config(c, origin) for c in data.get("configs") or [{"name": "default"}])
    external = tuple((str(k), Path(v)) for k, v in (data.get("external") or {}).items())
    if not sequences:
        raise ConfigError(f"{origin}: no sequences")
    for kind, names in (("sequence", [s.key for s in sequences]), ("config", [c.name for c in configs] + [e[0] for e in external])):
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ConfigError(f"{origin}: {kind} name(s) used twice: {', '.join(duplicates)}")
    repeats = int(data.get("repeats", 1))
    if repeats < 1:
        raise ConfigError(f"{origin}: repeats must be at least 1")
    return Suite(str(data.get("name", Path(origin).stem)), sequences, configs, repeats, external,
                 str(data.get("description", "")))


def builtin_suites() -> list[str]:
    """Names of the suite files shipped in ``osslam.configs/suites``."""
    folder = resources.files("osslam.configs").joinpath("suites")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_suite(source: str | Path, data_dir: Path | None = None) -> Suite:
    """Read a suite from a YAML file or a built-in suite name; ``data_dir`` overrides its ``data`` folder."""
    path = Path(source)
    if path.is_file():
        text, origin = path.read_text(), str(path)
    elif str(source) in builtin_suites():
        text = resources.files("osslam.configs").joinpath("suites", f"{source}.yaml").read_text()
        origin = f"suite {source}"
    else:
        raise ConfigError(f"suite '{source}' is neither a file nor a built-in suite ({', '.join(builtin_suites())})")
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError:
        raise ConfigError(f"{origin}: invalid YAML") from None
    return suite_from_dict(data, origin, data_dir)


def with_overrides(suite: Suite, overrides: list[str], repeats: int | None = None,
                   external: list[tuple[str, Path]] | None = None) -> Suite:
    """The suite with ``overrides`` appended to every config, and optionally other repeats or more externals."""
    configs = tuple(ConfigSpec(c.name, c.preset, c.overrides + tuple(overrides)) for c in suite.configs)
    return Suite(suite.name, suite.sequences, configs, repeats or suite.repeats,
                 suite.external + tuple(external or ()), suite.description)
