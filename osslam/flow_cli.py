"""``osslam flow train | eval``: train the learned flow network, and score flow backends against ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    """Add ``flow train`` and ``flow eval`` to the ``osslam`` command's subparsers."""
    flow = subparsers.add_parser("flow", help="train and evaluate the learned optical flow network")
    sub = flow.add_subparsers(dest="flow_command", required=True)

    tr = sub.add_parser("train", help="train the flow network (checkpoints, resume, CSV log)")
    tr.add_argument("--config", "-c", default="small", metavar="NAME|PATH",
                    help="training preset (configs/flow: small, paper, finetune) or YAML file (default: small)")
    tr.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override one entry, e.g. optim.steps=500 or model.unet=false (repeatable)")
    tr.add_argument("--out", "-o", type=Path, required=True, help="output folder")
    tr.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    tr.add_argument("--no-progress", action="store_true", help="no progress bar")
    tr.set_defaults(handler=_cmd_train)

    ev = sub.add_parser("eval", help="EPE, 1/3/5 px and Fl-all of flow backends on ground-truth flow")
    ev.add_argument("data", help="tum:FOLDER (rigid flow from depth and poses), composite:FOLDER (osslam synth "
                                 "output, movers included) or LAYOUT:FOLDER (chairs, things, sintel, kitti, hd1k)")
    ev.add_argument("--backend", "-b", action="append", default=[], metavar="NAME",
                    help="dis (as SLAM runs it by default), dis:ultrafast, dis:fast, dis:medium (OpenCV's presets), "
                         "learned or learned:WEIGHTS (repeatable; default: all DIS and the bundled network)")
    ev.add_argument("--pairs", type=int, default=0, help="evaluate every k-th pair so that about this many remain")
    ev.add_argument("--working-width", type=int, default=320, help="width both backends compute flow at")
    ev.add_argument("--threads", type=int, default=1, help="CPU threads of the learned backend")
    ev.add_argument("--iterations", default="", help="learned: update steps per scale, e.g. 3,2,1")
    ev.add_argument("--out", "-o", type=Path, help="write results.json and results.md here")
    ev.set_defaults(handler=_cmd_eval)


def run(args: argparse.Namespace) -> int:
    """Dispatch a parsed ``osslam flow`` command."""
    return args.handler(args)


def _cmd_train(args) -> int:
    from osslam.frontend.flow.settings import load_train_config
    from osslam.frontend.flow.train import train

    cfg = load_train_config(args.config, args.overrides)
    result = train(cfg, args.out, resume=args.resume, progress=False if args.no_progress else None)
    print(f"trained {result.steps} steps in {result.seconds / 60:.1f} min, final loss {result.final_loss:.3f}")
    print(f"weights: {result.weights}")
    return 0


def _cmd_eval(args) -> int:
    from osslam.frontend.flow.evaluate import (
        evaluate_backends,
        format_table,
        open_eval_data,
        write_results,
    )

    data = open_eval_data(args.data)
    backends = args.backend or ["dis:ultrafast", "dis:fast", "dis:medium", "dis", "learned"]
    iterations = [int(v) for v in args.iterations.split(",")] if args.iterations else []
    rows = evaluate_backends(data, backends, args.working_width, args.pairs, args.threads, iterations)
    print(format_table(rows))
    if args.out:
        write_results(rows, args.out, args.data)
        print(f"results: {args.out}")
    return 0
