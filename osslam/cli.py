"""Command line: ``osslam run | eval | demo``. Thin: parse, call, print."""

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
    return parser


def _preset_for(sequence: Path, explicit: str | None) -> str | None:
    """The preset a run uses: the explicit one, else tum_fr1/2/3 from the folder name."""
    if explicit:
        return explicit
    name = sequence.resolve().name.lower()
    for n in ("1", "2", "3"):
        if f"freiburg{n}" in name:
            return f"tum_fr{n}"
    return None


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
    commands = {"run": _cmd_run, "eval": _cmd_eval, "demo": _cmd_demo}
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
    except KeyboardInterrupt:
        saved = f"; the frames tracked so far are saved in {args.out}" if args.command in ("run", "demo") else ""
        print(f"osslam {args.command}: interrupted{saved}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
