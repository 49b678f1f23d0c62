"""Command line: ``fastslam-edu run ...`` (FastSLAM 1.0, or EKF-SLAM with ``--filter ekf``, on a MR.CLAM robot), ``fastslam-edu gridslam ...`` (grid SLAM on a 2D laser log).

Bad arguments or data give one clear line on stderr and exit status 2 (usage)
or 1 (data), never a traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path


from fastslam_edu.app.sweep import positive_int
from fastslam_edu.landmark.fastslam import MODES, PROPOSALS, FastSLAMParams


def _robot_list(text: str) -> tuple:
    """``--robots 1,2,3``: robot numbers in 1-5, none repeated."""
    from fastslam_edu.landmark.multi_robot import check_robot_numbers

    try:
        numbers = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected robot numbers separated by commas, e.g. 1,2,3, got {text!r}") from None
    try:
        return check_robot_numbers(numbers)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _initial_pose(text: str):
    if text == "landmarks":
        return text
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(map(math.isfinite, values)):
        raise argparse.ArgumentTypeError(f"expected X,Y,THETA (three numbers) or 'landmarks', got {text!r}")
    return tuple(values)


class _OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr (``--help`` still shows the usage)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The command line: ``run`` (landmark SLAM on MR.CLAM), ``gridslam`` (a laser log) and ``data``."""
    from fastslam_edu.datasets.registry import add_arguments as add_data_arguments

    parser = _OneLineParser(prog="fastslam-edu", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)
    _add_run_options(sub.add_parser("run", help="FastSLAM 1.0 (or EKF-SLAM) on one robot of a MR.CLAM dataset"))
    _add_gridslam_options(sub.add_parser("gridslam", help="particle-filter grid SLAM on a 2D laser log (Intel, FR079)"))
    add_data_arguments(sub.add_parser("data", help="fetch (or --check) the registered datasets into $FASTSLAM_EDU_DATA, "
                                                   "one line per dataset"))
    return parser


def _add_run_options(run: argparse.ArgumentParser) -> None:
    """The options of ``fastslam-edu run``."""
    run.add_argument("--data", required=True, type=Path, help="a MR.CLAM dataset folder (MRCLAM_DatasetN)")
    run.add_argument("--robot", type=positive_int, help="robot subject number (1-5); or --robots")
    run.add_argument("--robots", type=_robot_list, metavar="N,N,...",
                     help="several robots of the dataset, e.g. 1,2,3,4,5: with --smooth, one least-squares problem "
                          "over all their paths and one shared map, with their sightings of each other "
                          "(fastslam_edu.landmark.multi_robot); one robot: the same as --robot")
    run.add_argument("--filter", choices=FILTERS, default="fastslam",
                     help="fastslam: FastSLAM 1.0 (default); ekf: EKF-SLAM, one Gaussian over pose and map, with the "
                          "same noise model and gate (fastslam_edu.landmark.ekf_slam; deterministic)")
    run.add_argument("--particles", type=positive_int, default=None,
                     help=f"number of particles M (default {FastSLAMParams().n_particles}; FastSLAM only)")
    run.add_argument("--seed", type=int, default=0, help="random seed (same seed, same numbers)")
    run.add_argument("--rate", choices=("full", "1hz"), default="full", help="full-rate events or the write-up's 1 Hz cleaning")
    run.add_argument("--groundtruth", type=Path, help="groundtruth file (.dat or 1 Hz .csv) to score against")
    run.add_argument("--x0", type=_initial_pose, metavar="X,Y,THETA|landmarks",
                     help="initial pose [m, m, rad] (write --x0=X,Y,THETA when X is negative), or 'landmarks' to "
                          "find it from the first sightings of the surveyed landmarks (robots without groundtruth); "
                          "default: groundtruth at the first step; with --robots: 'landmarks' or the default")
    run.add_argument("--correspondences", choices=("known", "unknown"), default="known",
                     help="known: the barcodes say which landmark a sighting is (default); unknown: FastSLAM decides "
                          "per particle (fastslam_edu.landmark.association), EKF-SLAM by nearest neighbour (--filter "
                          "ekf), every sighting given without its barcode (other robots and misread barcodes "
                          "included); the barcodes only score the associations")
    run.add_argument("--association", choices=("joint", "greedy", "independent"), default=None,
                     help="with --correspondences unknown, how FastSLAM decides the sightings of one instant "
                          "(AssociationParams.association): joint (default): as a whole, their innovations correlated "
                          "by the pose error they share; greedy: the most likely pair first, each sighting and "
                          "landmark once; independent: each sighting alone")
    run.add_argument("--mode", choices=MODES, default="slam")
    run.add_argument("--proposal", choices=PROPOSALS, default="motion",
                     help="motion: FastSLAM 1.0 (default); fastslam2: FastSLAM 2.0's proposal")
    run.add_argument("--smooth", action="store_true",
                     help="also solve the whole log by least squares from the filter's result (fastslam_edu.landmark.smoother, "
                          "BEST_ESTIMATE: the filter's model with every sighting counted in full): the book's best "
                          "estimate; its figures go under 'smoother'")
    run.add_argument("--smoother-backend", choices=("scipy", "gtsam"), default=None,
                     help="with --smooth, who solves the least squares: scipy (default: the package's own "
                          "Levenberg-Marquardt) or gtsam (the same problem as GTSAM factors; needs the extra "
                          "'graph'); the JSON's smoother part says which ran ('backend') and its time ('seconds')")
    run.add_argument("--resampler", choices=("systematic", "stratified", "residual", "roulette", "multinomial"), default=None,
                     help=f"default {FastSLAMParams().resampler} (FastSLAM only)")
    run.add_argument("--no-audit", action="store_true", help="do not correct swapped landmark table entries")
    run.add_argument("--json", type=Path, help="write the figures, parameters and seed to this JSON file")
    run.add_argument("--plot", type=Path, help="write a figure (map, path, errors) to this PNG")
    run.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_gridslam_options(gs: argparse.ArgumentParser) -> None:
    """The options of ``fastslam-edu gridslam``."""
    gs.add_argument("--scans", required=True, type=Path, help="laser log: CARMEN (.log/.gz), Intel JSON (.json/.json.gz) or THOR LiDAR (.mat, with --joints)")
    gs.add_argument("--format", choices=LASER_FORMATS, help="file format (default: from the file name)")
    gs.add_argument("--joints", type=Path, help="THOR joint file (head/neck angles), with --format thor")
    gs.add_argument("--particles", type=positive_int, default=30, help="number of particles M")
    gs.add_argument("--seed", type=int, default=0, help="random seed (same seed, same numbers)")
    gs.add_argument("--maps", choices=("best", "particles"), default="best",
                    help="one map from the best particle (the write-up) or one map per particle (RBPF)")
    gs.add_argument("--no-scan-match", action="store_true", help="no scan matching (the write-up's proposal)")
    gs.add_argument("--writeup", action="store_true",
                    help="the write-up's exact rule: 0/1 correlation, exp(c), resample every step, no scan matching")
    gs.add_argument("--scans-limit", type=positive_int, help="use only the first N scans")
    gs.add_argument("--reference", type=Path, help="log with reference poses (e.g. GMapping's) for the aligned RMSE")
    gs.add_argument("--relations", type=Path, help="Kümmerle et al. relations file (same time base as --scans)")
    gs.add_argument("--tolerance", type=float, default=1e-3, help="time matching tolerance [s] (default 0.001)")
    gs.add_argument("--json", type=Path, help="write the metrics, parameters and seed to this JSON file")
    gs.add_argument("--map", type=Path, help="write the map and path to this PNG")
    gs.add_argument("--quiet", action="store_true", help="no progress bar")


#: Laser log formats of ``fastslam-edu gridslam``.
LASER_FORMATS = ("carmen", "intel-json", "thor")


def _laser_format(path: Path, given: str | None) -> str:
    if given:
        return given
    name = path.name.lower()
    if name.endswith((".json", ".json.gz")):
        return "intel-json"
    if name.endswith(".mat"):
        return "thor"
    return "carmen"


def _read_laser(path: Path, fmt: str, what: str, joints: Path | None = None):
    from fastslam_edu.datasets.laser import read_carmen, read_intel_json

    if not path.is_file():
        raise FileNotFoundError(f"{what} {path}: no such file")
    if fmt == "thor":
        return _read_thor_planar(path, joints, what)
    if fmt == "intel-json":
        name = path.name.lower()
        return read_intel_json(path, kind=None if ("gfs" in name or "corrected" in name) else "odometry")
    return read_carmen(path)


def _read_thor_planar(path: Path, joints: Path | None, what: str):
    """A THOR LiDAR log projected to the body's horizontal plane (:func:`fastslam_edu.grid.thor.planar_laser_log`)."""
    from fastslam_edu.datasets.thor_lidar import read_thor_joints, read_thor_lidar
    from fastslam_edu.grid.thor import planar_laser_log

    if joints is None:
        raise ValueError(f"{what} {path}: THOR scans need the joint log (head/neck angles): add --joints FILE")
    if not joints.is_file():
        raise FileNotFoundError(f"--joints {joints}: no such file")
    lidar = read_thor_lidar(path)
    t_j, neck, head = read_thor_joints(joints)
    try:
        return planar_laser_log(lidar, t_j, neck, head)
    except ValueError as exc:
        raise ValueError(f"{what} {path} with --joints {joints}: {exc}") from None


#: The filters of ``fastslam-edu run --filter``.
FILTERS = ("fastslam", "ekf")

#: The lines ``fastslam-edu run`` prints, in order.
RUN_KEYS = ("path_rmse_m", "path_rmse_aligned_m", "path_max_m", "landmark_error_mean_m",
            "landmark_error_aligned_mean_m", "steps", "measurements_used", "measurements_rejected", "filter_seconds")


def _print_rows(rows) -> None:
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {'n/a' if v is None else (f'{v:.4f}' if isinstance(v, float) else v)}")


def _check_ekf_options(args) -> None:
    """Refuse the options of ``run`` that only FastSLAM has, with ``--filter ekf``."""
    given = [name for name, used in (("--particles", args.particles is not None),
                                     ("--resampler", args.resampler is not None),
                                     ("--proposal", args.proposal != "motion"), ("--mode", args.mode != "slam"),
                                     ("--smooth", args.smooth), ("--association", args.association is not None))
             if used]
    if given:
        raise ValueError(f"{', '.join(given)}: FastSLAM's option(s), not EKF-SLAM's (--filter ekf)")


def cmd_run_ekf(args) -> int:
    """``fastslam-edu run --filter ekf``: EKF-SLAM on one robot, the same figures and JSON keys as FastSLAM's run
    (with ``--correspondences unknown``, as FastSLAM's run without barcodes)."""
    from fastslam_edu.app.experiment import run_mrclam_ekf
    from fastslam_edu.landmark.ekf_slam import EKFSLAMParams

    _check_ekf_options(args)
    params = EKFSLAMParams(correspondences=args.correspondences)
    result, summary, ctx = run_mrclam_ekf(args.data, args.robot, params, rate=args.rate, x0=args.x0,
                                          groundtruth_file=args.groundtruth, audit=not args.no_audit)
    summary.update(filter="ekf", seed=args.seed)
    _report(summary, UNKNOWN_KEYS if args.correspondences == "unknown" else RUN_KEYS, args.json)
    if args.plot and args.correspondences == "unknown":
        _unknown_figure(result, ctx, f"{args.data.name} robot {args.robot}, EKF-SLAM, unknown correspondences",
                        "map").savefig(args.plot, dpi=120)
    elif args.plot:
        _ekf_figure(result, ctx, f"{args.data.name} robot {args.robot}, EKF-SLAM").savefig(args.plot, dpi=120)
    return 0


def _ekf_figure(result, ctx, title: str):
    """Map and path (left); position error and the 2σ the filter reports, over time (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from fastslam_edu.app.plotting import plot_map
    from fastslam_edu.evaluation import metrics

    log, dataset = ctx["log"], ctx["dataset"]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [1.3, 1]})
    plot_map(ax0, result, dataset.landmark_positions, log.groundtruth, title=title)
    ax0.lines[0 if log.groundtruth is None else 1].set_label("EKF-SLAM (mean)")
    ax0.legend(loc="best", fontsize=7)
    t0 = result.t[0]
    if log.groundtruth is not None:
        gt = log.groundtruth
        t_gt = gt["time"].to_numpy()
        m = (result.t >= t_gt[0]) & (result.t <= t_gt[-1])
        e = metrics.trajectory_errors(result.t[m], result.pose_mean[m], t_gt, gt[["x", "y", "theta"]].to_numpy())
        ax1.plot(result.t[m] - t0, e["errors"], color="C0", lw=0.8, label="position error")
    two_sigma = 2 * np.sqrt(result.pose_cov[:, 0, 0] + result.pose_cov[:, 1, 1])
    ax1.plot(result.update_t - t0, two_sigma, color="C3", lw=0.8, ls="--", label="2σ reported")
    ax1.set(xlabel="time [s]", ylabel="[m]", title="position error and the filter's 2σ")
    ax1.legend(fontsize=7)
    fig.tight_layout()
    return fig


#: The lines ``fastslam-edu run --correspondences unknown`` prints, in order.
UNKNOWN_KEYS = ("association_accuracy", "association_accuracy_oracle", "landmarks_in_map", "landmarks_spurious",
                "landmark_error_mean_m", "landmark_error_aligned_mean_m", "path_rmse_m", "path_rmse_aligned_m",
                "sightings", "clutter_sightings", "filter_seconds")


def cmd_run_unknown(args) -> int:
    """``fastslam-edu run --correspondences unknown``: FastSLAM deciding the associations, scored by the barcodes."""
    from fastslam_edu.app.experiment import run_mrclam_unknown
    from fastslam_edu.landmark.association import AssociationParams

    given = [name for name, used in (("--mode", args.mode != "slam"), ("--rate 1hz", args.rate != "full")) if used]
    if given:
        raise ValueError(f"{', '.join(given)}: not available with --correspondences unknown")
    defaults = AssociationParams()
    f = defaults.filter
    params = defaults.replace(filter=f.replace(n_particles=f.n_particles if args.particles is None else args.particles,
                                               resampler=args.resampler or f.resampler, proposal=args.proposal),
                              association=args.association or defaults.association)
    result, summary, ctx = run_mrclam_unknown(args.data, args.robot, params, args.seed, rate=args.rate, x0=args.x0,
                                              groundtruth_file=args.groundtruth, audit=not args.no_audit)
    summary["filter"] = "fastslam"
    if args.smooth:  # the associations re-decided with the whole log (fastslam_edu.landmark.smoother_association)
        from fastslam_edu.app.experiment import summarize_smoother_association
        from fastslam_edu.landmark.smoother_association import smooth_association

        smoothed = smooth_association(ctx["stream"], result)
        summary["smoother"] = summarize_smoother_association(smoothed, ctx["stream"], ctx["true_index"],
                                                             ctx["dataset"], ctx["log"])
    _report(summary, UNKNOWN_KEYS, args.json)
    if args.plot:
        _unknown_figure(result, ctx, f"{args.data.name} robot {args.robot}, unknown correspondences, seed {args.seed}",
                        "map (best particle)").savefig(args.plot, dpi=120)
    return 0


def _unknown_figure(result, ctx, title: str, map_label: str):
    """The mean path, the surveyed landmarks and the filter's own map."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    truth = ctx["dataset"].landmark_positions
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.plot(result.pose_mean[:, 0], result.pose_mean[:, 1], lw=0.6, label="path (mean)")
    ax.plot(truth[:, 0], truth[:, 1], "k*", label="surveyed landmarks")
    ax.plot(result.landmarks[:, 0], result.landmarks[:, 1], "r+", label=map_label)
    ax.set(xlabel="x [m]", ylabel="y [m]", aspect="equal", title=title)
    ax.legend(fontsize=7)
    return fig


def _report(summary: dict, keys, json_path) -> None:
    """The run's notes on stderr, its figures ``keys`` as a table, and the whole summary as JSON if asked."""
    for note in summary["notes"]:
        print(f"note: {note}", file=sys.stderr)
    _print_rows([(k, summary.get(k)) for k in keys])
    if json_path:
        json_path.write_text(json.dumps(summary, indent=2))


def _backend_available(backend) -> bool:
    """False (after one line on stderr naming the extra to install) if ``--smoother-backend gtsam`` is asked for
    without GTSAM: checked before any filter runs."""
    if backend != "gtsam":
        return True
    from fastslam_edu.landmark.smoother_gtsam import require_gtsam

    try:
        require_gtsam()
    except ImportError as exc:
        print(f"fastslam-edu run: error: {exc}", file=sys.stderr)
        return False
    return True


def cmd_run(args) -> int:
    from fastslam_edu.app.experiment import run_mrclam
    from fastslam_edu.landmark.fastslam import ProgressBar

    if not args.data.is_dir():
        raise FileNotFoundError(f"--data {args.data}: no such dataset folder")
    if (args.robot is None) == (args.robots is None):
        raise ValueError("give the robot: --robot N, or --robots N,N,... (not both)")
    if args.smoother_backend is not None and not args.smooth:
        raise ValueError(f"--smoother-backend {args.smoother_backend} chooses the solver of --smooth: give --smooth too")
    if not _backend_available(args.smoother_backend):
        return 2
    if args.robots is not None and len(args.robots) == 1:
        args.robot = args.robots[0]  # the same run as --robot
    elif args.robots is not None:
        return cmd_run_robots(args)
    if args.filter == "ekf":
        return cmd_run_ekf(args)
    if args.correspondences == "unknown":
        return cmd_run_unknown(args)
    if args.association is not None:
        raise ValueError("--association decides which landmark a sighting is: it needs --correspondences unknown")
    if args.smooth and args.mode != "slam":
        raise ValueError(f"--smooth solves full SLAM; it does not apply to --mode {args.mode}")
    defaults = FastSLAMParams()
    args.particles = defaults.n_particles if args.particles is None else args.particles
    params = defaults.replace(n_particles=args.particles, mode=args.mode,
                              resampler=args.resampler or defaults.resampler, proposal=args.proposal)
    result, summary, ctx = run_mrclam(
        args.data, args.robot, params, args.seed, rate=args.rate, x0=args.x0,
        hooks=() if args.quiet else (ProgressBar(),), groundtruth_file=args.groundtruth, audit=not args.no_audit,
    )
    summary["filter"] = "fastslam"
    for note in summary["notes"]:
        print(f"note: {note}", file=sys.stderr)
    keys = RUN_KEYS
    rows = [(k, summary.get(k)) for k in keys]
    if args.smooth:
        from fastslam_edu.app.experiment import summarize_smoother
        from fastslam_edu.landmark.smoother import BEST_ESTIMATE, smooth

        summary["smoother"] = summarize_smoother(smooth(ctx["stream"], params, initial=result, solver=BEST_ESTIMATE,
                                                     backend=args.smoother_backend or "scipy"), ctx["dataset"], ctx["log"])
        rows += [(f"smoother.{k}", summary["smoother"].get(k)) for k in keys[:5] + ("smoother_seconds",)]
    _print_rows(rows)
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2))
    if args.plot:
        _save_run_figure(args, result, ctx)
    return 0


def _save_run_figure(args, result, ctx) -> None:
    """``--plot``: the FastSLAM run's map, path and errors against groundtruth (where there is some), as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    from fastslam_edu.evaluation import metrics
    from fastslam_edu.app.plotting import run_figure

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


def cmd_run_robots(args) -> int:
    """``fastslam-edu run --robots 1,2,3 --smooth``: FastSLAM on each robot, then one least-squares problem over all of
    them (:func:`fastslam_edu.app.multi_robot.run_mrclam_robots`); per robot its path's errors, and the shared map's."""
    from fastslam_edu.app.multi_robot import run_mrclam_robots
    from fastslam_edu.landmark.fastslam import ProgressBar

    given = [name for name, used in (("--filter ekf", args.filter != "fastslam"),
                                     ("--correspondences unknown", args.correspondences != "known"),
                                     ("--mode", args.mode != "slam"), ("--groundtruth", args.groundtruth is not None),
                                     ("--plot", args.plot is not None)) if used]
    if given:
        raise ValueError(f"{', '.join(given)}: not available with several robots (--robots)")
    if not args.smooth:
        raise ValueError("--robots with several robots solves them together: add --smooth (or give one robot)")
    if args.x0 is not None and not isinstance(args.x0, str):
        raise ValueError("--x0 X,Y,THETA is one robot's start: with several robots, give --x0 landmarks "
                         "(each robot's start from the surveyed landmarks) or nothing (groundtruth at the first step)")
    defaults = FastSLAMParams()
    params = defaults.replace(n_particles=defaults.n_particles if args.particles is None else args.particles,
                              resampler=args.resampler or defaults.resampler, proposal=args.proposal)
    _, summary, _ = run_mrclam_robots(args.data, args.robots, params, args.seed, rate=args.rate, x0=args.x0,
                                      audit=not args.no_audit, hooks=() if args.quiet else (ProgressBar(),),
                                      backend=args.smoother_backend or "scipy")
    summary["filter"] = "fastslam"
    for note in summary["notes"]:
        print(f"note: {note}", file=sys.stderr)
    sm = summary["smoother"]
    rows = [(f"robot{r}.{k}", fig.get(k)) for r, fig in sm["robots"].items() for k in ("path_rmse_m", "path_rmse_aligned_m")]
    rows += [(f"smoother.{k}", sm.get(k)) for k in ("landmark_error_mean_m", "landmark_error_aligned_mean_m",
                                                  "robot_sightings_used", "robot_sightings_gated", "backend", "seconds")]
    _print_rows(rows)
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2))
    return 0


def cmd_gridslam(args) -> int:
    import numpy as np

    from fastslam_edu.datasets.laser import read_relations
    from fastslam_edu.grid.gridslam import GridSLAMParams, run_grid_slam
    from fastslam_edu.evaluation.relations import score_trajectory

    if not (args.tolerance >= 0):
        raise ValueError(f"--tolerance must be ≥ 0, got {args.tolerance}")
    fmt = _laser_format(args.scans, args.format)
    if args.joints is not None and fmt != "thor":
        raise ValueError("--joints is only used with --format thor")
    log = _read_laser(args.scans, fmt, "--scans", args.joints)
    base = GridSLAMParams.writeup() if args.writeup else GridSLAMParams()
    changes = {"n_particles": args.particles, "maps": args.maps}
    if args.no_scan_match:
        changes["match_iterations"] = 0
    params = base.replace(**changes)
    reference = _read_laser(args.reference, _laser_format(args.reference, None), "--reference") if args.reference else None
    relations = read_relations(args.relations) if args.relations else None

    result = run_grid_slam(log, params, np.random.default_rng(args.seed), progress=not args.quiet,
                           n_scans=args.scans_limit)
    n = len(result.t)
    summary = {
        "scans_file": str(args.scans), "format": fmt, "n_scans": n, "seed": args.seed,
        "params": params.to_dict(), "filter_seconds": result.filter_seconds,
        "seconds_per_scan": result.filter_seconds / max(n - 1, 1),
        "resampling_steps": int(result.resampled.sum()), "mean_n_eff": float(result.n_eff[1:].mean()) if n > 1 else None,
        "planar_projection": ({"params": log.params, "counts": log.counts} if fmt == "thor" else None),
        "grid": {"shape": list(result.grid.shape), "resolution": result.grid.resolution,
                 "origin": list(result.grid.origin)},
        "reference": None, "relations": None,
    }
    ref_path = None if reference is None else (reference.t, reference.poses)
    est, odo = [score_trajectory(result.t, poses, relations=relations, reference=ref_path, tolerance=args.tolerance)
                for poses in (result.estimate, result.odometry)]
    if reference is not None:
        summary["reference"] = {"file": str(args.reference), **est["reference"],
                                "odometry_rmse_m": odo["reference"]["rmse_m"], "odometry_max_m": odo["reference"]["max_m"]}
    if relations is not None:
        ref = (None if reference is None else
               score_trajectory(*ref_path, relations=relations, tolerance=args.tolerance)["relations"])
        summary["relations"] = {"file": str(args.relations), "tolerance_s": args.tolerance,
                                "estimate": est["relations"], "odometry": odo["relations"], "reference": ref}
        if est["relations"]["n_used"] == 0:
            print(f"note: no relation has both times within {args.tolerance} s of a scan: different time bases?",
                  file=sys.stderr)

    _print_gridslam_summary(summary)
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2))
    if args.map:
        _save_grid_map(result, args.map, f"{args.scans.name}: M = {args.particles}, seed {args.seed}")
    return 0


def _print_gridslam_summary(summary: dict) -> None:
    """The lines ``fastslam-edu gridslam`` prints, ``name  value``, from its JSON summary."""
    rows = [("scans", summary["n_scans"]), ("filter_seconds", summary["filter_seconds"]),
            ("ms_per_scan", 1e3 * summary["seconds_per_scan"]), ("resampling_steps", summary["resampling_steps"])]
    if summary["reference"]:
        r = summary["reference"]
        rows += [("rmse_vs_reference_m", r["rmse_m"]), ("odometry_rmse_vs_reference_m", r["odometry_rmse_m"])]
    if summary["relations"]:
        r = summary["relations"]

        def pm(e, mean, std, digits=4):
            return "n/a" if e[mean] is None else f"{e[mean]:.{digits}f} ± {e[std]:.{digits}f}"

        rows += [("relations_used", f"{r['estimate']['n_used']} of {r['estimate']['n_relations']}"),
                 ("relation_trans_error_m", pm(r["estimate"], "trans_mean_m", "trans_std_m")),
                 ("relation_rot_error_deg", pm(r["estimate"], "rot_mean_deg", "rot_std_deg", 3)),
                 ("odometry_relation_trans_error_m", pm(r["odometry"], "trans_mean_m", "trans_std_m"))]
        if r["reference"]:
            rows.append(("reference_relation_trans_error_m (its own scans)",
                         pm(r["reference"], "trans_mean_m", "trans_std_m")))
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {f'{v:.4f}' if isinstance(v, float) else v}")


def _save_grid_map(result, path: Path, title: str) -> None:
    """The grid SLAM map with the estimated path, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    ax.imshow(result.grid.probability(), origin="lower", extent=result.grid.extent, cmap="gray_r", vmin=0, vmax=1)
    ax.plot(result.estimate[:, 0], result.estimate[:, 1], "r-", lw=0.6, label="estimate")
    ax.set(xlabel="x [m]", ylabel="y [m]", title=title)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def cmd_data(args) -> int:
    """``fastslam-edu data [NAME ...] [--check] [--quiet]``: see :mod:`fastslam_edu.datasets.registry`."""
    from fastslam_edu.datasets.registry import run_command

    return run_command(args)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            return cmd_run(args)
        if args.command == "gridslam":
            return cmd_gridslam(args)
        if args.command == "data":
            return cmd_data(args)
    except (ValueError, FileNotFoundError, OSError) as exc:
        print(f"fastslam-edu {args.command}: error: {exc}", file=sys.stderr)
        return 1
    parser.error(f"unknown command {args.command}")
    return 2


if __name__ == "__main__":
    sys.exit(main())
