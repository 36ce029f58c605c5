"""Command line: ``osslam run | eval | demo | synth | models | download | bench | flow``. Thin: parse, call, print."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from osslam.errors import OsslamError


def _config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", "-c", metavar="NAME|PATH", help="preset name (see --list-configs) or YAML file")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one config entry (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="osslam", description="OS-SLAM: dynamic-scene RGB-D SLAM")
    parser.add_argument("--verbose", "-v", action="store_true",
                        help="log progress details; show the traceback of an error")
    parser.add_argument("--list-configs", action="store_true", help="list the built-in config presets")
    sub = parser.add_subparsers(dest="command")

    run = sub.add_parser("run", help="run SLAM over a TUM RGB-D sequence folder")
    run.add_argument("sequence", type=Path, help="TUM sequence folder (with rgb.txt, depth.txt)")
    run.add_argument("--out", "-o", type=Path, required=True, help="output folder")
    _config_args(run)

    ev = sub.add_parser("eval", help="evaluate a trajectory against ground truth (APE, RPE, plots)")
    ev.add_argument("groundtruth", type=Path, help="ground truth, TUM format")
    ev.add_argument("estimate", type=Path, help="estimated trajectory, TUM format")
    ev.add_argument("--out", "-o", type=Path, required=True, help="output folder")
    ev.add_argument("--config", "-c", metavar="NAME|PATH")
    ev.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")

    demo = sub.add_parser("demo", help="run a built-in synthetic sequence end to end and print the ATE")
    demo.add_argument("--out", "-o", type=Path, default=Path("osslam-demo"), help="output folder")
    demo.add_argument("--frames", type=int, default=150, help="number of synthetic frames")
    demo.add_argument("--seed", type=int, default=0, help="seed of the synthetic scene")
    _config_args(demo)

    synth = sub.add_parser("synth", help="composite synthetic movers into a TUM sequence, with ground-truth masks")
    synth.add_argument("sequence", type=Path, help="TUM sequence folder with groundtruth.txt")
    synth.add_argument("out", type=Path, help="output folder (a TUM sequence plus masks/ and masks.txt)")
    synth.add_argument("--seed", type=int, default=0, help="seed of the movers")
    synth.add_argument("--boxes", type=int, default=2, help="number of textured boxes")
    synth.add_argument("--person-image", type=Path, help="photo of a person to cut out and move through the scene")
    synth.add_argument("--person-model", type=Path, help="MediaPipe selfie segmentation .tflite for the cut-out")
    synth.add_argument("--frames", type=int, default=0, help="only the first N frames (default: all)")
    synth.add_argument("--overwrite", action="store_true", help="replace an earlier composite in the output folder")
    synth.add_argument("--no-progress", action="store_true", help="no progress bar")
    synth.add_argument("--config", "-c", metavar="NAME|PATH")
    synth.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")

    models = sub.add_parser("models", help="list, download or verify the pretrained model files")
    models.add_argument("action", choices=["list", "download", "verify"])
    models.add_argument("names", nargs="*", metavar="NAME", help="models (default: all)")
    models.add_argument("--dir", type=Path, help="cache folder (default: models.dir, $OSSLAM_MODELS, ~/.cache)")
    models.add_argument("--mirror", metavar="URL", help="base address instead of the upstream ones")
    models.add_argument("--config", "-c", metavar="NAME|PATH")
    models.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")

    dl = sub.add_parser("download", help="download datasets by name (TUM RGB-D sequences)")
    dl.add_argument("dataset", choices=["tum"], help="dataset")
    dl.add_argument("names", nargs="*", metavar="NAME", help="sequences, e.g. fr1/xyz fr3/walking_xyz")
    dl.add_argument("--to", type=Path, default=Path("data/tum"), help="target folder (default: data/tum)")
    dl.add_argument("--list", action="store_true", help="list the catalogue")
    dl.add_argument("--mirror", metavar="URL", help="base address instead of the upstream one")
    dl.add_argument("--keep-archive", action="store_true", help="keep the .tgz after extraction")

    bench = sub.add_parser("bench", help="run a suite of sequences x configs x repeats and write report tables")
    bench.add_argument("sequences", nargs="*", metavar="SEQUENCE",
                       help="sequence folders, tum:fr1/xyz, synthetic:seed=S,frames=N or composite:base=FOLDER,seed=S "
                            "(instead of or besides --suite)")
    bench.add_argument("--suite", "-s", metavar="NAME|PATH", help="suite YAML file or built-in suite name")
    bench.add_argument("--out", "-o", type=Path, required=False, help="output folder (one subfolder per job)")
    bench.add_argument("--config", "-c", dest="configs", action="append", default=[], metavar="NAME|PATH",
                       help="config preset or YAML file to compare (repeatable; replaces the suite's)")
    bench.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                       help="override applied to every config (repeatable)")
    bench.add_argument("--repeats", type=int, help="runs per sequence and config (seed + k)")
    bench.add_argument("--external", action="append", default=[], metavar="NAME=FOLDER",
                       help="folder of TUM trajectories from another system, one column NAME (repeatable)")
    bench.add_argument("--data", type=Path, help="folder of downloaded TUM sequences for tum:NAME entries")
    bench.add_argument("--executor", choices=["local", "ray"], default="local", help="where jobs run (default: local)")
    bench.add_argument("--workers", type=int, help="parallel jobs (default: one per CPU)")
    bench.add_argument("--address", help="Ray cluster address (default: start a local Ray)")
    bench.add_argument("--rerun", action="store_true", help="run finished jobs again")
    bench.add_argument("--report-only", action="store_true", help="write the report from existing results")
    bench.add_argument("--report-dir", type=Path, help="report folder (default: OUT/report)")
    bench.add_argument("--no-plots", action="store_true", help="tables only")
    bench.add_argument("--list-suites", action="store_true", help="list the built-in suites")

    from osslam import flow_cli

    flow_cli.register(sub)
    return parser


def _preset_for(sequence: Path, explicit: str | None) -> str | None:
    """The preset a run uses: the explicit one, else tum_fr1/2/3 for the sensor the folder name names."""
    from osslam.datasets.intrinsics import sensor_from_name

    if explicit:
        return explicit
    sensor = sensor_from_name(sequence.resolve().name)
    return f"tum_fr{sensor[-1]}" if sensor else None


def _print_summary(summary) -> None:
    stats = summary.stats
    total = stats["timings_ms"].get("total", {})
    print(f"frames: {stats['frames_in']} in, {stats['frames_tracked']} tracked, {stats['lost_events']} lost events; "
          f"keyframes: {stats['keyframes']}; landmarks: {stats['landmarks']}")
    print(f"time per frame: mean {total.get('mean', 0):.1f} ms, p95 {total.get('p95', 0):.1f} ms")
    if summary.ape_rmse is not None:
        rpe = summary.metrics["rpe_trans"]["rmse"]
        print(f"ATE (APE RMSE): {summary.ape_rmse:.4f} m   RPE trans RMSE: {rpe:.4f} m/frame")
    print(f"results: {summary.out_dir}")


def _cmd_run(args) -> int:
    from osslam.config import load_config
    from osslam.datasets import open_sequence
    from osslam.pipeline import run_sequence

    cfg = load_config(_preset_for(args.sequence, args.config), args.overrides)
    seq = open_sequence(args.sequence, cfg)
    summary = run_sequence(seq, cfg, args.out, groundtruth=seq.groundtruth_path,
                           progress=False if args.no_progress else None)
    _print_summary(summary)
    return 0


def _cmd_eval(args) -> int:
    from osslam.config import load_config
    from osslam.eval.report import evaluate_files

    cfg = load_config(args.config, args.overrides)
    report = evaluate_files(args.groundtruth, args.estimate, args.out, cfg.eval)
    for key in ("ape", "rpe_trans", "rpe_rot"):
        s = report.metrics[key]
        print(f"{key:10s} rmse {s['rmse']:.4f}  mean {s['mean']:.4f}  median {s['median']:.4f}  max {s['max']:.4f}")
    print(f"results: {args.out}")
    return 0


def _cmd_demo(args) -> int:
    from osslam.config import load_config
    from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
    from osslam.pipeline import run_sequence

    cfg = load_config(args.config or "synthetic", args.overrides)
    seq = SyntheticSequence(SyntheticConfig(n_frames=args.frames, seed=args.seed))
    summary = run_sequence(seq, cfg, args.out, progress=False if args.no_progress else None)
    _print_summary(summary)
    return 0


def _cmd_synth(args) -> int:
    from osslam.config import load_config
    from osslam.datasets import open_sequence
    from osslam.datasets.composite import CompositeConfig, person_cutout, write_composite

    if (args.person_image is None) != (args.person_model is None):
        raise ValueError("--person-image and --person-model go together")
    cfg = load_config(_preset_for(args.sequence, args.config), args.overrides)
    seq = open_sequence(args.sequence, cfg)
    person = person_cutout(args.person_image, args.person_model) if args.person_image else None
    out = write_composite(seq, args.out, CompositeConfig(seed=args.seed, n_boxes=args.boxes, max_frames=args.frames),
                          person, args.overwrite, progress=False if args.no_progress else None)
    print(f"composite written to {out} (masks in {out / 'masks'})")
    return 0


def _cmd_models(args) -> int:
    from osslam import models
    from osslam.config import load_config

    folder = args.dir or models.models_dir(load_config(args.config, args.overrides).models.dir)
    chosen = models.select(args.names)
    bad = 0
    for model in chosen:
        if args.action == "download":
            files = models.fetch(model, folder, args.mirror, on_progress=_download_progress(model.name))
        else:
            files = models.status(model, folder)
        if args.action == "list":
            print(f"{model.name}: {model.description}")
        for st in files:
            state = "ok" if st.verified else ("CORRUPT (checksum)" if st.present else "missing")
            bad += args.action == "verify" and not st.verified
            print(f"  {st.path}  {state}")
    if bad:
        raise models.ModelError(f"{bad} model file(s) missing or corrupt in {folder}")
    return 0


def _cmd_download(args) -> int:
    from osslam.datasets.catalogue import TUM_BASE_URL, TUM_SEQUENCES, tum_entry
    from osslam.datasets.download import fetch_tum

    if args.list:
        for entry in TUM_SEQUENCES.values():
            print(f"{entry.short:42s} {entry.category:18s} ~{entry.size_mb:5d} MB  {entry.url()}")
        return 0
    if not args.names:
        raise ValueError("name at least one sequence (see --list)")
    entries = [tum_entry(name) for name in args.names]
    for entry in entries:
        result = fetch_tum(entry, args.to, base_url=args.mirror or TUM_BASE_URL, keep_archive=args.keep_archive,
                           on_progress=_download_progress(entry.short))
        what = "already present" if result.status == "present" else f"downloaded ({result.bytes_downloaded / 1e6:.1f} MB)"
        print(f"{entry.short}: {what}: {result.folder}")
    return 0


def _download_progress(label: str):
    """A download progress callback drawing one line on a terminal, silent otherwise."""
    import time

    last = [0.0]

    def show(done: int, total: int | None) -> None:
        now = time.monotonic()
        if not sys.stderr.isatty() or (now - last[0] < 0.2 and done != total):
            return
        last[0] = now
        of = f" of {total / 1e6:.1f}" if total else ""
        sys.stderr.write(f"\r{label}: {done / 1e6:.1f}{of} MB\033[K" + ("\n" if done == total else ""))

    return show


def _bench_suite(args):
    """The suite of ``osslam bench``: --suite and/or sequences on the command line, with the options applied."""
    from dataclasses import replace

    from osslam.bench.suite import load_suite, parse_config, suite_from_dict, with_overrides

    external = []
    for item in args.external:
        name, sep, folder = item.partition("=")
        if not sep or not name:
            raise ValueError(f"--external '{item}': expected NAME=FOLDER")
        external.append((name, Path(folder)))
    if not args.suite and not args.sequences:
        raise ValueError("name a --suite or sequences (see --list-suites)")
    extra = suite_from_dict({"name": "bench", "sequences": args.sequences}, "command line", args.data) \
        if args.sequences else None
    suite = load_suite(args.suite, args.data) if args.suite else extra
    if args.suite and extra:
        suite = replace(suite, sequences=suite.sequences + extra.sequences)
    if args.configs:
        suite = replace(suite, configs=tuple(parse_config(c, "--config") for c in args.configs))
    return with_overrides(suite, args.overrides, args.repeats, external)


def _cmd_bench(args) -> int:
    from osslam.bench.suite import builtin_suites

    if args.list_suites:
        print("\n".join(builtin_suites()))
        return 0
    if args.out is None:
        raise ValueError("--out is required")
    suite = _bench_suite(args)
    from osslam.bench.executors import make_executor
    from osslam.bench.report import write_report
    from osslam.bench.runner import run_suite

    failed = 0
    if not args.report_only:
        total = len(suite.sequences) * len(suite.configs) * suite.repeats
        done = [0]

        def show(result) -> None:
            done[0] += 1
            ape = f"  APE {result.ape_rmse:.4f} m" if result.ape_rmse is not None else ""
            detail = f"  {result.error}" if result.error else f"  {result.wall_s:.1f} s{ape}"
            print(f"[{done[0]}/{total}] {result.key}: {result.status}{detail}", flush=True)

        def prepared(p) -> None:
            what = f"failed  {p.error}" if p.error else f"built in {p.wall_s:.1f} s: {p.folder}"
            print(f"composite {p.label}: {what}", flush=True)

        executor = make_executor(args.executor, args.workers, args.address)
        bench_run = run_suite(suite, args.out, executor, show, rerun=args.rerun, on_prepared=prepared)
        failed = len(bench_run.failed)
    report = write_report(suite, args.out, args.report_dir, plots=not args.no_plots)
    print(f"report: {report.report_path}")
    if failed:
        print(f"osslam bench: {failed} job(s) failed (see the report and error.txt in their folders)", file=sys.stderr)
        return 1
    return 0


def _cmd_flow(args) -> int:
    from osslam import flow_cli

    return flow_cli.run(args)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``osslam`` command."""
    parser = _build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    if args.list_configs:
        from osslam.config import preset_names

        print("\n".join(preset_names()))
        return 0
    commands = {"run": _cmd_run, "eval": _cmd_eval, "demo": _cmd_demo, "synth": _cmd_synth,
                "models": _cmd_models, "download": _cmd_download, "bench": _cmd_bench, "flow": _cmd_flow}
    if args.command not in commands:
        parser.print_help()
        return 2
    try:
        return commands[args.command](args)
    except (OsslamError, ValueError) as exc:
        if args.verbose:
            raise
        print(f"osslam {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the file system refused: a path taken by a file, no permission, a full disk
        if args.verbose:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"osslam {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        saved = f"; the frames tracked so far are saved in {args.out}" if args.command in ("run", "demo") else ""
        print(f"osslam {args.command}: interrupted{saved}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
