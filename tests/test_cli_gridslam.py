"""``fastslam-edu gridslam`` on a simulated office written as Intel-JSON and CARMEN files (no real data)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fastslam_edu.app.cli import main
from fastslam_edu.core.se2 import relative
from fastslam_edu.datasets.sim_laser import simulate_laser_world

N_SCANS = 120
NO_RETURN = 81.83


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    w = simulate_laser_world(2)
    d = tmp_path_factory.mktemp("laser")
    t = 976052890.0 + 2.0 * np.arange(len(w.truth))
    ranges = np.where(np.isfinite(w.log.ranges), w.log.ranges, NO_RETURN)

    def write_json(path, poses):
        doc = {"map": {f"{ti:.6f}": {"range": r.tolist(), "x": p[0], "y": p[1], "theta": p[2]}
                       for ti, r, p in zip(t, ranges, poses)}}
        path.write_text(json.dumps(doc))

    write_json(d / "sim_gfs.json", w.log.poses)  # raw odometry, like intel_gfs.json
    write_json(d / "sim_corrected.json", w.truth)  # "reference" = the truth
    # relations from the truth: consecutive scans and some long ones, plus one with a time off by 0.5 s
    pairs = [(i, i + 1) for i in range(0, N_SCANS - 1, 3)] + [(0, 100), (10, 110)]
    lines = []
    for i, j in pairs:
        dlt = relative(w.truth[i], w.truth[j])
        lines.append(f"{t[i]:.6f} {t[j]:.6f} {dlt[0]:.6f} {dlt[1]:.6f} 0 0 0 {dlt[2]:.6f}")
    lines.append(f"{t[5] + 0.5:.6f} {t[6]:.6f} 0.1 0 0 0 0 0")
    (d / "sim.relations").write_text("\n".join(lines) + "\n")
    # the same scans as a raw CARMEN log: ODOM then FLASER with the odometry pose
    rows = []
    for k in range(len(t)):
        x, y, th = w.log.poses[k]
        rows.append(f"ODOM {x:.6f} {y:.6f} {th:.6f} 0 0 0 {t[k]:.6f} sim {t[k]:.6f}")
        rr = " ".join(f"{v:.3f}" for v in ranges[k])
        rows.append(f"FLASER {ranges.shape[1]} {rr} {x:.6f} {y:.6f} {th:.6f} {x:.6f} {y:.6f} {th:.6f} "
                    f"{t[k]:.6f} sim {t[k]:.6f}")
    (d / "sim.log").write_text("\n".join(rows) + "\n")
    return d, len(pairs)


def run(d, tmp_path, *extra):
    return main(["gridslam", "--scans", str(d / "sim_gfs.json"), "--particles", "10", "--quiet",
                 "--scans-limit", str(N_SCANS), "--json", str(tmp_path / "out.json"), *extra])


def test_json_metrics_against_the_known_truth(files, tmp_path, capsys):
    d, n_pairs = files
    rc = run(d, tmp_path, "--reference", str(d / "sim_corrected.json"), "--relations", str(d / "sim.relations"),
             "--map", str(tmp_path / "map.png"))
    assert rc == 0
    out = capsys.readouterr()
    assert out.err == "" and "relation_trans_error_m" in out.out
    s = json.loads((tmp_path / "out.json").read_text())
    assert s["n_scans"] == N_SCANS and s["params"]["n_particles"] == 10 and s["seed"] == 0
    assert s["filter_seconds"] > 0 and s["format"] == "intel-json"
    assert s["reference"]["n_matched"] == N_SCANS
    rel = s["relations"]
    assert rel["estimate"]["n_relations"] == n_pairs + 1
    assert rel["estimate"]["n_used"] == n_pairs  # the one 0.5 s off is not used
    assert rel["reference"]["trans_mean_m"] < 1e-5  # the reference is the truth the relations came from
    assert rel["estimate"]["trans_mean_m"] < 0.5 * rel["odometry"]["trans_mean_m"]
    assert s["reference"]["rmse_m"] < 0.3 * s["reference"]["odometry_rmse_m"]
    assert (tmp_path / "map.png").stat().st_size > 1000


def test_carmen_input_gives_the_same_run_as_json(files, tmp_path, capsys):
    d, _ = files
    assert run(d, tmp_path, "--no-scan-match") == 0
    a = json.loads((tmp_path / "out.json").read_text())
    rc = main(["gridslam", "--scans", str(d / "sim.log"), "--particles", "10", "--quiet", "--no-scan-match",
               "--scans-limit", str(N_SCANS), "--json", str(tmp_path / "b.json"),
               "--relations", str(d / "sim.relations")])
    assert rc == 0
    b = json.loads((tmp_path / "b.json").read_text())
    assert b["format"] == "carmen" and b["params"]["match_iterations"] == 0
    assert b["n_scans"] == a["n_scans"] and b["resampling_steps"] == a["resampling_steps"]
    assert b["relations"]["estimate"]["n_used"] > 0


def test_writeup_flag_sets_the_writeup_rule(files, tmp_path):
    d, _ = files
    assert run(d, tmp_path, "--writeup") == 0
    p = json.loads((tmp_path / "out.json").read_text())["params"]
    assert (p["hit_sigma"], p["resample_threshold"], p["match_iterations"]) == (0.0, 1.0, 0)


def test_errors_are_one_line_with_nonzero_exit(files, tmp_path, capsys):
    d, _ = files
    assert main(["gridslam", "--scans", str(tmp_path / "missing.log"), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.log" in err[0] and "no such file" in err[0]
    (tmp_path / "x.mat").write_bytes(b"")
    assert main(["gridslam", "--scans", str(tmp_path / "x.mat"), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "THOR" in err[0] and "--joints" in err[0]
    bad = tmp_path / "bad.log"
    bad.write_text("FLASER 3 1.0 2.0\n")
    assert main(["gridslam", "--scans", str(bad), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.log:1" in err[0]
    with pytest.raises(SystemExit) as exc:
        main(["gridslam", "--scans", str(d / "sim.log"), "--particles", "0"])
    assert exc.value.code == 2
    assert "positive integer" in capsys.readouterr().err


def test_relations_in_another_time_base_give_a_note(files, tmp_path, capsys):
    d, _ = files
    shifted = tmp_path / "shifted.relations"
    shifted.write_text("".join(
        f"{float(a) - 1000:.6f} {float(b) - 1000:.6f} {' '.join(rest)}\n"
        for a, b, *rest in (ln.split() for ln in (d / "sim.relations").read_text().splitlines())))
    assert run(d, tmp_path, "--relations", str(shifted), "--scans-limit", "20") == 0
    assert "different time bases" in capsys.readouterr().err
    s = json.loads((tmp_path / "out.json").read_text())
    assert s["relations"]["estimate"]["n_used"] == 0 and s["relations"]["estimate"]["trans_mean_m"] is None
