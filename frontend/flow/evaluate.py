"""Scoring flow backends against ground-truth flow: accuracy (paper §4.2 metrics) and time per pair."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from osslam.config import FlowConfig, load_config
from osslam.errors import OsslamError

from .data.composite import composite_flow_pairs
from .data.rigid import RigidFlowPairs
from .data.sample import FlowSample
from .data.standard import LAYOUTS
from .metrics import FlowErrors


@dataclass
class BackendResult:
    """One backend's scores over a data set.

    ``all``: every pixel with ground truth; ``kept``: those the backend marks valid;
    ``movers``: ground-truth pixels on independently moving objects (composites).
    """

    backend: str
    pairs: int
    ms_per_pair: float
    kept_percent: float
    all: dict[str, float] = field(default_factory=dict)
    kept: dict[str, float] = field(default_factory=dict)
    movers: dict[str, float] = field(default_factory=dict)


def open_eval_data(spec: str) -> Sequence[FlowSample]:
    """``tum:FOLDER``, ``composite:FOLDER`` or ``LAYOUT:FOLDER`` as a data set of flow samples."""
    kind, sep, folder = spec.partition(":")
    if not sep:
        raise OsslamError(f"evaluation data '{spec}': expected KIND:FOLDER (tum, composite, {', '.join(LAYOUTS)})")
    if kind in ("tum", "composite"):
        from osslam.datasets import open_sequence
        from osslam.datasets.intrinsics import sensor_from_name

        path = Path(folder)
        sensor = sensor_from_name(path.resolve().name)
        seq = open_sequence(path, load_config(f"tum_fr{sensor[-1]}" if sensor else None))
        return RigidFlowPairs(seq) if kind == "tum" else composite_flow_pairs(seq)
    if kind in LAYOUTS:
        return LAYOUTS[kind](folder)
    raise OsslamError(f"evaluation data kind '{kind}' unknown (tum, composite, {', '.join(LAYOUTS)})")


def make_backend(name: str, working_width: int, threads: int, iterations: list[int]):
    """A flow estimator from ``dis`` (as SLAM runs it by default), ``dis:PRESET`` (OpenCV's preset as it is),
    ``learned`` or ``learned:WEIGHTS``."""
    from . import make_flow_estimator

    kind, _, arg = name.partition(":")
    if kind == "dis" and not arg:
        cfg = FlowConfig(backend="dis", working_width=working_width)
    elif kind == "dis":
        cfg = FlowConfig(backend="dis", dis_preset=arg, working_width=working_width, dis_iterations=0,
                         dis_patch_stride=0, dis_refinement=-1, dis_check_patch_stride=0)
    elif kind == "learned":
        cfg = FlowConfig(backend="learned", weights=arg, working_width=working_width, threads=threads,
                         iterations=list(iterations))
    else:
        raise OsslamError(f"backend '{name}' unknown (dis[:ultrafast|fast|medium], learned[:WEIGHTS])")
    return make_flow_estimator(cfg)


def evaluate_backends(data: Sequence[FlowSample], backends: list[str], working_width: int = 320, pairs: int = 0,
                      threads: int = 1, iterations: list[int] | None = None) -> list[BackendResult]:
    """Every backend on the same pairs (every k-th so that about ``pairs`` remain; 0: all)."""
    step = max(1, math.ceil(len(data) / pairs)) if pairs > 0 else 1
    indices = range(0, len(data), step)
    estimators = {name: make_backend(name, working_width, threads, iterations or []) for name in backends}
    scores = {name: (FlowErrors(), FlowErrors(), FlowErrors(), [], []) for name in backends}
    cv2.setNumThreads(threads)
    for i in indices:
        sample = data[i]
        src = cv2.cvtColor(sample.image1, cv2.COLOR_RGB2GRAY)
        tgt = cv2.cvtColor(sample.image2, cv2.COLOR_RGB2GRAY)
        for name, estimator in estimators.items():
            every, kept, movers, times, fractions = scores[name]
            t0 = time.perf_counter()
            field_ = estimator.compute(src, tgt)
            times.append((time.perf_counter() - t0) * 1e3)
            every.add(field_.flow, sample.flow, sample.valid)
            kept.add(field_.flow, sample.flow, sample.valid & field_.valid)
            fractions.append(float((sample.valid & field_.valid).sum()) / max(int(sample.valid.sum()), 1))
            if sample.movers is not None:
                movers.add(field_.flow, sample.flow, sample.valid & sample.movers)
    results = []
    for name in backends:
        every, kept, movers, times, fractions = scores[name]
        results.append(BackendResult(name, len(times), float(np.mean(times)), 100 * float(np.mean(fractions)),
                                     every.summary(), kept.summary(), movers.summary() if movers.pixels else {}))
    return results


def format_table(rows: list[BackendResult]) -> str:
    """A Markdown table of the results."""
    has_movers = any(r.movers for r in rows)
    head = ["backend", "pairs", "EPE", "1px %", "3px %", "5px %", "Fl-all %", "kept %", "EPE kept", "ms/pair"]
    head += ["EPE movers", "Fl movers %"] if has_movers else []
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        a = r.all
        cells = [r.backend, str(r.pairs), f"{a['epe']:.3f}", f"{a['1px']:.1f}", f"{a['3px']:.1f}", f"{a['5px']:.1f}",
                 f"{a['fl_all']:.2f}", f"{r.kept_percent:.1f}", f"{r.kept['epe']:.3f}", f"{r.ms_per_pair:.1f}"]
        if has_movers:
            cells += [f"{r.movers['epe']:.3f}", f"{r.movers['fl_all']:.2f}"] if r.movers else ["-", "-"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_results(rows: list[BackendResult], out_dir: str | Path, data: str) -> None:
    """``results.json`` and ``results.md`` in ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps({"data": data, "results": [asdict(r) for r in rows]}, indent=2))
    (out / "results.md").write_text(f"Flow on {data}\n\n{format_table(rows)}\n")
