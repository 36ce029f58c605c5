"""Benchmark suites: the same tables under the local and Ray executors, resumption, failures, reports."""

import json
from pathlib import Path

import pytest

from osslam.bench.executors import LocalExecutor, RayExecutor
from osslam.bench.jobs import DONE_FILE, ERROR_FILE, JOB_FILE, is_finished, plan_jobs
from osslam.bench.render import to_csv, to_latex, to_markdown
from osslam.bench.report import write_report
from osslam.bench.runner import run_suite
from osslam.bench.suite import Suite, load_suite, suite_from_dict, with_overrides
from osslam.bench.tables import Stat, Table
from osslam.cli import main
from osslam.config import ConfigError

SUITE = {
    "name": "tiny",
    "sequences": ["synthetic:seed=0,frames=30", "synthetic:seed=1,frames=30", "no/such/sequence_folder"],
    "configs": [{"name": "default"}, {"name": "orb500", "set": ["features.n_features=500"]}],
}
ACCURACY_TABLES = ("ape_rmse", "rpe_trans_rmse", "ape_statistics", "rpe_trans_statistics", "failures")


def _suite() -> Suite:
    return suite_from_dict(SUITE, "test suite")


def _run(out: Path, executor) -> tuple:
    seen = []
    bench = run_suite(_suite(), out, executor, seen.append)
    report = write_report(_suite(), out, plots=executor.name == "local")
    return bench, report, seen


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    return (out, *_run(out, LocalExecutor(workers=2)))


def test_local_suite_runs_every_job_and_reports_failures(local_run):
    out, bench, report, seen = local_run
    assert len(seen) == len(bench.results) == 6
    failed = {r.key for r in bench.failed}
    assert failed == {"sequence_folder/default/run0", "sequence_folder/orb500/run0"}
    for r in bench.results:
        if r.status == "ok":
            assert r.ape_rmse is not None and r.ape_rmse < 0.05
            assert r.wall_s > 0 and r.peak_memory_mb > 50 and 0 < r.cpu_utilisation < 4
    job_dir = out / "synth-s0-f30" / "orb500" / "run0"
    for name in ("trajectory.txt", "keyframes.txt", "stats.json", "config.yaml", "eval/metrics.json", DONE_FILE):
        assert (job_dir / name).is_file(), name
    assert "n_features: 500" in (job_dir / "config.yaml").read_text()
    bad = out / "sequence_folder" / "default" / "run0"
    assert "sequence folder not found" in (bad / ERROR_FILE).read_text()
    assert not (bad / DONE_FILE).exists()
    text = report.report_path.read_text()
    assert "Failed and missing runs" in text and "sequence folder not found" in text
    ape = next(t for t in report.tables if t.name == "ape_rmse")
    assert [row[0] for row in ape.rows] == ["synth-s0-f30", "synth-s1-f30", "sequence_folder"]
    assert ape.rows[2][1:] == ["failed", "failed"]
    assert all(isinstance(c, Stat) and c.n == 1 for row in ape.rows[:2] for c in row[1:])
    for name in ("ape_rmse.png", "rpe_trans_rmse.png", "trajectories.png"):
        assert (report.report_path.parent / name).stat().st_size > 5000
    for suffix in (".md", ".csv", ".tex"):
        assert (report.report_path.parent / "tables" / f"cost{suffix}").is_file()


def test_ray_executor_gives_the_same_tables(local_run, tmp_path):
    ray = pytest.importorskip("ray", reason="the ray extra is not installed (pip install 'osslam[ray]')")
    out, _, local_report, _ = local_run
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        bench, report, seen = _run(tmp_path, RayExecutor())
    finally:
        ray.shutdown()
    assert len(seen) == 6 and len(bench.failed) == 2
    assert all(r.status != "skipped" for r in seen)
    for name in ACCURACY_TABLES:
        ours = (tmp_path / "report" / "tables" / f"{name}.md").read_text()
        assert ours == (out / "report" / "tables" / f"{name}.md").read_text(), name
    cost = (tmp_path / "report" / "tables" / "cost.md").read_text()
    assert "synth-s1-f30 | orb500 | 30 |" in cost


class _Recorder:
    """An executor that records what it is given and runs nothing."""

    name = "recorder"

    def __init__(self):
        self.jobs = []

    def run(self, jobs, on_result):
        self.jobs = list(jobs)
        return []


def test_rerun_skips_finished_jobs_and_retries_failed_ones(local_run):
    out = local_run[0]
    recorder = _Recorder()
    bench = run_suite(_suite(), out, recorder)
    assert sorted(j.key for j in recorder.jobs) == ["sequence_folder/default/run0", "sequence_folder/orb500/run0"]
    skipped = [r for r in bench.results if r.status == "skipped"]
    assert len(skipped) == 4 and all(r.ape_rmse is not None for r in skipped)
    changed = with_overrides(_suite(), ["tracking.min_inliers=12"])
    assert not any(is_finished(j) for j in plan_jobs(changed, out)), "a changed config runs again"
    assert all(is_finished(j) or "sequence_folder" in j.key for j in plan_jobs(_suite(), out))


def test_external_estimates_become_a_column(local_run, tmp_path):
    out = local_run[0]
    folder = tmp_path / "orbslam3"
    folder.mkdir()
    (folder / "synth-s0-f30.txt").write_text((out / "synth-s0-f30" / "default" / "run0" / "groundtruth.txt").read_text())
    suite = with_overrides(_suite(), [], external=[("ORB-SLAM3", folder)])
    report = write_report(suite, out, tmp_path / "report", plots=False)
    ape = next(t for t in report.tables if t.name == "ape_rmse")
    assert ape.header == ["sequence", "default", "orb500", "ORB-SLAM3"]
    assert ape.rows[0][3].mean < 1e-6
    assert ape.rows[1][3] == "-"
    failures = (tmp_path / "report" / "tables" / "failures.md").read_text()
    assert "ORB-SLAM3" in failures and "no estimate file" in failures


def test_cli_bench_skips_finished_jobs_and_exits_1_on_failures(local_run, tmp_path, capsys):
    out = local_run[0]
    suite_file = tmp_path / "suite.yaml"
    suite_file.write_text(json.dumps({**SUITE, "sequences": SUITE["sequences"][:2]}))
    assert main(["bench", "--suite", str(suite_file), "--out", str(out), "--no-plots"]) == 0
    printed = capsys.readouterr().out
    assert printed.count(": skipped") == 4 and "report:" in printed
    assert main(["bench", "no/such/folder", "--out", str(tmp_path / "b"), "--no-plots", "--workers", "1"]) == 1
    captured = capsys.readouterr()
    assert "[1/1] folder/default/run0: failed  InputError" in captured.out
    assert "1 job(s) failed" in captured.err
    assert json.loads((tmp_path / "b" / "folder" / "default" / "run0" / JOB_FILE).read_text())["status"] == "failed"


def test_suite_files_are_checked():
    with pytest.raises(ConfigError, match="unknown key"):
        suite_from_dict({**SUITE, "sequence": []}, "s")
    with pytest.raises(ConfigError, match="used twice"):
        suite_from_dict({**SUITE, "configs": ["synthetic", "synthetic"]}, "s")
    with pytest.raises(ConfigError, match="expected key=value"):
        suite_from_dict({"sequences": ["synthetic:speed=3"]}, "s")
    here = load_suite("data_here")
    assert [s.label for s in here.sequences] == ["fr1/xyz"] + [f"fr1/xyz+synth-s{k}-person" for k in (1, 2, 3, 4)]
    assert all(s.default_preset == "tum_fr1" for s in here.sequences)
    assert [c.name for c in here.configs] == ["no_gating", "detection_only", "motion_only", "fused"]
    paper = load_suite("tum_paper", Path("/data"))
    assert paper.sequences[0].path == Path("/data/rgbd_dataset_freiburg3_walking_xyz")
    assert len(paper.sequences) == 6


def test_renderers_show_mean_and_std():
    table = Table("t_1", "A & B", ["sequence", "cfg_a"], [["fr1/x_y", Stat(0.5, 0.25, 3)], ["b", Stat(1.0, 0.0, 1)]])
    assert "| fr1/x_y | 0.5000 ± 0.2500 |" in to_markdown(table)
    assert to_csv(table).splitlines() == ["sequence,cfg_a,cfg_a std", "fr1/x_y,0.5,0.25", "b,1.0,"]
    latex = to_latex(table)
    assert r"fr1/x\_y & 0.5000 $\pm$ 0.2500 \\" in latex and r"\caption{A \& B}" in latex
    assert r"\begin{tabular}{lr}" in latex
