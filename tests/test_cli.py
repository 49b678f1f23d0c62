"""Tests of the command line ``fastslam-edu run`` (fastslam_edu.app.cli) on a simulated dataset.

The dataset is simulated and written in the MR.CLAM format with
``write_dataset``; the figures in the JSON are checked against what can be
counted in the files independently (steps = distinct odometry/measurement
times, measurements used + rejected = the measurement rows) and against
properties of the metrics (an aligned RMSE is never larger than the raw one,
the maximum never smaller than the RMSE).
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fastslam_edu.app.cli import main
from fastslam_edu.datasets.mrclam import write_dataset
from fastslam_edu.datasets.sim import simulate_dataset

KEYS = (
    "landmark_error_mean_m", "landmark_error_aligned_mean_m", "path_rmse_m", "path_rmse_aligned_m",
    "path_max_m", "steps", "measurements_used", "measurements_rejected", "filter_seconds", "params", "seed",
)


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory) -> Path:
    data = simulate_dataset(4, duration=30.0)
    return write_dataset(data, tmp_path_factory.mktemp("sim") / "MRCLAM_Sim")


def data_rows(path: Path) -> np.ndarray:
    return np.loadtxt(path, comments="#", ndmin=2)


def run_cli(dataset_dir: Path, out: Path, *extra: str) -> int:
    return main(["run", "--data", str(dataset_dir), "--robot", "1", "--particles", "20",
                 "--json", str(out / "out.json"), "--quiet", *extra])


def test_sightings_of_unknown_barcodes_are_skipped_and_reported(dataset_dir, tmp_path, capsys):
    """A misread barcode (one in no table) is not a landmark: the run skips it, says so on stderr naming the
    barcode and the count, and the JSON counts it with the robot sightings."""
    folder = tmp_path / "MRCLAM_Sim"
    shutil.copytree(dataset_dir, folder)
    path = folder / "Robot1_Measurement.dat"
    lines = path.read_text().splitlines(keepends=True)
    rows = [i for i, line in enumerate(lines) if not line.startswith("#")]
    for i in rows[10:13]:  # three sightings now carry barcode 96, which no subject has
        fields = lines[i].split("\t")
        fields[1] = "96"
        lines[i] = "\t".join(fields)
    path.write_text("".join(lines))
    assert main(["run", "--data", str(folder), "--robot", "1", "--particles", "20",
                 "--json", str(tmp_path / "out.json")]) == 0
    err = capsys.readouterr().err
    assert "3 sighting(s) of barcodes in no table skipped: 96 (3x)" in err
    summary = json.loads((tmp_path / "out.json").read_text())
    assert summary["sightings_skipped"]["unknown_barcodes"] == {"96": 3}
    assert summary["sightings_skipped"]["robot_sightings"] == 0  # one simulated robot: nobody else to see
    assert summary["measurements_used"] + summary["measurements_rejected"] == len(rows) - 3


def test_run_writes_json_and_plot(dataset_dir, tmp_path, capsys):
    assert run_cli(dataset_dir, tmp_path, "--plot", str(tmp_path / "out.png")) == 0
    captured = capsys.readouterr()
    assert captured.err == ""  # --quiet, no notes for a consistent table
    assert "path_rmse_m" in captured.out
    summary = json.loads((tmp_path / "out.json").read_text())
    assert set(KEYS) <= set(summary)
    for k in KEYS[:5]:
        assert isinstance(summary[k], float) and math.isfinite(summary[k]), k
    # counted from the files
    odo = data_rows(dataset_dir / "Robot1_Odometry.dat")
    meas = data_rows(dataset_dir / "Robot1_Measurement.dat")
    assert summary["steps"] == len(np.unique(np.concatenate([odo[:, 0], meas[:, 0]])))
    assert summary["measurements_used"] + summary["measurements_rejected"] == len(meas)
    assert 0 <= summary["measurements_rejected"] <= 0.05 * len(meas)
    # plausible: a 30 s simulation, default filter noise (larger than the simulator's);
    # measured: path RMSE 0.23 m (0.05 m aligned), landmarks 0.34 m (0.02 m aligned)
    assert 0 < summary["path_rmse_aligned_m"] <= summary["path_rmse_m"] + 1e-12 <= summary["path_max_m"] + 1e-12
    assert summary["path_rmse_m"] < 1.0 and summary["path_rmse_aligned_m"] < 0.2
    assert 0 < summary["landmark_error_aligned_mean_m"] < 0.2 and summary["landmark_error_mean_m"] < 1.5
    assert summary["filter_seconds"] >= 0
    assert summary["seed"] == 0 and summary["params"]["n_particles"] == 20
    assert summary["params"]["mode"] == "slam" and summary["params"]["resampler"] == "systematic"
    png = (tmp_path / "out.png").read_bytes()
    assert len(png) > 10_000 and png[:8] == b"\x89PNG\r\n\x1a\n"


def test_same_seed_same_figures(dataset_dir, tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "c").mkdir()
    assert run_cli(dataset_dir, tmp_path / "a", "--seed", "3") == 0
    assert run_cli(dataset_dir, tmp_path / "b", "--seed", "3") == 0
    assert run_cli(dataset_dir, tmp_path / "c", "--seed", "4") == 0
    a, b, c = (json.loads((tmp_path / d / "out.json").read_text()) for d in "abc")
    for s in (a, b, c):
        s.pop("filter_seconds")
    assert a == b
    assert a["seed"] == 3 and c["seed"] == 4
    assert a["path_rmse_m"] != c["path_rmse_m"]


def test_proposal_option(dataset_dir, tmp_path, capsys):
    """--proposal fastslam2 runs FastSLAM 2.0's proposal and says so in the JSON; an unknown one is refused."""
    assert run_cli(dataset_dir, tmp_path, "--proposal", "fastslam2") == 0
    summary = json.loads((tmp_path / "out.json").read_text())
    assert summary["params"]["proposal"] == "fastslam2"
    assert summary["path_rmse_aligned_m"] < 0.2 and summary["landmark_error_aligned_mean_m"] < 0.2
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        run_cli(dataset_dir, tmp_path, "--proposal", "fastslam3")
    assert exit_info.value.code != 0
    assert "invalid choice: 'fastslam3'" in capsys.readouterr().err


def test_smooth_option(dataset_dir, tmp_path, capsys):
    """--smooth adds the least-squares solution's figures (under "smoother"); on a simulated log its map's shape is
    at least as good as that of the filter's run it started from (within 1 cm); not with --mode localize."""
    assert run_cli(dataset_dir, tmp_path, "--smooth") == 0
    out = capsys.readouterr().out
    assert "smoother.path_rmse_m" in out
    summary = json.loads((tmp_path / "out.json").read_text())
    sm = summary["smoother"]
    for k in KEYS[:5]:
        assert isinstance(sm[k], float) and math.isfinite(sm[k]), k
    assert sm["landmark_error_aligned_mean_m"] <= summary["landmark_error_aligned_mean_m"] + 0.01
    assert sm["measurements_used"] + sm["measurements_rejected"] <= summary["measurements_used"] + summary[
        "measurements_rejected"]
    assert run_cli(dataset_dir, tmp_path, "--smooth", "--mode", "localize") == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--smooth solves full SLAM" in err


def test_initial_pose_from_the_landmarks_for_a_robot_without_groundtruth(dataset_dir, tmp_path, capsys):
    """--x0 landmarks: the start from the first sightings of the surveyed landmarks; --x0 X,Y,THETA as given."""
    blind = tmp_path / "blind"
    shutil.copytree(dataset_dir, blind)
    start = data_rows(blind / "Robot1_Groundtruth.dat")[0]
    (blind / "Robot1_Groundtruth.dat").unlink()
    assert main(["run", "--data", str(blind), "--robot", "1", "--quiet"]) == 1
    assert "--x0 landmarks" in one_error_line(capsys)
    assert run_cli(blind, tmp_path, "--x0", "landmarks") == 0
    assert "initial pose from" in capsys.readouterr().err
    summary = json.loads((tmp_path / "out.json").read_text())
    assert summary["path_rmse_m"] is None  # nothing to score the path against
    assert any(n.startswith("initial pose from") for n in summary["notes"])
    x0 = np.array(summary["x0"])
    assert np.hypot(*(x0[:2] - start[1:3])) < 0.15 and abs(x0[2] - start[3]) < 0.1  # the simulation's start (to 3 deg)
    assert summary["landmark_error_aligned_mean_m"] < 0.2 and summary["landmark_error_mean_m"] < 1.5
    # an explicit pose is used as given: the true start gives the groundtruth run's map
    given = ",".join(f"{v:.12g}" for v in start[1:4])
    assert run_cli(blind, tmp_path, f"--x0={given}") == 0  # with '=': a pose may start with a minus sign
    explicit = json.loads((tmp_path / "out.json").read_text())
    np.testing.assert_allclose(explicit["x0"], start[1:4], atol=1e-9)
    assert run_cli(dataset_dir, tmp_path) == 0
    truth_start = json.loads((tmp_path / "out.json").read_text())
    assert explicit["landmark_error_mean_m"] == pytest.approx(truth_start["landmark_error_mean_m"], abs=1e-3)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        run_cli(blind, tmp_path, "--x0", "1,2")
    assert exit_info.value.code == 2 and "X,Y,THETA" in one_error_line(capsys)


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def test_missing_folder(tmp_path, capsys):
    assert main(["run", "--data", str(tmp_path / "nowhere"), "--robot", "1", "--quiet"]) != 0
    assert "nowhere" in one_error_line(capsys)


def test_robot_without_odometry_file(dataset_dir, capsys):
    assert main(["run", "--data", str(dataset_dir), "--robot", "3", "--quiet"]) != 0
    assert "Robot3_Odometry.dat" in one_error_line(capsys)


def test_robot_zero_is_refused(dataset_dir, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--data", str(dataset_dir), "--robot", "0", "--quiet"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert "--robot" in last and "0" in last


def test_robot_zero_gives_one_line(dataset_dir, capsys):
    with pytest.raises(SystemExit):
        main(["run", "--data", str(dataset_dir), "--robot", "0", "--quiet"])
    one_error_line(capsys)


@pytest.mark.parametrize(
    "file, bad_line, expected",
    [
        ("Robot1_Odometry.dat", "1248272303.5\tfast\t0.1\n", "is not a number"),
        ("Robot1_Measurement.dat", "1248272303.5\t28\t1.0\n", "expected 4 columns"),
        ("Landmark_Groundtruth.dat", "21\t1.0\tnan\t0.0\t0.0\n", "NaN"),
    ],
    ids=["text-in-odometry", "short-measurement-row", "nan-landmark"],
)
def test_malformed_file(dataset_dir, tmp_path, capsys, file, bad_line, expected):
    broken = tmp_path / "broken"
    shutil.copytree(dataset_dir, broken)
    path = broken / file
    lines = path.read_text().splitlines(keepends=True)
    at = min(len(lines), 40)  # a data line in the middle (line numbers count from 1)
    lines.insert(at, bad_line)
    path.write_text("".join(lines))
    assert main(["run", "--data", str(broken), "--robot", "1", "--quiet"]) == 1
    line = one_error_line(capsys)
    assert file in line and f"line {at + 1}" in line and expected in line


def test_console_script(dataset_dir, tmp_path):
    exe = Path(sys.executable).parent / "fastslam-edu"
    assert exe.exists(), exe
    out = tmp_path / "cs.json"
    proc = subprocess.run(
        [str(exe), "run", "--data", str(dataset_dir), "--robot", "1", "--particles", "5", "--quiet",
         "--json", str(out)],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "path_rmse_m" in proc.stdout
    assert json.loads(out.read_text())["params"]["n_particles"] == 5
    bad = subprocess.run([str(exe), "run", "--data", str(tmp_path / "nowhere"), "--robot", "1"],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1 and len(bad.stderr.strip().splitlines()) == 1
