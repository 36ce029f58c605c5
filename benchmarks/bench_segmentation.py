"""Benchmark: the dynamic gate's own cost per frame, stage by stage, without a tracker beside it.

Inside SLAM the gate's worker thread shares the interpreter with the tracker, so its stage
timings there include waits for the other thread. Here the gate runs alone, one frame after
the other, on the configured threads, and its stages (detection, flow, motion, fusion) are
timed as in SLAM. The camera's ego-motion comes either from the ground truth, as tracking
gives it when anchored on mature landmarks, or is fitted to the flow, as when it is not
(``--ego`` both prints both; frames without ground truth are fitted either way). With
``--trajectory RUN_DIR/trajectory.txt`` the given ego-motion and poses come from an
``osslam run`` of the same sequence instead, as tracking gave them. The two leave different
amounts of static scene moving, and motion segmentation and fusion take longer the more
there is: on composites 1-8 on 2026-12-04 tracked poses masked 15.7 % of the static
keypoints more than 15 px from any mover against 5.7 % with the ground truth's (about 1.5 ms
a frame more); by 2026-12-06, with the gate refining the given ego-motion on the flow, the
order had turned (composite 1: 2.9 % tracked against 3.8 % with the ground truth's). Issue 3's
target: segmentation <= 30 ms per frame.

Machines of one kind differ in speed by a factor of two or more, and one machine's speed drifts
within a run, so the benchmark times a fixed reference job on the sequence's first two frames,
whatever the config (OpenCV's DIS flow, preset medium, at 320 x 240 on one thread), before
the run and every ``REFERENCE_EVERY`` frames during it, between frames. Figures from two
machines, or from one machine at two times, compare after dividing by the reference times
measured during their runs: the line under the table gives the mean segmentation cost over
their mean (a mean over the run, as the cost is, which follows a machine that switches between
speeds during the run). The stage timings are wall-clock, as SLAM sees them;
"cpu" is the CPU time of the gate's threads together over each frame's start and finish, so
that what the stages leave uncounted shows as the difference; "finish" is the part that ran on
the caller's thread (in SLAM, the tracker's): the check of the segmentation made with the
predicted ego-motion, and the segmentation redone where the given ego-motion did not confirm
it, counted in the stages as well. Under the table: in how many frames that segmentation stood.

    python benchmarks/bench_segmentation.py COMPOSITE_DIR [--frames N] [--ego tracked|fitted|both]
        [--trajectory RUN_DIR/trajectory.txt] [--set k=v ...]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from osslam.config import load_config
from osslam.datasets import open_sequence
from osslam.datasets.association import associate
from osslam.errors import InputError
from osslam.frontend.gating import STAGES, DynamicGate
from osslam.geometry import invert
from osslam.timing import StageTimer
from osslam.trajectory_io import read_tum

REFERENCE_SIZE = (320, 240)
REFERENCE_REPEATS = 30  # timings of the reference job before the run
REFERENCE_EVERY = 10  # frames between timings of the reference job during the run ...
REFERENCE_DURING = 3  # ... of this many repeats each


class ReferenceJob:
    """The machine's reference job: DIS medium between a sequence's first two frames at 320 x 240, one thread."""

    def __init__(self, sequence):
        self._images = [cv2.resize(cv2.cvtColor(sequence[i].rgb, cv2.COLOR_RGB2GRAY), REFERENCE_SIZE,
                                   interpolation=cv2.INTER_AREA) for i in (0, 1)]
        self._dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)

    def time_ms(self, repeats: int) -> list[float]:
        """Milliseconds of each of ``repeats`` runs of the job."""
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            self._dis.calc(*self._images, None)
            times.append((time.perf_counter() - t0) * 1e3)
        cv2.setNumThreads(threads)
        return times


def _run_poses(path: Path, sequence) -> list[np.ndarray | None]:
    """Each frame's pose in an ``osslam run`` trajectory file, None for frames it lacks."""
    try:
        run = read_tum(path)
    except InputError as exc:
        raise SystemExit(str(exc)) from None
    poses: list[np.ndarray | None] = [None] * len(sequence)
    matrices = run.poses
    for i, j in associate(sequence.timestamps, run.timestamps, 1e-4):
        poses[i] = matrices[j]
    if not any(p is not None for p in poses):
        raise SystemExit(f"{path}: no pose matches a frame of {sequence.name}")
    return poses


def _time_gate(sequence, cfg, given: bool, frames: int, run: list[np.ndarray | None] | None,
               reference: ReferenceJob) -> tuple[dict, int, list[float]]:
    """Stage timings of the gate over the first ``frames`` frames, ego-motion given or fitted.

    Poses (and the given ego-motion) are the ground truth's, or those of ``run`` when it is there.
    Also returns in how many frames the segmentation with the predicted ego-motion stood, and
    the reference job's timings between frames.
    """
    cv2.setNumThreads(cfg.run.threads)
    gate = DynamicGate(cfg, sequence.intrinsics)
    timer = StageTimer()
    kept = 0
    previous = None
    reference_ms: list[float] = []
    try:
        for i in range(frames):
            if i % REFERENCE_EVERY == 0:
                reference_ms += reference.time_ms(REFERENCE_DURING)
            frame = sequence[i]
            gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
            pose = frame.gt_pose if run is None else run[i]
            known = given and previous is not None and pose is not None
            ego = invert(previous) @ pose if known else None
            cpu = time.process_time()
            gate.start(frame.rgb, gray, frame.depth)
            result = gate.finish(ego, None, pose)
            cpu = (time.process_time() - cpu) * 1e3
            previous = pose
            if i > 0:  # the first frame has no flow
                timer.add({**{k: v for k, v in result.timings_ms.items() if k in (*STAGES, "finish")},
                           "segmentation": result.cost_ms, "cpu": cpu})
                kept += result.predicted
    finally:
        gate.close()
    return timer.summary(), kept, reference_ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", type=Path, help="a TUM folder with ground truth (an `osslam synth` composite)")
    parser.add_argument("--frames", type=int, default=0, help="frames to run (0: all)")
    parser.add_argument("--ego", choices=("tracked", "fitted", "both"), default="both")
    parser.add_argument("--trajectory", type=Path, help="poses of this `osslam run` instead of the ground truth's")
    parser.add_argument("--config", default="tum_fr1")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()
    cfg = load_config(args.config, ["gating.enabled=true", *args.overrides])
    sequence = open_sequence(args.sequence, cfg)
    frames = len(sequence) if args.frames <= 0 else min(args.frames, len(sequence))
    modes = ("tracked", "fitted") if args.ego == "both" else (args.ego,)
    if frames < 2:
        raise SystemExit(f"{args.sequence}: the benchmark needs at least 2 frames, {frames} chosen")
    run = None if args.trajectory is None else _run_poses(args.trajectory, sequence)
    print(f"{args.sequence}: {frames} frames, OpenCV threads {cfg.run.threads}")
    if run is not None:
        print(f"  poses and given ego-motion from {args.trajectory}")
    reference = ReferenceJob(sequence)
    print(f"  machine reference (DIS medium, 320 x 240, 1 thread): "
          f"{np.median(reference.time_ms(REFERENCE_REPEATS)):.1f} ms before the run")
    columns = (*STAGES, "segmentation", "cpu", "finish")
    print(f"  {'ego-motion':10s} " + " ".join(f"{s:>22s}" for s in columns))
    print(f"  {'':10s} " + " ".join(f"{'mean / median / p95':>22s}" for _ in columns))
    for mode in modes:
        summary, kept, reference_ms = _time_gate(sequence, cfg, mode == "tracked", frames, run, reference)
        cells = []
        for stage in columns:
            t = summary.get(stage)
            cells.append("n/a" if t is None else f"{t['mean']:.1f} / {t['median']:.1f} / {t['p95']:.1f}")
        print(f"  {mode:10s} " + " ".join(f"{c:>22s}" for c in cells))
        print(f"  {'':10s} the segmentation with the predicted ego-motion stood in {kept} of {frames - 1} frames")
        during = float(np.mean(reference_ms))
        print(f"  {'':10s} reference during the run: mean {during:.1f} ms (p10 {np.percentile(reference_ms, 10):.1f}, "
              f"p90 {np.percentile(reference_ms, 90):.1f}); mean segmentation / mean reference: "
              f"{summary['segmentation']['mean'] / during:.2f}")


if __name__ == "__main__":
    main()
