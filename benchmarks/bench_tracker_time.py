"""Benchmark: how much the dynamic gate raises the tracker's time per frame, measured in lockstep.

Two systems, gating off and gating on, track the same frames in turn in one process: each
frame goes to one and then to the other, the order swapping from frame to frame. Between
separate runs this machine's speed drifts by more than the effect (up to 16 ms a frame within
minutes); in lockstep the drift falls on both alike. The gated system's worker (a child
process by default) works beside that system's own tracking, as in a gated run, and is idle
while the other system tracks.

Prints each system's mean time per frame (all of ``System.track``, and less the back-end, whose
keyframes differ between the two), their difference with a standard error over blocks of
``--block`` frames (neighbouring frames' differences are not independent), and the gated
system's stages. On the tracker's thread, ``finish`` is the gate's check (and segmentation redone
where it failed), ``masked`` the pose refined without the observations under the mask and the
landmarks retired there; what is left untimed there is mostly the hand-over to the gate's worker.
Target (issue 3): the tracker's time raised by at most 5 ms.

    OSSLAM_MODELS=../shared/models python benchmarks/bench_tracker_time.py --frames 400
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from osslam.config import load_config
from osslam.datasets import open_sequence
from osslam.system import System

SHARED = Path(__file__).resolve().parents[2] / "shared"
DEFAULT_SEQUENCE = SHARED / "data" / "tum" / "rgbd_dataset_freiburg1_xyz"
GATE_STAGES = ("segmentation", "flow", "detection", "motion", "fusion", "wait", "finish")
TRACKER_STAGES = ("features", "tracking", "masked", "keyframe", "backend", "finish")  # timed on the tracker's thread


def _difference(on: np.ndarray, off: np.ndarray, block: int) -> tuple[float, float]:
    """Mean of ``on - off`` and its standard error from the means of consecutive blocks of frames."""
    diff = on - off
    n = len(diff) // block
    means = diff[: n * block].reshape(n, block).mean(axis=1)
    return float(diff.mean()), float(means.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", type=Path, nargs="?", default=DEFAULT_SEQUENCE)
    parser.add_argument("--config", default="tum_fr1")
    parser.add_argument("--frames", type=int, default=0, help="frames to track (0: all)")
    parser.add_argument("--skip", type=int, default=10, help="first frames left out of the figures (start-up)")
    parser.add_argument("--block", type=int, default=50, help="frames per block for the standard error")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()

    base = ["mapping.enabled=false", *args.overrides]
    configs = {gated: load_config(args.config, [*base, f"gating.enabled={str(gated).lower()}"])
               for gated in (False, True)}
    seq = open_sequence(args.sequence, configs[False])
    frames = len(seq) if args.frames <= 0 else min(args.frames, len(seq))
    if frames <= args.skip + args.block:
        parser.error(f"{frames} frames leave too few after --skip {args.skip} for blocks of {args.block}")
    columns = ("total", *TRACKER_STAGES)
    times = {gated: np.zeros((frames, len(columns))) for gated in (False, True)}  # ms per frame and column
    stages = {k: 0.0 for k in GATE_STAGES}
    with System(configs[False], seq.intrinsics) as off, System(configs[True], seq.intrinsics) as on:
        systems = {False: off, True: on}
        for i in range(frames):
            frame = seq[i]
            for gated in ((False, True) if i % 2 == 0 else (True, False)):
                t = systems[gated].track(frame.rgb, frame.depth, frame.timestamp).timings_ms
                times[gated][i] = [t.get(k, 0.0) for k in columns]
                if gated and i >= args.skip:
                    for k in GATE_STAGES:
                        stages[k] += t.get(k, 0.0)
            if (i + 1) % 100 == 0:
                print(f"  {i + 1}/{frames} frames", flush=True)
        keyframes = {gated: s.stats()["keyframes"] for gated, s in systems.items()}

    counted = frames - args.skip
    off_t, on_t = times[False][args.skip:], times[True][args.skip:]
    print(f"{args.sequence.name}: frames {args.skip}-{frames - 1} ({counted}), keyframes off {keyframes[False]}, "
          f"on {keyframes[True]}")
    backend = columns.index("backend")
    rows = {"all of track()": (off_t[:, 0], on_t[:, 0]),
            "less the back-end": (off_t[:, 0] - off_t[:, backend], on_t[:, 0] - on_t[:, backend])}
    for label, (a, b) in rows.items():
        mean, se = _difference(b, a, args.block)
        print(f"  {label:18s} ms per frame: off {a.mean():.1f}, on {b.mean():.1f}, difference {mean:+.1f} "
              f"(standard error {se:.1f}, blocks of {args.block}; {100 * (b.mean() / a.mean() - 1):+.1f} %); "
              f"target at most +5")
    rest = [t[:, 0] - t[:, 1:].sum(axis=1) for t in (off_t, on_t)]
    print("  tracker's thread, ms per frame (off / on): " + "  ".join(
        f"{k} {off_t[:, j].mean():.1f} / {on_t[:, j].mean():.1f}" for j, k in enumerate(columns) if j)
        + f"  untimed {rest[0].mean():.1f} / {rest[1].mean():.1f}")
    print("  gate, ms per frame: " + "  ".join(f"{k} {v / counted:.1f}" for k, v in stages.items()))


if __name__ == "__main__":
    main()
