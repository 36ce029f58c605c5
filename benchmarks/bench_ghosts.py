"""Benchmark: ghost points of dense maps, against the map of a clean run.

A ghost is a map point farther than 3 cm from every point of the reference map (the run of
the clean sequence; both runs start their world at the same first frame). Prints, for each
run folder, the share of ghost points and the points the map's cleaning steps removed
(from its stats.json). Issue 4's target on composites with the system's masks: <= 1 %.

    python benchmarks/bench_ghosts.py CLEAN_RUN RUN [RUN ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from osslam.mapping.metrics import fraction_farther


def _points(run: Path) -> np.ndarray:
    import open3d as o3d

    return np.asarray(o3d.io.read_point_cloud(str(run / "map.ply")).points)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("clean", type=Path, help="run folder of the clean sequence (with map.ply)")
    parser.add_argument("runs", type=Path, nargs="+", help="run folders to score")
    parser.add_argument("--threshold", type=float, default=0.03, help="metres")
    args = parser.parse_args()
    reference = _points(args.clean)
    print(f"reference {args.clean}: {len(reference)} points")
    for run in args.runs:
        points = _points(run)
        mapping = json.loads((run / "stats.json").read_text()).get("mapping", {})
        ghosts = fraction_farther(points, reference, args.threshold)
        print(f"{run}: {len(points)} points, ghosts {100 * ghosts:.2f} %; fused {mapping.get('points_fused')}, "
              f"removed by SOR {mapping.get('removed_sor')}, as residue {mapping.get('removed_residue')}")


if __name__ == "__main__":
    main()
