"""Composite sequences of a suite: ``osslam synth`` movers in a TUM sequence, built once into a cache.

A composite is written as ``composite:base=FOLDER,seed=1`` (keys below); it is built the
first time a job needs it into ``<suite output>/composites/<label>-<digest>/`` and reused
by every other job and later call. The digest covers every parameter, with paths resolved,
so a changed specification builds a new folder. Concurrent builders (jobs in several
processes) take a lock file and build into a temporary folder that is renamed into place
when complete, so a composite folder is either absent or whole, and is built once. The
lock files stay (``<folder>.lock``, empty): removing one could race with a waiting builder.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

from osslam.config import ConfigError
from osslam.datasets.catalogue import tum_entry
from osslam.folders import folder_aside

log = logging.getLogger(__name__)

COMPOSITES_DIR = "composites"
COMPOSITE_KEYS = ("base", "seed", "boxes", "frames", "person", "person_model")
DEFAULT_BOXES = 2


@dataclass(frozen=True)
class CompositeSpec:
    """Movers of ``seed`` (``boxes`` boxes, a person cut out of ``person`` with ``person_model``) in ``base``.

    ``frames`` > 0 keeps only the first frames of the base sequence.
    """

    base: Path
    seed: int = 0
    boxes: int = DEFAULT_BOXES
    frames: int = 0
    person: Path | None = None
    person_model: Path | None = None

    @property
    def suffix(self) -> str:
        """The label's composite part: ``synth-s1``, plus ``-b3`` / ``-f100`` / ``-person`` where they apply."""
        parts = [f"synth-s{self.seed}"]
        if self.boxes != DEFAULT_BOXES:
            parts.append(f"b{self.boxes}")
        if self.frames > 0:
            parts.append(f"f{self.frames}")
        if self.person is not None:
            parts.append("person")
        return "-".join(parts)

    @property
    def digest(self) -> str:
        """A short hash of every parameter, paths resolved: a changed specification gets a new folder."""
        params = {"base": str(self.base.resolve()), "seed": self.seed, "boxes": self.boxes, "frames": self.frames,
                  "person": str(self.person.resolve()) if self.person else None,
                  "person_model": str(self.person_model.resolve()) if self.person_model else None}
        return hashlib.sha1(json.dumps(params, sort_keys=True).encode()).hexdigest()[:10]


def parse_composite(text: str, data_dir: Path) -> CompositeSpec:
    """A :class:`CompositeSpec` from ``base=FOLDER|tum:NAME,seed=S[,boxes=N][,frames=N][,person=IMG,person_model=TFLITE]``.

    Raises ConfigError (the caller names the file and entry) for anything else.
    """
    params: dict[str, str] = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = (s.strip() for s in item.partition("="))
        if not sep or key not in COMPOSITE_KEYS or not value:
            raise ConfigError(f"expected key=value with keys {', '.join(COMPOSITE_KEYS)}")
        if key in params:
            raise ConfigError(f"'{key}' given twice")
        params[key] = value
    if "base" not in params:
        raise ConfigError("'base' (a TUM folder or tum:NAME) is required")
    if ("person" in params) != ("person_model" in params):
        raise ConfigError("'person' and 'person_model' go together")
    base = params["base"]
    base_path = data_dir / tum_entry(base[4:]).folder if base.startswith("tum:") else Path(base)
    try:
        numbers = {k: int(params[k]) for k in ("seed", "boxes", "frames") if k in params}
    except ValueError:
        raise ConfigError("seed, boxes and frames are whole numbers") from None
    if numbers.get("boxes", DEFAULT_BOXES) < 0 or numbers.get("frames", 0) < 0:
        raise ConfigError("boxes and frames cannot be negative")
    person = params.get("person")
    model = params.get("person_model")
    return CompositeSpec(base_path, **numbers, person=Path(person) if person else None,
                         person_model=Path(model) if model else None)


def _build(spec: CompositeSpec, target: Path, preset: str | None) -> None:
    """Write the composite of ``spec`` into ``target`` (the base read with ``preset`` and no overrides)."""
    from osslam.config import load_config
    from osslam.datasets import open_sequence
    from osslam.datasets.composite import (
        CompositeConfig,
        composite_sequence,
        person_cutout,
    )

    base = open_sequence(spec.base, load_config(preset))
    person = person_cutout(spec.person, spec.person_model) if spec.person is not None else None
    composite_sequence(base, target, CompositeConfig(seed=spec.seed, n_boxes=spec.boxes, max_frames=spec.frames),
                       person)


def ensure_composite(spec: CompositeSpec, folder: Path, preset: str | None) -> bool:
    """Build the composite of ``spec`` into ``folder`` unless it is there; True when this call built it.

    Safe with concurrent callers on one machine (a lock file beside ``folder``) and, as the
    folder only appears by an atomic rename of a complete build, across machines sharing
    the file system (there the composite may be built twice, never half).
    """
    if folder.is_dir():
        return False
    folder.parent.mkdir(parents=True, exist_ok=True)
    with open(folder.parent / f"{folder.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if folder.is_dir():
            return False
        start = time.perf_counter()
        with folder_aside(folder) as tmp:
            _build(spec, tmp, preset)
            try:
                tmp.rename(folder)
            except OSError:
                if not folder.is_dir():
                    raise
                return False  # another machine renamed its build into place first
        log.info("composite %s built in %.1f s", folder, time.perf_counter() - start)
        return True
