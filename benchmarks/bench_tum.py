"""Benchmark: accuracy and per-frame cost of `osslam run` on a TUM sequence, run twice.

Prints APE/RPE, per-stage timings (mean / median / p95 ms), peak memory, the dense map's
cost and cleaning counts, and whether the two runs gave
identical trajectories (determinism). Targets for fr1/xyz: APE RMSE <= 0.015 m and a mean
of at most 60 ms per frame on a 2-core CPU.

    python benchmarks/bench_tum.py ../shared/data/tum/rgbd_dataset_freiburg1_xyz --runs 2
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from osslam.config import load_config
from osslam.datasets import open_sequence
from osslam.pipeline import run_sequence

DEFAULT_SEQUENCE = Path(__file__).resolve().parents[2] / "shared" / "data" / "tum" / "rgbd_dataset_freiburg1_xyz"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence", type=Path, nargs="?", default=DEFAULT_SEQUENCE)
    parser.add_argument("--config", default="tum_fr1")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--out", type=Path, help="keep results here (default: a temporary folder)")
    args = parser.parse_args()

    cfg = load_config(args.config, args.overrides)
    trajectories = []
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        for run in range(args.runs):
            seq = open_sequence(args.sequence, cfg)
            summary = run_sequence(seq, cfg, root / f"run{run}", groundtruth=seq.groundtruth_path, progress=False)
            trajectories.append((root / f"run{run}" / "trajectory.txt").read_text())
            s, m = summary.stats, summary.metrics
            print(f"run {run}: {seq.name}: {s['frames_in']} frames, {s['frames_tracked']} tracked, "
                  f"{s['lost_events']} lost events, {s['keyframes']} keyframes, {s['landmarks']} landmarks")
            if m is not None:
                for key, unit in (("ape", "m"), ("rpe_trans", "m"), ("rpe_rot", "deg")):
                    st = m[key]
                    print(f"  {key:10s} rmse {st['rmse']:.4f} {unit}  mean {st['mean']:.4f}  median {st['median']:.4f}"
                          f"  max {st['max']:.4f}")
            print(f"  {'stage':10s} {'count':>6s} {'mean':>8s} {'median':>8s} {'p95':>8s} {'per frame':>10s}  (ms)")
            for stage, t in s["timings_ms"].items():
                print(f"  {stage:10s} {t['count']:6d} {t['mean']:8.2f} {t['median']:8.2f} {t['p95']:8.2f}"
                      f" {t['per_frame']:10.2f}")
            print(f"  peak memory {s['peak_rss_mb']:.0f} MB")
            if "mapping" in s:
                mp = s["mapping"]
                print(f"  map: {mp['ms_per_view']:.2f} ms per map view, {mp['points_fused']} points fused, "
                      f"{mp['removed_free_space']} removed as seen through, {mp['removed_sor']} by SOR, "
                      f"{mp['removed_residue']} as residue, {mp['points_final']} "
                      f"kept; store {mp['store_mb']:.1f} MB; save {mp['save_s']:.2f} s")
    if len(trajectories) > 1:
        same = all(t == trajectories[0] for t in trajectories[1:])
        print(f"deterministic: {'yes, identical trajectories' if same else 'NO, trajectories differ'}")


if __name__ == "__main__":
    main()
