"""Command line: ``fastslam-edu run ...`` (FastSLAM 1.0 on a MR.CLAM robot).

Bad arguments or data give one clear line on stderr and exit status 2 (usage)
or 1 (data), never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


from .fastslam import MODES, FastSLAMParams, with_params


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


class _OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr (``--help`` still shows the usage)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog="fastslam-edu", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)
    run = sub.add_parser("run", help="FastSLAM 1.0 on one robot of a MR.CLAM dataset")
    run.add_argument("--data", required=True, type=Path, help="a MR.CLAM dataset folder (MRCLAM_DatasetN)")
    run.add_argument("--robot", required=True, type=_positive_int, help="robot subject number (1-5)")
    run.add_argument("--particles", type=_positive_int, default=FastSLAMParams().n_particles, help="number of particles M")
    run.add_argument("--seed", type=int, default=0, help="random seed (same seed, same numbers)")
    run.add_argument("--rate", choices=("full", "1hz"), default="full", help="full-rate events or the write-up's 1 Hz cleaning")
    run.add_argument("--groundtruth", type=Path, help="groundtruth file (.dat or 1 Hz .csv) to score against")
    run.add_argument("--mode", choices=MODES, default="slam")
    run.add_argument("--resampler", choices=("systematic", "stratified", "residual", "multinomial"), default="systematic")
    run.add_argument("--no-audit", action="store_true", help="do not correct swapped landmark table entries")
    run.add_argument("--json", type=Path, help="write the figures, parameters and seed to this JSON file")
    run.add_argument("--plot", type=Path, help="write a figure (map, path, errors) to this PNG")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def cmd_run(args) -> int:
    from .experiment import run_mrclam

    if not args.data.is_dir():
        raise FileNotFoundError(f"--data {args.data}: no such dataset folder")
    params = with_params(FastSLAMParams(), n_particles=args.particles, mode=args.mode, resampler=args.resampler)
    result, summary, ctx = run_mrclam(
        args.data, args.robot, params, args.seed, rate=args.rate, groundtruth_file=args.groundtruth,
        progress=not args.quiet, audit=not args.no_audit,
    )
    for note in summary["notes"]:
        print(f"note: {note}", file=sys.stderr)
    keys = ("path_rmse_m", "path_rmse_aligned_m", "path_max_m", "landmark_error_mean_m",
            "landmark_error_aligned_mean_m", "steps", "measurements_used", "measurements_rejected", "filter_seconds")
    width = max(map(len, keys))
    for k in keys:
        v = summary.get(k)
        print(f"{k:<{width}}  {'n/a' if v is None else (f'{v:.4f}' if isinstance(v, float) else v)}")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2))
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        from . import metrics
        from .plotting import run_figure

        log, dataset = ctx["log"], ctx["dataset"]
        errs = None
        if log.groundtruth is not None:
            gt = log.groundtruth
            t_gt = gt["time"].to_numpy()
            m = (result.t >= t_gt[0]) & (result.t <= t_gt[-1])
            e = metrics.trajectory_errors(result.t[m], result.pose_mean[m], t_gt, gt[["x", "y", "theta"]].to_numpy())
            errs = (result.t[m], e["errors"])
        fig = run_figure(result, dataset.landmark_positions, log.groundtruth, errs,
                         title=f"{args.data.name} robot {args.robot}, M={args.particles}, seed {args.seed}")
        fig.savefig(args.plot, dpi=120)
    return 0


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            return cmd_run(args)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"fastslam-edu {args.command}: error: {exc}", file=sys.stderr)
        return 1
    parser.error(f"unknown command {args.command}")
    return 2


if __name__ == "__main__":
    sys.exit(main())
