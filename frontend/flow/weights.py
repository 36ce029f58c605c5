"""Self-describing weight files: the network's configuration, its parameters and how they were made."""

from __future__ import annotations

import dataclasses
import pickle
from pathlib import Path
from typing import Any

import torch

from osslam.errors import InputError, OsslamError

from .network import FlowNetConfig, MultiScaleFlowNet

#: Weights trained by this project's own training code (``configs/flow/small.yaml``), shipped with the package.
BUNDLED = Path(__file__).parent / "weights" / "small.pt"


def save_weights(path: str | Path, net: MultiScaleFlowNet, meta: dict[str, Any]) -> Path:
    """Write the configuration, parameters and ``meta`` (training details) to ``path``."""
    path = Path(path)
    torch.save({"config": dataclasses.asdict(net.cfg), "state_dict": net.state_dict(), "meta": meta}, path)
    return path


def load_weights(path: str | Path) -> tuple[MultiScaleFlowNet, dict[str, Any]]:
    """The network (in eval mode) stored in ``path``, and its training details."""
    path = Path(path)
    if not path.is_file():
        raise OsslamError(f"{path}: flow network weights not found (train them with 'osslam flow train', "
                          f"or set flow.weights)")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        net = MultiScaleFlowNet(FlowNetConfig(**state["config"]))
        net.load_state_dict(merged_gates(state["state_dict"]))
    except (RuntimeError, KeyError, TypeError, ValueError, EOFError, pickle.UnpicklingError) as exc:
        raise InputError(path, f"not a flow weights file or corrupt ({type(exc).__name__})") from None
    return net.eval(), state.get("meta", {})


def merged_gates(state_dict: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Parameters saved when the ConvGRU had separate ``convz`` and ``convr`` as one ``convzr`` (the same network)."""
    merged = {}
    for key, value in state_dict.items():
        if ".convz." in key:
            merged[key.replace(".convz.", ".convzr.")] = torch.cat([value, state_dict[key.replace(".convz.", ".convr.")]])
        elif ".convr." not in key:
            merged[key] = value
    return merged
