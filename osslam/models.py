"""Pretrained model files: where they come from, where they are kept, and their checksums.

The cache folder holds one sub-folder per model, laid out as the upstream files are named
(``yolo-fastest-1.1/yolo-fastest-1.1.weights`` ...). It is ``models.dir`` from the config,
else the ``OSSLAM_MODELS`` environment variable, else ``$XDG_CACHE_HOME/osslam/models``
(``~/.cache/osslam/models``).
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

from osslam.datasets.download import DownloadError, ProgressCallback, download
from osslam.errors import OsslamError

log = logging.getLogger(__name__)

ENV_VAR = "OSSLAM_MODELS"
_YOLO = "https://raw.githubusercontent.com/dog-qiuqiu/Yolo-Fastest/96a2900/ModelZoo"
_MEDIAPIPE = "https://storage.googleapis.com/mediapipe-assets"


@dataclass(frozen=True)
class ModelFile:
    """One file of a model: its path in the cache, its upstream address and SHA-256."""

    path: str
    url: str
    sha256: str


@dataclass(frozen=True)
class Model:
    """A named model made of one or more files."""

    name: str
    description: str
    files: tuple[ModelFile, ...]


MODELS: dict[str, Model] = {m.name: m for m in (
    Model("yolo-fastest-1.1", "Yolo-Fastest v1.1, COCO 80 classes (darknet cfg + weights)", (
        ModelFile("yolo-fastest-1.1/yolo-fastest-1.1.cfg", f"{_YOLO}/yolo-fastest-1.1_coco/yolo-fastest-1.1.cfg",
                  "f6df5775c1e862998cf69046eba9265be3ae84dfe8b2caab7529823f0795bf70"),
        ModelFile("yolo-fastest-1.1/yolo-fastest-1.1.weights",
                  f"{_YOLO}/yolo-fastest-1.1_coco/yolo-fastest-1.1.weights",
                  "1c445c42bbd6df63edea2cc69f99667b5650d663ca11e34b116240740cd42890"),
    )),
    Model("yolo-fastest-1.1-body", "Yolo-Fastest v1.1, one class: person (darknet cfg + weights)", (
        ModelFile("yolo-fastest-1.1-body/yolo-fastest-1.1_body.cfg",
                  f"{_YOLO}/yolo-fastest-1.1_body/yolo-fastest-1.1_body.cfg",
                  "045b8e276ebe3924474da8c866b7e709159ea067137b5d66bf9dd560411b2c1a"),
        ModelFile("yolo-fastest-1.1-body/yolo-fastest-1.1_body.weights",
                  f"{_YOLO}/yolo-fastest-1.1_body/yolo-fastest-1.1_body.weights",
                  "5bbb6d878f6e2eb3deee39e91dc6f9b39700e99ec83fa94d258670a554949728"),
    )),
    Model("mediapipe-selfie-segmentation", "MediaPipe selfie (person) segmentation, TFLite, 256x256 and 256x144", (
        ModelFile("mediapipe-selfie-segmentation/selfie_segmentation.tflite",
                  f"{_MEDIAPIPE}/selfie_segmentation.tflite",
                  "9ee168ec7c8f2a16c56fe8e1cfbc514974cbbb7e434051b455635f1bd1462f5c"),
        ModelFile("mediapipe-selfie-segmentation/selfie_segmentation_landscape.tflite",
                  f"{_MEDIAPIPE}/selfie_segmentation_landscape.tflite",
                  "a77d03f4659b9f6b6c1f5106947bf40e99d7655094b6527f214ea7d451106edd"),
    )),
)}


class ModelError(OsslamError):
    """An unknown model name, or a model file that is missing or fails its checksum."""


@dataclass
class FileStatus:
    """A model file in a cache folder: whether it is there and whether its checksum matches."""

    file: ModelFile
    path: Path
    present: bool
    verified: bool


def models_dir(configured: str = "") -> Path:
    """The cache folder: the configured one, else ``$OSSLAM_MODELS``, else the user cache."""
    if configured:
        return Path(configured).expanduser()
    if os.environ.get(ENV_VAR):
        return Path(os.environ[ENV_VAR]).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(cache) / "osslam" / "models"


def select(names: list[str] | None) -> list[Model]:
    """The models named (all when ``names`` is empty); ModelError for an unknown name."""
    if not names:
        return list(MODELS.values())
    unknown = [n for n in names if n not in MODELS]
    if unknown:
        raise ModelError(f"unknown model(s) {', '.join(unknown)} (known: {', '.join(MODELS)})")
    return [MODELS[n] for n in names]


def sha256(path: Path) -> str:
    """SHA-256 of a file, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def status(model: Model, folder: Path) -> list[FileStatus]:
    """Presence and checksum of each file of ``model`` in ``folder``."""
    out = []
    for file in model.files:
        path = folder / file.path
        present = path.is_file()
        out.append(FileStatus(file, path, present, present and sha256(path) == file.sha256))
    return out


def fetch(model: Model, folder: Path, mirror: str | None = None,
          on_progress: ProgressCallback | None = None) -> list[FileStatus]:
    """Download the files of ``model`` that are missing or corrupt, resuming, and verify them.

    ``mirror`` replaces the upstream addresses by ``mirror/<cache path>``. A file whose
    checksum does not match after download is deleted and reported as ModelError.
    """
    for st in status(model, folder):
        if st.verified:
            continue
        if st.present:
            log.warning("%s fails its checksum; downloading it again", st.path)
            st.path.unlink()
        url = f"{mirror.rstrip('/')}/{st.file.path}" if mirror else st.file.url
        try:
            download(url, st.path, on_progress=on_progress)
        except DownloadError as exc:
            raise ModelError(str(exc)) from None
        got = sha256(st.path)
        if got != st.file.sha256:
            st.path.unlink()
            raise ModelError(f"{url}: SHA-256 {got} does not match the expected {st.file.sha256}; file removed")
    return status(model, folder)

