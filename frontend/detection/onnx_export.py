"""A darknet network exported to ONNX for OpenCV's DNN module, built on first use and cached per user.

Reading a cached file needs no PyTorch; building one imports it.

The cache folder is the ``OSSLAM_ONNX_CACHE`` environment variable, else
``$XDG_CACHE_HOME/osslam/onnx`` (``~/.cache/osslam/onnx``). A file there is named by the
SHA-256 of the darknet cfg and weights it was built from, so it is never stale, and it is
never written into the models folder or the repository.
"""

from __future__ import annotations

import copy
import hashlib
import logging
import os
import uuid
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import cv2

from osslam.errors import OsslamError

from .darknet_cfg import Layout

if TYPE_CHECKING:
    from .darknet import DarknetNet

log = logging.getLogger(__name__)

ENV_VAR = "OSSLAM_ONNX_CACHE"
OPSET = 11
FORMAT = f"darknet-bn-fused-opset{OPSET}"  # part of the cache key: a new export recipe gets new files


class OnnxExportError(OsslamError):
    """The network could not be exported to ONNX, or the exported file could not be read back."""


def cache_dir() -> Path:
    """The cache folder: ``$OSSLAM_ONNX_CACHE``, else the user cache."""
    if os.environ.get(ENV_VAR):
        return Path(os.environ[ENV_VAR]).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(cache) / "osslam" / "onnx"


def cache_path(cfg_path: Path, weights_path: Path) -> Path:
    """Where the ONNX file built from these darknet files is kept: named by the weights and their hash."""
    digest = hashlib.sha256(FORMAT.encode())
    for path in (cfg_path, weights_path):
        digest.update(Path(path).read_bytes())
    return cache_dir() / f"{Path(weights_path).stem}-{digest.hexdigest()[:16]}.onnx"


def output_names(layout: Layout) -> list[str]:
    """The names the exported file gives the ``[yolo]`` outputs, in ``layout.outputs`` order."""
    return [f"yolo{i}" for i in range(len(layout.outputs))]


def _fused(net: DarknetNet) -> DarknetNet:
    """A copy of ``net`` (in eval mode) with each batch norm folded into its convolution."""
    from torch import nn
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    out = copy.deepcopy(net).eval()
    for block in out.layers:
        if isinstance(block, nn.Sequential) and hasattr(block, "bn"):
            block.conv = fuse_conv_bn_eval(block.conv, block.bn)
            block.bn = nn.Identity()
    return out


def export_onnx(net: DarknetNet, path: Path) -> None:
    """Write ``net`` (batch norms folded) to ``path`` as ONNX, atomically; OnnxExportError when that fails."""
    import torch

    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.part")
    x = torch.zeros(1, 3, net.layout.height, net.layout.width)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with warnings.catch_warnings():  # the TorchScript exporter's deprecation and constant-folding notes
            warnings.simplefilter("ignore")
            torch.onnx.export(_fused(net), (x,), str(tmp), opset_version=OPSET, dynamo=False,
                              input_names=["image"], output_names=output_names(net.layout))
        os.replace(tmp, path)
    except (ImportError, RuntimeError, OSError) as exc:
        raise OnnxExportError(f"{path}: ONNX export failed ({exc})") from None
    finally:
        tmp.unlink(missing_ok=True)


def read_onnx(path: Path, outputs: list[str]) -> cv2.dnn.Net:
    """The OpenCV DNN network (on the CPU) of an ONNX file with these outputs; OnnxExportError when unreadable."""
    try:
        dnn = cv2.dnn.readNetFromONNX(str(path))
    except cv2.error as exc:
        reason = str(exc).strip().splitlines()[-1]
        raise OnnxExportError(f"{path}: not a readable ONNX network ({reason})") from None
    missing = set(outputs) - set(dnn.getUnconnectedOutLayersNames())
    if missing:
        raise OnnxExportError(f"{path}: lacks the outputs {', '.join(sorted(missing))}")
    return dnn


def cached_dnn(cfg_path: Path, weights_path: Path, layout: Layout,
               network: Callable[[], DarknetNet]) -> cv2.dnn.Net:
    """The network of ``cfg_path`` and ``weights_path`` (of this layout) as an OpenCV DNN network from the cache.

    On a miss, and when a cached file cannot be read (logged), the file is exported from
    ``network()``, the PyTorch module. OnnxExportError when the export fails or its result is
    unreadable.
    """
    path = cache_path(cfg_path, weights_path)
    outputs = output_names(layout)
    if path.is_file():
        try:
            return read_onnx(path, outputs)
        except OnnxExportError as exc:
            log.warning("%s; rebuilding it", exc)
    export_onnx(network(), path)
    return read_onnx(path, outputs)
