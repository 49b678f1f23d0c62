"""MR.CLAM reader and writer: round trip, barcode mapping, and clear errors on bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.datasets.mrclam import (
    landmark_sightings,
    read_barcodes,
    read_dataset,
    read_groundtruth,
    read_groundtruth_csv,
    read_landmark_groundtruth,
    read_measurements,
    read_odometry,
    read_robot,
    robots_in,
    write_dataset,
)

HEADER = "# UTIAS MR.CLAM\r\n# produced by a test\r\n# Data Format:\r\n# columns\r\n"

# Barcodes: robots 1, 2 and landmarks 6, 7, 8; subject 9 has a barcode but no groundtruth.
BARCODES = {5: 1, 14: 2, 72: 6, 27: 7, 54: 8, 70: 9}
LANDMARKS = pd.DataFrame(
    {"x": [1.5, -2.25, 3.0], "y": [0.5, 4.0, -1.125], "x_std": [1e-4, 2e-4, 3e-4], "y_std": [4e-4, 5e-4, 6e-4]},
    index=pd.Index([6, 7, 8], name="subject"),
)


def write(path: Path, rows: list[str], header: str = HEADER, newline: str = "\r\n") -> Path:
    path.write_text(header + "".join(r + newline for r in rows), encoding="utf-8", newline="")
    return path


def make_dataset(rng: np.random.Generator) -> Dataset:
    """Two robots with random numbers (times sorted, some repeated); robot 2 has no groundtruth."""
    robots = {}
    for n, with_gt in ((1, True), (2, False)):
        t_odo = np.sort(1.2e9 + rng.uniform(0, 50, 300))
        odometry = pd.DataFrame({"time": t_odo, "v": rng.normal(0, 0.1, 300), "omega": rng.normal(0, 0.3, 300)})
        t_m = np.sort(np.repeat(1.2e9 + rng.uniform(0, 50, 40), 2))  # pairs at one instant
        measurements = pd.DataFrame({
            "time": t_m, "subject": rng.choice([6, 7, 8], t_m.size).astype(np.int64),
            "range": rng.uniform(0.5, 6, t_m.size), "bearing": rng.uniform(-0.6, 0.6, t_m.size),
        })
        gt = None
        if with_gt:
            t_g = 1.2e9 + np.arange(0, 50, 0.01)
            gt = pd.DataFrame({"time": t_g, "x": rng.normal(size=t_g.size), "y": rng.normal(size=t_g.size),
                               "theta": rng.uniform(-np.pi, np.pi, t_g.size)})
        robots[n] = RobotLog(robot=n, odometry=odometry, measurements=measurements, groundtruth=gt,
                             dropped={}, source="test")
    return Dataset(path=None, barcodes=dict(BARCODES), landmarks=LANDMARKS.copy(), robots=robots)


# --------------------------------------------------------------------------
# round trip
# --------------------------------------------------------------------------


def test_write_read_round_trip_is_exact(tmp_path):
    ds = make_dataset(np.random.default_rng(1))
    folder = write_dataset(ds, tmp_path / "MRCLAM_DatasetX")
    back = read_dataset(folder)
    assert back.barcodes == ds.barcodes
    pd.testing.assert_frame_equal(back.landmarks, ds.landmarks)
    assert sorted(back.robots) == [1, 2]
    for n, log in ds.robots.items():
        got = back.robots[n]
        pd.testing.assert_frame_equal(got.odometry, log.odometry)
        pd.testing.assert_frame_equal(got.measurements, log.measurements)
        assert got.dropped == {"robot_sightings": 0, "unknown_barcodes": {}, "subjects_without_groundtruth": {}}
        assert got.source == str(folder)
    pd.testing.assert_frame_equal(back.robots[1].groundtruth, ds.robots[1].groundtruth, check_flags=False)
    assert back.robots[1].groundtruth.attrs["rate"] == "full"
    assert back.robots[2].groundtruth is None
    np.testing.assert_array_equal(back.landmark_subjects, [6, 7, 8])


def test_written_files_follow_the_format(tmp_path):
    """Checked with plain str.split, independently of the reader."""
    ds = make_dataset(np.random.default_rng(2))
    folder = write_dataset(ds, tmp_path)
    lines = (folder / "Robot1_Measurement.dat").read_text().splitlines()
    assert all(line.startswith("#") for line in lines[:4]) and not lines[4].startswith("#")
    fields = [line.split() for line in lines[4:]]
    assert len(fields) == len(ds.robots[1].measurements)
    # column 2 holds barcodes, not subjects
    subject_of = BARCODES
    got_subjects = [subject_of[int(f[1])] for f in fields]
    assert got_subjects == ds.robots[1].measurements["subject"].tolist()
    assert [float(f[0]) for f in fields] == ds.robots[1].measurements["time"].tolist()
    barcode_lines = (folder / "Barcodes.dat").read_text().splitlines()[4:]
    assert [tuple(map(int, line.split())) for line in barcode_lines] == sorted((s, b) for b, s in BARCODES.items())


def test_one_hz_groundtruth_round_trips_to_csv(tmp_path):
    ds = make_dataset(np.random.default_rng(3))
    gt = pd.DataFrame({"time": [10.0, 11.0, 12.0], "x": [0.0, 0.5, 1.0], "y": [1.0, 1.0, 1.0], "theta": [0.0, 0.1, 0.2]})
    gt.attrs["rate"] = "1hz"
    log = ds.robots[2]
    ds.robots[2] = RobotLog(2, log.odometry, log.measurements, gt, {}, "test")
    write_dataset(ds, tmp_path)
    assert not (tmp_path / "Robot2_Groundtruth.dat").exists()
    csv = tmp_path / "groundtruth_1hz" / "Robot2_Groundtruth_1hz.csv"
    assert csv.read_text().splitlines()[0] == "Time,X,Y,Orientation"
    back = read_groundtruth(tmp_path, 2)
    assert back.attrs["rate"] == "1hz"
    np.testing.assert_array_equal(back.to_numpy(), gt.to_numpy())


def test_write_rejects_nan_and_subject_without_barcode(tmp_path):
    ds = make_dataset(np.random.default_rng(4))
    ds.robots[1].odometry.loc[5, "v"] = np.nan
    with pytest.raises(ValueError, match=r"robot 1 odometry: row 5 .*NaN"):
        write_dataset(ds, tmp_path / "a")
    ds = make_dataset(np.random.default_rng(4))
    ds.robots[2].measurements.loc[0, "subject"] = 12
    with pytest.raises(ValueError, match=r"subjects \[12\] have no barcode"):
        write_dataset(ds, tmp_path / "b")


# --------------------------------------------------------------------------
# barcodes -> subjects, drops
# --------------------------------------------------------------------------


def write_small_folder(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    write(folder / "Barcodes.dat", [f"  {s} \t {b} " for b, s in sorted(BARCODES.items(), key=lambda p: p[1])])
    write(folder / "Landmark_Groundtruth.dat",
          [f"{s}\t{r.x}\t{r.y}\t{r.x_std}\t{r.y_std}" for s, r in LANDMARKS.iterrows()])
    write(folder / "Robot1_Odometry.dat", ["100.0\t0.1\t0.0", "100.5\t0.2\t-0.1", "100.5\t0.2\t-0.2"])
    write(folder / "Robot1_Measurement.dat", [
        "100.1\t72\t1.0\t0.1",   # subject 6
        "100.1\t14\t2.0\t0.2",   # robot 2: dropped
        "100.2\t43\t3.0\t0.3",   # unknown barcode
        "100.3\t27\t4.0\t-0.4",  # subject 7
        "100.3\t43\t5.0\t0.5",   # unknown barcode again
        "100.4\t70\t6.0\t0.6",   # subject 9: barcode but no groundtruth
        "100.4\t54\t7.0\t-0.7",  # subject 8
        "100.4\t72\t8.0\t0.8",   # subject 6
    ])
    return folder


def test_barcodes_map_to_subjects_and_drops_are_counted(tmp_path):
    folder = write_small_folder(tmp_path / "ds")
    assert read_barcodes(folder / "Barcodes.dat") == BARCODES
    log = read_robot(folder, 1, BARCODES, [6, 7, 8])
    m = log.measurements
    assert m["subject"].tolist() == [6, 7, 8, 6]
    assert m["time"].tolist() == [100.1, 100.3, 100.4, 100.4]
    assert m["range"].tolist() == [1.0, 4.0, 7.0, 8.0]
    assert m["bearing"].tolist() == [0.1, -0.4, -0.7, 0.8]
    assert m["subject"].dtype == np.int64
    assert log.dropped == {"robot_sightings": 1, "unknown_barcodes": {43: 2}, "subjects_without_groundtruth": {9: 1}}
    assert log.groundtruth is None
    # repeated odometry times are kept as they are
    assert log.odometry["time"].tolist() == [100.0, 100.5, 100.5]


def test_landmark_sightings_on_a_frame():
    raw = pd.DataFrame({"time": [1.0, 2.0, 3.0], "barcode": [5, 27, 99], "range": [1.0, 2.0, 3.0],
                        "bearing": [0.0, 0.1, 0.2]})
    m, dropped = landmark_sightings(raw, BARCODES, [6, 7, 8])
    assert m.to_dict("list") == {"time": [2.0], "subject": [7], "range": [2.0], "bearing": [0.1]}
    assert dropped["robot_sightings"] == 1 and dropped["unknown_barcodes"] == {99: 1}


def test_landmark_groundtruth_sorted_by_subject(tmp_path):
    p = write(tmp_path / "Landmark_Groundtruth.dat", ["8\t3.0\t-1.0\t0.1\t0.2", "6\t1.0\t2.0\t0.3\t0.4"])
    lm = read_landmark_groundtruth(p)
    assert lm.index.tolist() == [6, 8] and lm.index.name == "subject"
    assert lm.loc[8].tolist() == [3.0, -1.0, 0.1, 0.2]


def test_groundtruth_prefers_full_rate_and_reads_csv_with_blank_lines(tmp_path):
    sub = tmp_path / "groundtruth_1hz"
    sub.mkdir()
    (sub / "Robot2_Groundtruth_1hz.csv").write_text("Time,X,Y,Orientation\n\n10,1.5,2.5,0.25\n\n11,1.75,2.5,-0.5\n")
    (sub / "Cleaned_Robot3_Groundtruth.csv").write_text("Time,X,Y,Orientation\n7,0,0,0\n")
    gt = read_groundtruth(tmp_path, 2)
    assert gt.attrs["rate"] == "1hz" and gt.attrs["file"].endswith("Robot2_Groundtruth_1hz.csv")
    assert gt.to_numpy().tolist() == [[10, 1.5, 2.5, 0.25], [11, 1.75, 2.5, -0.5]]
    assert read_groundtruth(tmp_path, 3)["time"].tolist() == [7.0]
    write(tmp_path / "Robot2_Groundtruth.dat", ["10.0\t1\t2\t0.5", "10.01\t1\t2\t0.5"])
    gt = read_groundtruth(tmp_path, 2)
    assert gt.attrs["rate"] == "full" and len(gt) == 2
    assert read_groundtruth(tmp_path, 4) is None


# --------------------------------------------------------------------------
# bad input: the message names the file and the line
# --------------------------------------------------------------------------

GOOD_ODOMETRY = ["100.0\t0.1\t0.0", "100.1\t0.2\t0.1", "100.2\t0.2\t0.1", "100.3\t0.1\t0.0"]


def with_line(rows: list[str], i: int, text: str) -> list[str]:
    rows = list(rows)
    rows[i] = text
    return rows


@pytest.mark.parametrize(
    "rows, line, words",
    [
        (with_line(GOOD_ODOMETRY, 2, "100.2\t0.2\t0.1\t7"), 7, "expected 3 columns"),
        (with_line(GOOD_ODOMETRY, 2, "100.2\t0.2"), 7, "expected 3 columns"),
        ([r + "\t1" for r in GOOD_ODOMETRY], 5, "expected 3 columns"),
        (with_line(GOOD_ODOMETRY, 1, "100.1\tfast\t0.1"), 6, "v field 'fast' is not a number"),
        (with_line(GOOD_ODOMETRY, 3, "100.3\t0.1\tnan"), 8, "omega is nan"),
        (with_line(GOOD_ODOMETRY, 0, "inf\t0.1\t0.0"), 5, "time is inf"),
        (with_line(GOOD_ODOMETRY, 2, "100.05\t0.2\t0.1"), 7, "goes backwards"),
    ],
)
def test_bad_odometry_names_file_and_line(tmp_path, rows, line, words):
    p = write(tmp_path / "Robot1_Odometry.dat", rows)
    with pytest.raises(ValueError) as info:
        read_odometry(p)
    msg = str(info.value)
    assert str(p) in msg and f"line {line}:" in msg and words in msg, msg


def test_line_numbers_count_comment_and_blank_lines(tmp_path):
    rows = ["100.0\t0.1\t0.0", "", "# a comment", "100.1\t0.2\t0.1", "100.0\t0.2\t0.1"]
    p = write(tmp_path / "Robot1_Odometry.dat", rows)
    with pytest.raises(ValueError, match=r"line 9: time 100\.0 s goes backwards \(line 8 has 100\.1 s\)"):
        read_odometry(p)


def test_empty_file_is_an_error(tmp_path):
    p = write(tmp_path / "Robot1_Odometry.dat", [])
    with pytest.raises(ValueError, match="no data rows") as info:
        read_odometry(p)
    assert str(p) in str(info.value)


def test_missing_files_name_the_path(tmp_path):
    with pytest.raises(FileNotFoundError, match="Robot3_Odometry.dat"):
        read_odometry(tmp_path / "Robot3_Odometry.dat")
    with pytest.raises(FileNotFoundError, match="nowhere"):
        read_dataset(tmp_path / "nowhere")
    folder = write_small_folder(tmp_path / "ds")
    with pytest.raises(FileNotFoundError) as info:
        read_dataset(folder, robots=[1, 2])
    assert str(folder / "Robot2_Odometry.dat") in str(info.value)
    (folder / "Robot1_Measurement.dat").unlink()
    with pytest.raises(FileNotFoundError, match="Robot1_Measurement.dat"):
        read_dataset(folder)


def test_bad_measurement_and_barcode_files(tmp_path):
    p = write(tmp_path / "Robot1_Measurement.dat", ["1.0\t72\t1.0\t0.1", "1.0\t72.5\t1.0\t0.1"])
    with pytest.raises(ValueError, match=r"line 6: barcode 72\.5 is not a whole number") as info:
        read_measurements(p)
    assert str(p) in str(info.value)
    p = write(tmp_path / "Barcodes.dat", ["1\t5", "2\t14", "3\t5"])
    with pytest.raises(ValueError, match=r"line 7: barcode 5 repeats line 5") as info:
        read_barcodes(p)
    assert str(p) in str(info.value)
    p = tmp_path / "bad.csv"
    p.write_text("t,x,y,o\n1,2,3,4\n")
    with pytest.raises(ValueError, match=r"bad.csv, line 1: expected the header"):
        read_groundtruth_csv(p)
    p.write_text("Time,X,Y,Orientation\n\n1,2,3,4\n2,2,3\n")
    with pytest.raises(ValueError, match=r"bad.csv, line 4: expected 4 columns"):
        read_groundtruth_csv(p)


def test_repeated_ids_name_the_first_two_lines(tmp_path):
    """Reference: hand-written files — a duplicate is reported at its second line against its first (even when it
    occurs three times), for barcodes, subjects in Barcodes.dat and subjects in Landmark_Groundtruth.dat."""
    p = write(tmp_path / "Barcodes.dat", ["1\t5", "2\t5", "3\t5"])
    with pytest.raises(ValueError, match=r"line 6: barcode 5 repeats line 5"):
        read_barcodes(p)
    p = write(tmp_path / "Barcodes.dat", ["1\t5", "2\t14", "1\t72"])
    with pytest.raises(ValueError, match=r"line 7: subject 1 repeats line 5"):
        read_barcodes(p)
    p = write(tmp_path / "Landmark_Groundtruth.dat", ["6\t1.0\t2.0\t0.1\t0.1", "6\t3.0\t4.0\t0.1\t0.1"])
    with pytest.raises(ValueError, match=r"line 6: subject 6 repeats line 5"):
        read_landmark_groundtruth(p)


def test_csv_header_may_have_spaces(tmp_path):
    """Reference: the documented header check ignores spaces and case ('Time, X, Y, Orientation')."""
    p = tmp_path / "gt.csv"
    p.write_text("Time, X, Y, Orientation\n1,2,3,0.5\n")
    assert read_groundtruth_csv(p).to_numpy().tolist() == [[1.0, 2.0, 3.0, 0.5]]


def test_a_subject_listed_as_landmark_is_not_also_counted_as_a_robot_sighting():
    """Reference: hand count — if subject 2 (a robot) is passed as a landmark, its sighting is kept, and not also
    counted among the dropped robot sightings."""
    raw = pd.DataFrame({"time": [1.0, 2.0, 3.0], "barcode": [14, 5, 27], "range": 1.0, "bearing": 0.0})
    m, dropped = landmark_sightings(raw, BARCODES, [2, 6, 7, 8])
    assert m["subject"].tolist() == [2, 7]
    assert dropped["robot_sightings"] == 1


def test_robots_in_reads_multi_digit_numbers(tmp_path):
    """Reference: the file names written here (RobotN_Odometry.dat for N = 1, 12; other files ignored)."""
    for name in ("Robot1_Odometry.dat", "Robot12_Odometry.dat", "Robot3_Measurement.dat", "Robot4_Odometry.txt"):
        (tmp_path / name).write_text("")
    assert robots_in(tmp_path) == [1, 12]


def test_write_sorts_barcodes_by_subject_and_refuses_bad_values(tmp_path):
    """Checked with str.split: Barcodes.dat lists subjects in increasing order whatever the dict order; NaN in the
    landmarks and measurement times going backwards are refused with a message."""
    ds = make_dataset(np.random.default_rng(5))
    shuffled = dict(sorted(BARCODES.items(), key=lambda p: -p[1]))  # subjects 9, 8, 7, 6, 2, 1
    folder = write_dataset(Dataset(path=None, barcodes=shuffled, landmarks=ds.landmarks, robots=ds.robots),
                           tmp_path / "a")
    lines = (folder / "Barcodes.dat").read_text().splitlines()[4:]
    assert [int(line.split()[0]) for line in lines] == [1, 2, 6, 7, 8, 9]
    lm = ds.landmarks.copy()
    lm.loc[7, "y"] = np.nan
    with pytest.raises(ValueError, match=r"landmarks: row 1 has a NaN"):
        write_dataset(Dataset(path=None, barcodes=ds.barcodes, landmarks=lm, robots=ds.robots), tmp_path / "b")
    m = ds.robots[2].measurements
    m.loc[3, "time"] = m.loc[2, "time"] - 0.5  # half a second backwards
    with pytest.raises(ValueError, match=r"robot 2 measurements: time goes backwards at row 3"):
        write_dataset(ds, tmp_path / "c")
