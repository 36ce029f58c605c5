"""Composite sequences in benchmark suites: parsed, labelled, built once, run with their ground truth and masks."""

import json
import threading
import time
from pathlib import Path

import pytest

from osslam.bench import composites
from osslam.bench.collect import collect_records
from osslam.bench.composites import COMPOSITES_DIR, ensure_composite
from osslam.bench.executors import LocalExecutor
from osslam.bench.jobs import DONE_FILE, plan_jobs, run_job
from osslam.bench.report import write_report
from osslam.bench.runner import prepare_composites, run_suite
from osslam.bench.suite import suite_from_dict
from osslam.config import ConfigError
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.errors import InputError

FR1 = "/data/rgbd_dataset_freiburg1_xyz"
FAST = ["mapping.enabled=false"]


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    """A 10-frame synthetic room written as a TUM folder (with ground truth)."""
    folder = tmp_path_factory.mktemp("seq") / "room"
    return SyntheticSequence(SyntheticConfig(n_frames=10, seed=1)).write_tum(folder)


def _suite(sequences, configs=None):
    return suite_from_dict({"name": "c", "sequences": sequences,
                            "configs": configs or [{"name": "plain", "preset": "synthetic", "set": FAST}]},
                           "suite.yaml", Path("/data"))


def test_composite_text_parses_and_labels():
    seqs = _suite([f"composite:base={FR1},seed=1", "composite: seed=2 , base=tum:fr1/xyz ,boxes=3,frames=40",
                   f"composite:base={FR1},seed=1,person=p.jpg,person_model=m.tflite"]).sequences
    assert [s.label for s in seqs] == ["fr1/xyz+synth-s1", "fr1/xyz+synth-s2-b3-f40", "fr1/xyz+synth-s1-person"]
    assert [s.key for s in seqs] == ["fr1_xyz+synth-s1", "fr1_xyz+synth-s2-b3-f40", "fr1_xyz+synth-s1-person"]
    first, second, third = (s.composite for s in seqs)
    assert first.base == second.base == Path(FR1)
    assert (second.seed, second.boxes, second.frames) == (2, 3, 40)
    assert (third.person, third.person_model) == (Path("p.jpg"), Path("m.tflite"))
    assert all(s.default_preset == "tum_fr1" and s.path is None for s in seqs)
    folder = seqs[0].folder(Path("/out"))
    assert folder.parent == Path("/out") / COMPOSITES_DIR and folder.name.startswith("fr1_xyz+synth-s1-")
    assert len({s.composite.digest for s in seqs}) == 3
    again = _suite([f"composite:seed=1,base={FR1}"]).sequences[0]
    assert again.folder(Path("/out")) == folder, "the same parameters share one composite"


@pytest.mark.parametrize("text, message", [
    ("composite:seed=1", "'base' .* is required"),
    (f"composite:base={FR1},speed=1", "expected key=value with keys base, seed"),
    (f"composite:base={FR1},seed", "expected key=value"),
    (f"composite:base={FR1},seed=one", "whole numbers"),
    (f"composite:base={FR1},frames=-1", "cannot be negative"),
    (f"composite:base={FR1},seed=1,seed=2", "'seed' given twice"),
    (f"composite:base={FR1},person=p.jpg", "'person' and 'person_model' go together"),
    ("composite:base=tum:fr9/nothing", "unknown TUM sequence"),
])
def test_bad_composite_text_names_the_file_and_entry(text, message):
    with pytest.raises(ConfigError, match=message) as info:
        _suite([text])
    assert str(info.value).startswith(f"suite.yaml: sequence '{text}': ")


def test_concurrent_builders_build_once(room, tmp_path, monkeypatch):
    """A second builder arriving during a build waits for it and reuses its folder."""
    calls = []
    real_build = composites._build

    def slow_build(spec, target, preset):
        calls.append(target)
        time.sleep(0.5)
        real_build(spec, target, preset)

    monkeypatch.setattr(composites, "_build", slow_build)
    seq = _suite([f"composite:base={room},seed=3,frames=4"]).sequences[0]
    folder = seq.folder(tmp_path)
    built = []
    threads = [threading.Thread(target=lambda: built.append(ensure_composite(seq.composite, folder, "synthetic")))
               for _ in range(2)]
    for t in threads:
        t.start()
        time.sleep(0.1)
    for t in threads:
        t.join()
    assert sorted(built) == [False, True] and len(calls) == 1
    assert calls[0].parent == folder.parent and calls[0] != folder, "built aside, then renamed into place"
    assert (folder / "masks.txt").is_file() and (folder / "groundtruth.txt").is_file()
    assert sorted(p.name for p in folder.parent.iterdir()) == [folder.name, f"{folder.name}.lock"], "no temporary left"
    assert not ensure_composite(seq.composite, folder, "synthetic") and len(calls) == 1


def test_failed_build_leaves_no_folder(tmp_path):
    seq = _suite([f"composite:base={tmp_path / 'missing'},seed=1"]).sequences[0]
    folder = seq.folder(tmp_path / "out")
    with pytest.raises(InputError, match="sequence folder not found"):
        ensure_composite(seq.composite, folder, None)
    assert not folder.exists() and not list(folder.parent.glob(".*tmp"))


def test_a_job_builds_its_composite_when_missing(room, tmp_path):
    suite = _suite([f"composite:base={room},seed=1,frames=6"])
    (job,) = plan_jobs(suite, tmp_path)
    result = run_job(job)
    assert result.status == "ok", result.error
    assert result.ape_rmse is not None, "the composite's ground truth was found"
    assert (job.sequence_dir / "masks.txt").is_file()
    masks = json.loads((job.out_dir / "eval" / "masks.json").read_text())
    assert masks["total"]["frames"] == 6, "the composite's masks were scored"


def test_suite_with_a_composite_builds_it_once_and_reports_it(room, tmp_path):
    configs = [{"name": "plain", "preset": "synthetic", "set": FAST},
               {"name": "motion", "preset": "synthetic", "set": FAST + ["gating.enabled=true", "detection.enabled=false"]}]
    suite = _suite([str(room), f"composite:base={room},seed=1,frames=8"], configs)
    built = []
    bench = run_suite(suite, tmp_path, LocalExecutor(workers=1), on_prepared=built.append)
    assert [b.label for b in built] == ["room+synth-s1-f8"] and not built[0].error and built[0].wall_s > 0
    folder = built[0].folder
    assert [p.name for p in (tmp_path / COMPOSITES_DIR).iterdir() if p.is_dir()] == [folder.name]
    stamp = (folder / "synth.yaml").stat().st_mtime_ns
    assert sorted(r.key for r in bench.results if r.status == "ok") == [
        "room+synth-s1-f8/motion/run0", "room+synth-s1-f8/plain/run0", "room/motion/run0", "room/plain/run0"]
    for config in ("plain", "motion"):
        run = tmp_path / "room+synth-s1-f8" / config / "run0"
        assert (run / DONE_FILE).is_file()
        assert json.loads((run / "eval" / "masks.json").read_text())["total"]["frames"] == 8
        assert not (run / "groundtruth.txt").exists(), "ground truth read from the composite, not written"
    records = collect_records(suite, tmp_path)
    assert {r.groundtruth for r in records if r.sequence == "room+synth-s1-f8"} == {folder / "groundtruth.txt"}
    report = write_report(suite, tmp_path, plots=False)
    ape = next(t for t in report.tables if t.name == "ape_rmse")
    assert [row[0] for row in ape.rows] == ["room", "room+synth-s1-f8"]
    assert all(cell.n == 1 for row in ape.rows for cell in row[1:])
    masks = next(t for t in report.tables if t.name == "masks")
    assert [row[:2] for row in masks.rows] == [["room+synth-s1-f8", "plain"], ["room+synth-s1-f8", "motion"]]
    plain = dict(zip(masks.header, masks.rows[0]))
    assert plain["mover keypoints removed"].mean == 0.0 and plain["pixel precision"] == "n/a", "no gating: nothing masked"
    assert "Dynamic masks" in report.report_path.read_text()
    again = []
    rerun = run_suite(suite, tmp_path, LocalExecutor(workers=1), on_prepared=again.append)
    assert again == [] and all(r.status == "skipped" for r in rerun.results)
    assert prepare_composites(plan_jobs(suite, tmp_path)) == []
    assert (folder / "synth.yaml").stat().st_mtime_ns == stamp
