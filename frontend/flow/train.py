"""Training of the flow network: seeded data stream, AdamW one-cycle, checkpoints with resume, CSV log, AMP on GPU."""

from __future__ import annotations

import csv
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import torch
import yaml

from osslam.progress import Progress

from .data.mix import Batch, TrainingStream, build_sources
from .loss import sequence_loss
from .network import MultiScaleFlowNet, count_parameters
from .settings import TrainConfig
from .weights import save_weights

CHECKPOINT = "checkpoint.pt"
LOG = "train_log.csv"
WEIGHTS = "weights.pt"
RESUME_SLACK = 100


@dataclass
class TrainResult:
    """Where the outputs are and what the run did."""

    weights: Path
    steps: int
    seconds: float
    final_loss: float


def make_stream(cfg: TrainConfig) -> TrainingStream:
    """The configured training data as a seeded batch stream."""
    d = cfg.data
    room = {"seeds": d.room_seeds, "frames": d.room_frames, "size": d.room_size, "gaps": d.room_gaps}
    sources = build_sources(d.weights, d.procedural, room, d.roots, d.cache, cfg.optim.seed)
    o = cfg.optim
    return TrainingStream(sources, d.weights, o.crop, o.batch, o.seed, o.grayscale, o.flip)


def train_step(net: MultiScaleFlowNet, opt: torch.optim.Optimizer, batch: Batch, cfg: TrainConfig,
               device: torch.device, scaler: torch.amp.GradScaler | None) -> float:
    """One optimisation step on a batch; the loss before the step."""
    net.train()
    im1, im2, flow, valid = (t.to(device) for t in (batch.image1, batch.image2, batch.flow, batch.valid))
    with torch.autocast(device.type, enabled=scaler is not None):
        preds = net(im1, im2, all_steps=True)
    loss = sequence_loss([dataclasses.replace(p, flow=p.flow.float()) for p in preds], flow, valid, cfg.loss)
    opt.zero_grad(set_to_none=True)
    if scaler is not None:
        scaler.scale(loss).backward()
        scaler.unscale_(opt)
    else:
        loss.backward()
    torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.optim.clip)
    if scaler is not None:
        scaler.step(opt)
        scaler.update()
    else:
        opt.step()
    return float(loss.detach())


def train(cfg: TrainConfig, out_dir: str | Path, resume: bool = False, progress: bool | None = None) -> TrainResult:
    """Train for ``cfg.optim.steps`` steps into ``out_dir`` (checkpoint, CSV log, config, final weights)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    o = cfg.optim
    torch.set_num_threads(o.threads)
    torch.manual_seed(o.seed)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    net = MultiScaleFlowNet(cfg.model).to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=o.lr, weight_decay=o.weight_decay)
    # The schedule is fixed by the first start; the slack lets a resumed run go a little past it.
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, o.lr, total_steps=o.steps + RESUME_SLACK, pct_start=0.05,
                                                anneal_strategy="linear", cycle_momentum=False)
    scaler = torch.amp.GradScaler("cuda") if device.type == "cuda" else None
    start, elapsed = 0, 0.0
    ckpt = out / CHECKPOINT
    if resume and ckpt.is_file():
        state = torch.load(ckpt, map_location=device, weights_only=False)
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        start, elapsed = state["step"], state["seconds"]
    (out / "config.yaml").write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
    stream = make_stream(cfg)
    log_file = (out / LOG).open("a" if start else "w", newline="")
    log = csv.writer(log_file)
    if not start:
        log.writerow(["step", "loss", "lr", "seconds"])
    bar = Progress(o.steps, "flow train", enabled=progress)
    t0 = time.perf_counter() - elapsed
    loss = float("nan")
    try:
        for step in range(start, o.steps):
            loss = train_step(net, opt, stream(step), cfg, device, scaler)
            sched.step()
            done = step + 1
            if done % o.log_every == 0 or done == o.steps:
                log.writerow([done, f"{loss:.4f}", f"{sched.get_last_lr()[0]:.2e}", f"{time.perf_counter() - t0:.1f}"])
                log_file.flush()
            if done % o.checkpoint_every == 0 or done == o.steps:
                torch.save({"net": net.state_dict(), "opt": opt.state_dict(), "sched": sched.state_dict(),
                            "step": done, "seconds": time.perf_counter() - t0}, ckpt)
            bar.update(done, f"loss {loss:.3f}")
    finally:
        log_file.close()
    seconds = time.perf_counter() - t0
    meta = {"steps": o.steps, "train_seconds": round(seconds, 1), "parameters": count_parameters(net),
            "data": dict(cfg.data.weights), "final_loss": round(loss, 4)}
    weights = save_weights(out / WEIGHTS, net.cpu(), meta)
    return TrainResult(weights, o.steps, seconds, loss)
