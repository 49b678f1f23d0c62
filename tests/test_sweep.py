"""Sweeps (fastslam_edu.app.sweep): the same numbers serially, with joblib on 2 processes and on a dask cluster.

The sweep is a real one: a short FastSLAM 1.0 run on the simulator per seed (20 s, M = 20), scored against the
simulator's truth. Each run takes its seed from its job, so every engine must return exactly the same floats, in
the order of the jobs; the serial run (in this process, no pickling) is the reference.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("joblib")
distributed = pytest.importorskip("distributed")

from fastslam_edu.app.sweep import SweepError, add_sweep_options, run_sweep  # noqa: E402
from fastslam_edu.landmark.fastslam import FastSLAMParams, run_fastslam  # noqa: E402
from streams import path_rmse, simulate  # noqa: E402

PARAMS = FastSLAMParams(n_particles=20)
#: (simulation seed, filter seed): two worlds, two filter seeds each; the order is deliberately not sorted
JOBS = [(3, 1), (2, 0), (3, 0), (2, 1)]


def short_run(sim_seed: int, filter_seed: int) -> dict:
    """FastSLAM on a 20 s simulation: the mean path's RMSE [m] against the truth, its last pose (x, y, theta) and the
    mean map of the landmarks it saw [m], as exact floats (any change of seed or of order changes them)."""
    data, log, stream = simulate(sim_seed, duration=20.0)
    result = run_fastslam(stream, PARAMS, np.random.default_rng(filter_seed))
    return {"job": (sim_seed, filter_seed), "path_rmse_m": path_rmse(result.t, result.pose_mean, log),
            "last_pose": result.pose_mean[-1].tolist(), "landmarks": result.landmarks_mean[result.observed].tolist()}


@pytest.fixture(scope="module")
def serial():
    return run_sweep(short_run, JOBS, n_jobs=1)


def test_the_serial_sweep_keeps_the_job_order_and_the_seeds_matter(serial):
    assert [r["job"] for r in serial] == JOBS
    rmse = [r["path_rmse_m"] for r in serial]
    assert all(0.0 < v < 1.0 for v in rmse)  # the filter tracks the simulated path
    assert len(set(rmse)) == len(JOBS)  # another filter seed or world: other numbers (so equality below means something)
    assert serial[0] == short_run(*JOBS[0])  # the same as calling the function directly


def test_joblib_on_two_processes_gives_the_serial_numbers(serial):
    assert run_sweep(short_run, JOBS, n_jobs=2) == serial


def test_a_local_dask_cluster_gives_the_serial_numbers(serial):
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        assert run_sweep(short_run, JOBS, scheduler=cluster.scheduler_address) == serial


@pytest.mark.parametrize("n_jobs", [0, -1, 1.5, True, "2"])
def test_jobs_below_one_or_not_whole_are_refused(n_jobs):
    with pytest.raises(SweepError, match=r"jobs must be a whole number >= 1 \(got "):
        run_sweep(short_run, JOBS, n_jobs=n_jobs)


def test_an_unreachable_scheduler_is_one_clear_line(monkeypatch):
    monkeypatch.setattr("fastslam_edu.app.sweep.CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(SweepError) as error:
        run_sweep(short_run, JOBS, scheduler="tcp://127.0.0.1:9")  # port 9 (discard): nobody listens
    message = str(error.value)
    assert "\n" not in message and "cannot reach the dask scheduler at 'tcp://127.0.0.1:9'" in message


def test_jobs_and_a_scheduler_together_are_refused():
    with pytest.raises(SweepError, match="not both"):
        run_sweep(short_run, JOBS, n_jobs=2, scheduler="tcp://127.0.0.1:9")


def test_the_command_line_options(capsys):
    import argparse

    ap = argparse.ArgumentParser(prog="bench")
    add_sweep_options(ap)
    assert vars(ap.parse_args([])) == {"jobs": None, "scheduler": None}
    assert ap.parse_args(["--jobs", "3"]).jobs == 3
    assert ap.parse_args(["--scheduler", "tcp://h:8786"]).scheduler == "tcp://h:8786"
    for bad, says in ((["--jobs", "0"], "must be >= 1 (got 0)"), (["--jobs", "x"], "not a whole number: 'x'"),
                      (["--jobs", "2", "--scheduler", "tcp://h:8786"], "not allowed with argument")):
        with pytest.raises(SystemExit):
            ap.parse_args(bad)
        assert says in capsys.readouterr().err.splitlines()[-1]
