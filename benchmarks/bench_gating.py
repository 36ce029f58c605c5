"""Benchmark: dynamic gating on `osslam synth` composites of a TUM sequence, and on the clean sequence.

For each composite seed (built once into --work) and for the clean sequence, runs SLAM with
gating off and on and prints APE, the mask scores against the composite's ground truth
(pixel precision/recall, mover keypoints removed, static keypoints removed, also counted
only off the movers' outlines and only 15+ px from movers) and the per-stage segmentation cost (flow, detection, motion,
fusion, the tracker's wait for the worker thread, and the gate's finish on the tracker's thread:
the check of the predicted segmentation, and the segmentation redone where it failed), the
tracker's own stages (features, tracking, back-end) and what else ran on its thread: with gating
on, mostly that finish and ``masked``, the pose refined without the masked observations and the
landmarks retired under the mask. Targets (issue 3): APE with gating
at most 1.25 x the clean run, mover keypoint recall >= 0.9, under 5 % of static keypoints
removed, segmentation <= 30 ms per frame, the tracker's own time raised by at most 5 ms, clean
APE within 5 % of gating off. For each
composite it also prints what the ground-truth masks themselves, grown by 1, 2 and 5 px,
would remove of the static keypoints: FAST corners cluster on the movers' outlines, so a
mask one pixel wider than the truth already removes a share of them. With --oracle, each
composite is also run with gating off and its ground-truth masks, grown by
``fusion.dilation``, given as the mask: the APE perfect gating would reach.

    OSSLAM_MODELS=../shared/models python benchmarks/bench_gating.py --seeds 1 2 --work /tmp/gating
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from osslam.bench.composites import CompositeSpec, ensure_composite
from osslam.config import load_config
from osslam.datasets import open_sequence
from osslam.eval.masks import MaskCounts, mask_counts
from osslam.frontend.features import FeatureExtractor
from osslam.imaging import grow
from osslam.pipeline import run_sequence

SHARED = Path(__file__).resolve().parents[2] / "shared"
DEFAULT_SEQUENCE = SHARED / "data" / "tum" / "rgbd_dataset_freiburg1_xyz"
PERSON = SHARED / "models" / "samples" / "person.jpg"
SELFIE = SHARED / "models" / "mediapipe-selfie-segmentation" / "selfie_segmentation.tflite"
EDGE_RADII = (1, 2, 5)  # pixels by which the ground-truth masks are grown for the edge reference
EDGE_STEP = 8  # every EDGE_STEP-th frame of a composite is scored for that reference
STAGES = ("segmentation", "flow", "detection", "motion", "fusion", "wait", "finish", "features", "tracking", "masked",
          "backend", "total")
TRACKER_STAGES = ("features", "tracking", "keyframe", "backend", "mapping")  # the tracker's own work on its thread


def _composite(sequence: Path, seed: int, work: Path) -> Path:
    """The composite of ``sequence`` with movers of ``seed`` (and the person when its files are here), built once."""
    person = PERSON.is_file() and SELFIE.is_file()
    spec = CompositeSpec(sequence, seed, person=PERSON if person else None, person_model=SELFIE if person else None)
    out = work / f"composite-{spec.suffix}-{spec.digest}"
    ensure_composite(spec, out, "tum_fr1")
    return out


def _run(label: str, sequence: Path, gating: bool, overrides: list[str], out: Path, oracle: bool = False) -> None:
    """One run, printed; ``oracle`` gives the tracker each frame's ground-truth mask grown by ``fusion.dilation``."""
    cfg = load_config("tum_fr1", [f"gating.enabled={str(gating).lower()}", "mapping.enabled=false", *overrides])
    seq = open_sequence(sequence, cfg)
    def truth(frame):
        return None if frame.gt_mask is None else grow(frame.gt_mask, cfg.fusion.dilation)

    ignore = truth if oracle else None
    s = run_sequence(seq, cfg, out, groundtruth=seq.groundtruth_path, progress=False, ignore=ignore).stats
    mode = "oracle" if oracle else ("gating on " if gating else "gating off")
    print(f"{label:18s} {mode:10s}  APE {s.get('ape_rmse', float('nan')):.4f} m  "
          f"tracked {s['frames_tracked']}/{s['frames_in']}  lost events {s['lost_events']}")
    if "masks" in s:
        print("    masks: " + "  ".join(f"{k} {v:.3f}" for k, v in s["masks"].items() if isinstance(v, float)))
    t = s["timings_ms"]
    print("    ms per frame (mean / p95): " + "  ".join(
        f"{k} {t[k]['per_frame']:.1f}/{t[k]['p95']:.1f}" for k in STAGES if k in t))
    own = sum(t[k]["per_frame"] for k in TRACKER_STAGES if k in t)
    print(f"    tracker's thread, ms per frame: its own stages {own:.1f}, "
          f"anything else {t['total']['per_frame'] - own:.1f}")


def _edge_reference(sequence: Path) -> str:
    """Static keypoints removed by the ground-truth masks grown by each of ``EDGE_RADII`` pixels."""
    cfg = load_config("tum_fr1")
    seq = open_sequence(sequence, cfg)
    extractor = FeatureExtractor(cfg.features, cfg.camera, seq.intrinsics)
    totals = {r: MaskCounts() for r in EDGE_RADII}
    for i in range(0, len(seq), EDGE_STEP):
        frame = seq[i]
        keypoints = extractor.extract(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), frame.depth).pixels
        for r in EDGE_RADII:
            totals[r] += mask_counts(grow(frame.gt_mask, r), frame.gt_mask, keypoints)
    return "  ".join(f"{r} px {totals[r].scores()['static_keypoints_removed']:.3f}" for r in EDGE_RADII)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", type=Path, nargs="?", default=DEFAULT_SEQUENCE)
    parser.add_argument("--seeds", type=int, nargs="*", default=[1, 2])
    parser.add_argument("--work", type=Path, required=True, help="folder for the composites and run outputs")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--skip-off", action="store_true", help="only the gated runs")
    parser.add_argument("--oracle", action="store_true",
                        help="also run each composite with its ground-truth masks (grown by fusion.dilation)")
    args = parser.parse_args()

    runs = [("clean", args.sequence)] + [(f"composite s{s}", _composite(args.sequence, s, args.work))
                                          for s in args.seeds]
    for label, sequence in runs:
        if label != "clean":
            print(f"{label:18s} static keypoints removed by the ground truth grown by {_edge_reference(sequence)}")
        for gating in ([True] if args.skip_off else [False, True]):
            _run(label, sequence, gating, args.overrides, args.work / "runs" / f"{label.replace(' ', '_')}-{gating}")
        if args.oracle and label != "clean":
            _run(label, sequence, False, args.overrides, args.work / "runs" / f"{label.replace(' ', '_')}-oracle",
                 oracle=True)


if __name__ == "__main__":
    main()
