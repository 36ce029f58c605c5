"""End to end on the real TUM fr1/xyz sequence from ../shared (skips only when it is absent)."""

import json


def test_fr1_xyz_tracks_every_frame_within_15mm(fr1_xyz_run):
    out = fr1_xyz_run.out
    assert fr1_xyz_run.code == 0
    assert "ATE" in fr1_xyz_run.printed
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
