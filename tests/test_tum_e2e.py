"""End to end on the real TUM fr1/xyz sequence from ../shared (skips only when it is absent)."""

import json
from pathlib import Path

import pytest

from osslam.cli import main

FR1_XYZ = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "tum" / "rgbd_dataset_freiburg1_xyz"

pytestmark = pytest.mark.skipif(not (FR1_XYZ / "rgb.txt").is_file(), reason=f"{FR1_XYZ} not present")


def test_fr1_xyz_tracks_every_frame_within_15mm(tmp_path, capsys):
    out = tmp_path / "fr1_xyz"
    assert main(["run", str(FR1_XYZ), "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "ATE" in printed
    stats = json.loads((out / "stats.json").read_text())
    # 798 colour and 798 depth images; TUM's one-to-one association within 0.02 s pairs 792
    assert stats["frames_in"] == 792
    assert stats["frames_tracked"] == 792
    assert stats["lost_events"] == 0
    metrics = json.loads((out / "eval" / "metrics.json").read_text())
    assert metrics["ape"]["rmse"] <= 0.015
    assert metrics["rpe_trans"]["rmse"] <= 0.01
    for png in ("trajectory_xy.png", "trajectory_xz.png", "ape_over_time.png"):
        assert (out / "eval" / png).stat().st_size > 1000
    rows = [l for l in (out / "trajectory.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert len(rows) == 792
