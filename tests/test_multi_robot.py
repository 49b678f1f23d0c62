"""Several robots in one least-squares problem (fastslam_edu.landmark.multi_robot), on the simulator:
the robot-robot factor's Jacobians against finite differences, two robots that see only each other against the
simulator's relative pose, the joint map against the single-robot ones, one robot against smooth(), bad input."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from fastslam_edu.app.experiment import summarize_smoother
from fastslam_edu.core.motion import MotionNoise
from fastslam_edu.core.se2 import interpolate_poses, relative
from fastslam_edu.core.angles import wrap_angle
from fastslam_edu.datasets.events import event_stream, groundtruth_at
from fastslam_edu.datasets.mrclam import read_dataset, robot_sightings, write_dataset
from fastslam_edu.datasets.sim import simulate_dataset
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.landmark.multi_robot import check_robot_numbers, smooth_robots
from fastslam_edu.landmark.robot_sightings import compose_jacobian
from fastslam_edu.landmark.robot_sightings import compose_unwrapped as compose
from fastslam_edu.landmark.smoother import BEST_ESTIMATE, smooth
from fastslam_edu.landmark.smoother_factors import sighting_residuals

NOISE = MotionNoise(sigma_v=0.01, sigma_omega=0.02)


def _params(**kw):
    """The model matched to the simulation (as tests/test_smoother.py): its noise, its R, no tempering."""
    base = dict(motion_noise=NOISE, measurement_cov=np.diag([0.05**2, 0.02**2]), range_std_slope=0.0,
                measurement_correlation_s=None)
    return FastSLAMParams(**(base | kw))


def _team(seed, n_robots=2, duration=60.0, landmarks=True, **overrides):
    data = simulate_dataset(seed, n_robots=n_robots, see_robots=True, duration=duration, **overrides)
    logs = data.robots if landmarks else {
        r: dataclasses.replace(log, measurements=log.measurements.iloc[:0]) for r, log in data.robots.items()}
    streams = {r: event_stream(log, data.landmark_subjects) for r, log in logs.items()}
    return data, logs, streams, {r: log.robot_sightings for r, log in logs.items()}


def _numeric_jacobian(f, x, h=1e-6):
    return np.stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(len(x))], axis=-1)


def test_robot_sighting_jacobians_match_finite_differences():
    """e(x_a, x_b) = z ⊖ h(x_a ⊕ δ_a, (x_b ⊕ δ_b)_xy): the chain rule through compose_jacobian."""
    rng = np.random.default_rng(0)
    for _ in range(5):
        xa, xb = rng.normal(size=3) * [2, 2, 2], rng.normal(size=3) * [2, 2, 2]
        da, db = rng.normal(size=3) * 0.3, rng.normal(size=3) * 0.3
        z = np.array([2.0, 0.3])

        def e(xa, xb):
            return sighting_residuals(compose(xa[None], da[None]), compose(xb[None], db[None])[:, :2], z[None])[0][0]

        _, Jx, Jm = sighting_residuals(compose(xa[None], da[None]), compose(xb[None], db[None])[:, :2], z[None])
        Ja = Jx[0] @ compose_jacobian(xa[None], da[None])[0]
        Jb = Jm[0] @ compose_jacobian(xb[None], db[None])[0][:2]
        np.testing.assert_allclose(Ja, _numeric_jacobian(lambda x: e(x, xb), xa), atol=1e-6)
        np.testing.assert_allclose(Jb, _numeric_jacobian(lambda x: e(xa, x), xb), atol=1e-6)


def test_keyframe_offsets_carry_the_keyframe_to_the_sighting_time():
    """x̂(t) = x̂_k ⊕ δ: the dead-reckoned pose at any time inside the log, from the keyframe at or before it."""
    from fastslam_edu.landmark.robot_sightings import keyframe_offsets
    from fastslam_edu.landmark.smoother_factors import dead_reckon_stream, keyframe_steps

    data, logs, streams, _ = _team(2, n_robots=1, duration=30.0)
    s = streams[1]
    path, keys = dead_reckon_stream(s, s.x0), keyframe_steps(s)
    t = np.random.default_rng(0).uniform(s.t[0], s.t[-1], 50)
    k, delta = keyframe_offsets(s, path, keys, t)
    assert np.all(s.t[keys[k]] <= t) and np.all(np.abs(delta[:, :2]).max(axis=1) < 0.5)  # keyframes ≤ 1 s apart
    expected = np.stack([np.interp(t, s.t, path[:, i]) for i in range(3)], axis=1)
    np.testing.assert_allclose(compose(path[keys[k]], delta), expected, atol=1e-9)


def test_robot_sightings_are_tempered_per_robot_seen():
    """β = min(1, Δt/τ) with Δt since the observer last saw the same robot (a robot seen is a landmark of its
    observer); other observers and other robots do not count."""
    from fastslam_edu.landmark.robot_sightings import robot_sighting_weights

    observer = np.array([1, 1, 1, 2, 1])
    seen = np.array([2, 2, 3, 1, 2])
    t = np.array([0.0, 1.0, 1.0, 1.5, 4.0])
    np.testing.assert_allclose(robot_sighting_weights(observer, seen, t, 2.0), [1.0, 0.5, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(robot_sighting_weights(observer, seen, t, None), 1.0)


def test_one_robot_is_the_single_robot_smoother():
    data, logs, streams, _ = _team(1, n_robots=1)
    for solver in (BEST_ESTIMATE, BEST_ESTIMATE.replace(tempering=True)):
        single = smooth(streams[1], _params(measurement_correlation_s=2.0), solver=solver)
        joint = smooth_robots(streams, None, _params(measurement_correlation_s=2.0), solver=solver)
        np.testing.assert_array_equal(joint.poses[1], single.poses)
        np.testing.assert_array_equal(joint.landmarks, single.landmarks)
        np.testing.assert_allclose(joint.landmarks_cov, single.landmarks_cov, rtol=1e-9, equal_nan=True)
        assert (joint.iterations, joint.cost, joint.measurements_used) == (single.iterations, single.cost,
                                                                          single.measurements_used)
        assert joint.notes == [] and joint.robot_sightings_used == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_robots_that_see_only_each_other_end_in_their_true_relative_pose(seed):
    """No landmark, no noise; robot 1 starts at the truth, robot 2 1.3 m and 0.5 rad off with a loose prior. Its
    pose relative to robot 1, x_1(t)⁻¹ ⊕ x_2(t), must be the simulator's at every keyframe of robot 2: the mutual
    range–bearing sightings fix it (a sees b: b's position in a's frame; b sees a: b's heading). Left: centimetres,
    from the filter's motion model stepping along the heading where the simulator drives exact arcs (60 s of dead
    reckoning). Without the sightings robot 2 stays metres off."""
    data, logs, streams, sightings = _team(seed, landmarks=False, odometry_noise=MotionNoise(), range_std=0.0,
                                           bearing_std=0.0)
    x0 = {2: streams[2].x0 + [1.0, -0.8, 0.5]}
    loose = {2: (10.0, 10.0, 3.0)}

    def relative_error(result):
        t = result.t[2]
        est = relative(interpolate_poses(t, result.t[1], result.poses[1], tolerance=1.0), result.poses[2])
        true = relative(groundtruth_at(logs[1], t), groundtruth_at(logs[2], t))
        return np.max(np.hypot(*(est - true)[:, :2].T)), np.max(np.abs(wrap_angle(est[:, 2] - true[:, 2])))

    joint = smooth_robots(streams, sightings, _params(), x0=x0, x0_std=loose)
    assert joint.robot_sightings_used > 50 and joint.robot_sightings_gated == 0
    position, heading = relative_error(joint)
    assert position < 0.03 and heading < 0.01
    alone = smooth_robots(streams, None, _params(), x0=x0, x0_std=loose)
    assert relative_error(alone)[0] > 1.0
    assert alone.notes and "no robot-robot sighting" in alone.notes[0]


def test_the_joint_solution_is_at_least_as_good_as_each_robot_alone():
    """Three robots among 15 landmarks, 90 s, seeds 0–3: the joint paths and map (on the landmarks each robot saw)
    against each robot's own smoother. Pooled over the 12 robots, the joint errors are less than half; robot by
    robot, every joint error is under 3 cm where the robots alone reach 16 and 19 cm. (One log is one draw: seed 3
    robot 1 alone is luckier than the joint solution, path 1.3 against 2.0 cm, map 1.1 against 2.4 cm.)"""
    single, joint = [], []
    for seed in range(4):
        data, logs, streams, sightings = _team(seed, n_robots=3, duration=90.0)
        together = smooth_robots(streams, sightings, _params())
        for r in streams:
            s1 = summarize_smoother(smooth(streams[r], _params()), data, logs[r])
            sj = summarize_smoother(together.robot(r), data, logs[r])
            own = [k for k, e in s1["landmark_errors_m"].items() if e is not None]  # the robot's own landmarks
            e1 = np.mean([s1["landmark_errors_m"][k] for k in own])
            ej = np.mean([sj["landmark_errors_m"][k] for k in own])
            assert sj["path_rmse_m"] < 0.03 and ej < 0.03, (seed, r)  # alone: up to 0.16 and 0.19 m
            single.append([s1["path_rmse_m"], e1])
            joint.append([sj["path_rmse_m"], ej])
    assert np.all(np.mean(joint, axis=0) < 0.5 * np.mean(single, axis=0))


def test_robot_sightings_through_the_gate_and_counted():
    data, logs, streams, sightings = _team(4, n_robots=2, duration=60.0)
    bad = {r: s.copy() for r, s in sightings.items()}
    bad[1].loc[bad[1].index[::10], "range"] += 1.5  # one sighting in ten 1.5 m too far
    result = smooth_robots(streams, bad, _params())
    n_bad = len(bad[1].index[::10])
    assert result.robot_sightings_gated == n_bad
    assert result.robot_sightings_used + result.robot_sightings_gated == sum(len(s) for s in sightings.values())


def test_robot_sightings_are_read_back_from_the_files(tmp_path):
    data = simulate_dataset(5, n_robots=3, see_robots=True, duration=30.0)
    back = read_dataset(write_dataset(data, tmp_path))
    for r, log in data.robots.items():
        got = back.robots[r].robot_sightings
        pd.testing.assert_frame_equal(got.reset_index(drop=True), log.robot_sightings.reset_index(drop=True),
                                      check_dtype=False)
        assert back.robots[r].dropped["robot_sightings"] == len(log.robot_sightings)


def test_robot_sightings_refuse_bad_rows():
    barcodes = {10: 1, 11: 2, 12: 6}
    raw = pd.DataFrame({"time": [0.0, 1.0, 2.0], "barcode": [11, 12, 10], "range": [1.0, 2.0, 3.0],
                        "bearing": [0.1, 0.2, 0.3]})
    seen = robot_sightings(raw, barcodes, robots=(1, 2))
    assert seen["subject"].tolist() == [2, 1] and seen["time"].tolist() == [0.0, 2.0]
    with pytest.raises(ValueError, match="robot 1 sees its own barcode 10"):
        robot_sightings(raw.assign(barcode=[10, 12, 11]), barcodes, robot=1, robots=(1, 2))
    with pytest.raises(ValueError, match=r"robot\(s\) \[3\] have no barcode"):
        robot_sightings(raw, barcodes, robots=(1, 2, 3))
    with pytest.raises(ValueError, match="negative range"):
        robot_sightings(raw.assign(range=[-1.0, 2.0, 3.0]), barcodes, robots=(1, 2))
    with pytest.raises(ValueError, match="lack the column"):
        robot_sightings(raw.drop(columns="bearing"), barcodes)


def test_bad_input_gets_one_clear_line():
    data, logs, streams, sightings = _team(6, n_robots=2, duration=20.0)
    for robots, message in (([0, 1], "not a MR.CLAM robot"), ([1, 6], "not a MR.CLAM robot"),
                            ([2, 2], r"robot\(s\) \[2\] given more than once"), ([], "no robot given")):
        with pytest.raises(ValueError, match=message):
            check_robot_numbers(robots)
    with pytest.raises(ValueError, match="not a MR.CLAM robot"):
        smooth_robots({7: streams[1]})
    later = dataclasses.replace(streams[2], t=streams[2].t + 86400.0)  # another day: another dataset
    with pytest.raises(ValueError, match="share no time.*different datasets"):
        smooth_robots({1: streams[1], 2: later})
    other = dataclasses.replace(streams[2], landmark_subjects=streams[2].landmark_subjects + 1)
    with pytest.raises(ValueError, match="different landmark tables"):
        smooth_robots({1: streams[1], 2: other})
    with pytest.raises(ValueError, match="not among the robots solved"):
        smooth_robots({1: streams[1]}, sightings)
    with pytest.raises(ValueError, match="not supported"):
        smooth_robots(streams, sightings, solver=BEST_ESTIMATE.replace(calibrate=("k_v",)))
    for message in (str(e) for e in _errors(streams, sightings)):
        assert "\n" not in message


def _errors(streams, sightings):
    out = []
    for call in (lambda: check_robot_numbers([9]), lambda: smooth_robots({1: streams[1]}, sightings)):
        try:
            call()
        except ValueError as exc:
            out.append(exc)
    assert len(out) == 2
    return out


def test_no_robot_robot_sighting_goes_on_and_says_so():
    data, logs, streams, sightings = _team(6, n_robots=2, duration=30.0)
    empty = {r: s.iloc[:0] for r, s in sightings.items()}
    result = smooth_robots(streams, empty, _params())
    assert result.robot_sightings_used == 0 and np.all(result.observed == smooth(streams[1], _params()).observed
                                                       | smooth(streams[2], _params()).observed)
    assert len(result.notes) == 1 and "no robot-robot sighting between robots 1, 2" in result.notes[0]


# --------------------------------------------------------------------------- the command line, on simulated folders


@pytest.fixture(scope="module")
def team_dir(tmp_path_factory):
    data = simulate_dataset(8, n_robots=3, see_robots=True, duration=30.0)
    return write_dataset(data, tmp_path_factory.mktemp("team") / "MRCLAM_Team")


def _cli(folder, out, *extra):
    from fastslam_edu.app.cli import main

    return main(["run", "--data", str(folder), "--particles", "20", "--quiet", "--json", str(out), *extra])


def test_cli_robots_smooth_writes_every_robot_and_the_shared_map(team_dir, tmp_path, capsys):
    assert _cli(team_dir, tmp_path / "out.json", "--robots", "1,2,3", "--smooth") == 0
    assert "robot2.path_rmse_m" in capsys.readouterr().out
    sm = json.loads((tmp_path / "out.json").read_text())["smoother"]
    assert sorted(sm["robots"]) == ["1", "2", "3"]
    for figures in sm["robots"].values():
        assert 0 <= figures["path_rmse_aligned_m"] <= figures["path_rmse_m"] < 0.2
    assert sm["landmark_error_mean_m"] < 0.2 and sm["landmark_error_aligned_mean_m"] < 0.2
    assert sm["robot_sightings_used"] > 0 and sm["robot_sightings_gated"] >= 0


def test_cli_one_robot_in_robots_is_robot(team_dir, tmp_path):
    assert _cli(team_dir, tmp_path / "a.json", "--robots", "2", "--smooth") == 0
    assert _cli(team_dir, tmp_path / "b.json", "--robot", "2", "--smooth") == 0
    a, b = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))
    for d in (a, b, a["smoother"], b["smoother"]):
        for k in [k for k in d if "seconds" in k]:
            d.pop(k)
    assert a == b


@pytest.mark.parametrize("robots, code, message", [
    ("1,7", 2, "not a MR.CLAM robot"), ("1,1", 2, "given more than once"), ("1,x", 2, "separated by commas")])
def test_cli_bad_robot_lists(team_dir, tmp_path, capsys, robots, code, message):
    with pytest.raises(SystemExit) as exit_:
        _cli(team_dir, tmp_path / "out.json", "--robots", robots, "--smooth")
    err = capsys.readouterr().err
    assert exit_.value.code == code and err.count("\n") == 1 and message in err
    assert not (tmp_path / "out.json").exists()


def test_cli_bad_input_one_line_nothing_written(team_dir, tmp_path, capsys):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(team_dir, broken)
    (broken / "Robot3_Measurement.dat").unlink()
    out = tmp_path / "out.json"
    for folder, extra, message in (
            (broken, ("--robots", "1,3", "--smooth"), "Robot3_Measurement.dat"),
            (team_dir, ("--robots", "1,2"), "add --smooth"),
            (team_dir, ("--robots", "1,2", "--smooth", "--filter", "ekf"), "not available with several robots"),
            (team_dir, ("--robot", "1", "--robots", "1,2", "--smooth"), "not both")):
        assert _cli(folder, out, *extra) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
        assert not out.exists()


def test_cli_without_robot_sightings_goes_on_and_says_so(tmp_path, capsys):
    folder = write_dataset(simulate_dataset(9, n_robots=2, duration=20.0), tmp_path / "MRCLAM_Alone")
    assert _cli(folder, tmp_path / "out.json", "--robots", "1,2", "--smooth") == 0
    assert "no robot-robot sighting between robots 1, 2" in capsys.readouterr().err
    assert json.loads((tmp_path / "out.json").read_text())["smoother"]["robot_sightings_used"] == 0


def _shift_times(folder, robot: int, seconds: float) -> None:
    """Move one robot's files ``seconds`` later (a robot of another day's recording: another dataset)."""
    for kind in ("Odometry", "Measurement", "Groundtruth"):
        f = folder / f"Robot{robot}_{kind}.dat"
        lines = [line if line.startswith("#") or not line.strip() else
                 "\t".join([repr(float(line.split("\t")[0]) + seconds), *line.split("\t")[1:]])
                 for line in f.read_text().splitlines()]
        f.write_text("\n".join(lines) + "\n")


def test_cli_robots_from_different_datasets_refused_before_the_filters(team_dir, tmp_path, capsys, monkeypatch):
    import shutil

    import fastslam_edu.app.multi_robot as app_multi

    mixed = tmp_path / "mixed"
    shutil.copytree(team_dir, mixed)
    _shift_times(mixed, 2, 86400.0)
    monkeypatch.setattr(app_multi, "run_fastslam", lambda *a, **k: pytest.fail("the filter ran before the check"))
    out = tmp_path / "out.json"
    assert _cli(mixed, out, "--robots", "1,2", "--smooth") == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "robots 1 and 2 share no time" in err and "different datasets" in err, err
    assert not out.exists()


def test_cli_robot_without_groundtruth_hints_at_what_works(team_dir, tmp_path, capsys):
    """Dataset 1's robots 3-5 have no groundtruth: the line names them and --x0 landmarks (which --robots takes),
    not --groundtruth (which --robots refuses); with --x0 landmarks the run goes through."""
    import shutil

    bare = tmp_path / "bare"
    shutil.copytree(team_dir, bare)
    (bare / "Robot2_Groundtruth.dat").unlink()
    (bare / "Robot3_Groundtruth.dat").unlink()
    out = tmp_path / "out.json"
    assert _cli(bare, out, "--robots", "1,2,3", "--smooth") == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "robot(s) 2, 3" in err and "--x0 landmarks" in err and "--groundtruth" not in err
    assert not out.exists()
    assert _cli(bare, out, "--robots", "1,2", "--smooth", "--x0", "landmarks") == 0
    sm = json.loads(out.read_text())["smoother"]
    assert sm["robots"]["2"]["path_rmse_m"] is None and sm["robots"]["1"]["path_rmse_m"] < 0.3


def test_cli_one_pose_for_several_robots_is_refused(team_dir, tmp_path, capsys):
    out = tmp_path / "out.json"
    assert _cli(team_dir, out, "--robots", "1,2", "--smooth", "--x0=1,2,0") == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--x0 landmarks" in err
    assert not out.exists()


def test_cli_robots_gtsam_backend_refused_without_gtsam(team_dir, tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "gtsam", None)  # `import gtsam` raises ImportError
    out = tmp_path / "out.json"
    assert _cli(team_dir, out, "--robots", "1,2", "--smooth", "--smoother-backend", "gtsam") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "[graph]" in err and "Traceback" not in err
    assert not out.exists()


def test_cli_robots_gtsam_and_scipy_agree(team_dir, tmp_path, capsys):
    """The same joint problem (same filter runs, same gate) solved by both backends: every JSON figure of the paths
    and the shared map within 1 mm, the cost within 1e-6 relative, Laplace σ within 1 %; backend and seconds given."""
    pytest.importorskip("gtsam")
    runs = {}
    for backend in ("scipy", "gtsam"):
        assert _cli(team_dir, tmp_path / f"{backend}.json", "--robots", "1,2", "--smooth",
                    "--smoother-backend", backend) == 0
        runs[backend] = json.loads((tmp_path / f"{backend}.json").read_text())["smoother"]
    s, g = runs["scipy"], runs["gtsam"]
    assert (s["backend"], g["backend"]) == ("scipy", "gtsam") and s["seconds"] > 0 and g["seconds"] > 0
    for r in ("1", "2"):
        for key in ("path_rmse_m", "path_rmse_aligned_m", "path_mean_m", "path_max_m"):
            assert g["robots"][r][key] == pytest.approx(s["robots"][r][key], abs=1e-3), (r, key)
    assert sorted(g["landmark_errors_m"]) == sorted(s["landmark_errors_m"]) and len(s["landmark_errors_m"]) > 5
    for subject, error in s["landmark_errors_m"].items():
        assert g["landmark_errors_m"][subject] == pytest.approx(error, abs=1e-3), subject
    for key in ("landmark_error_mean_m", "landmark_error_aligned_mean_m"):
        assert g[key] == pytest.approx(s[key], abs=1e-3), key
    assert g["cost"] == pytest.approx(s["cost"], rel=1e-6)
    assert g["landmark_std_mean_m"] == pytest.approx(s["landmark_std_mean_m"], rel=0.01)
    assert (g["robot_sightings_used"], g["measurements_used"]) == (s["robot_sightings_used"], s["measurements_used"])


def test_run_mrclam_robots_checks_the_backend_before_the_filters(team_dir, monkeypatch):
    import sys

    import fastslam_edu.app.multi_robot as app_multi

    monkeypatch.setattr(app_multi, "run_fastslam", lambda *a, **k: pytest.fail("the filter ran before the check"))
    with pytest.raises(ValueError, match="backend must be 'scipy' or 'gtsam', got 'ceres'"):
        app_multi.run_mrclam_robots(team_dir, (1, 2), backend="ceres")
    monkeypatch.setitem(sys.modules, "gtsam", None)
    with pytest.raises(ImportError, match=r"fastslam-edu\[graph\]"):
        app_multi.run_mrclam_robots(team_dir, (1, 2), backend="gtsam")
