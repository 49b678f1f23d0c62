"""Damaged input files (cut short, bytes flipped, wrong format) give one clear ValueError line, never a traceback.

Every file is written here, valid, and then damaged the way downloads and
disks damage them: cut in half, a byte flipped, the wrong kind of file under
the expected name. Each case checks the exception type, that the message names
the file and says what is wrong, and that it is one line; the last tests check
that the command line prints that line and exits with status 1.

Not tested: flipping bytes inside an uncompressed ``.mat`` file. SciPy's MAT
reader does not check every tag it reads, and some flips (an invalid data-type
code, a "complex" flag on a real array) crash the interpreter inside
``scipy.io.loadmat`` (SciPy 1.17; scipy/scipy PRs #25349, #25829), which no
Python code can catch.
"""

from __future__ import annotations

import gzip
import json
import zlib

import numpy as np
import pytest
import scipy.io

from fastslam_edu.app.cli import main
from fastslam_edu.datasets.laser import read_carmen, read_intel_json, read_relations
from fastslam_edu.datasets.thor_lidar import read_thor_joints, read_thor_lidar, write_thor_lidar

N_LINES = 400


def carmen_text(n=N_LINES) -> bytes:
    """A valid CARMEN log: one PARAM line, then ODOM + FLASER pairs (8 beams), 1 + n lines in all."""
    rng = np.random.default_rng(3)
    lines = ["PARAM robot_front_laser_max 80.0"]
    for k in range(n // 2):
        x, y, th = rng.normal(size=3)
        rs = " ".join(f"{r:.3f}" for r in rng.uniform(0.5, 8.0, 8))
        lines.append(f"ODOM {x:.6f} {y:.6f} {th:.6f} 0 0 0 {k:.3f} h {k:.3f}")
        lines.append(f"FLASER 8 {rs} {x:.6f} {y:.6f} {th:.6f} {x:.6f} {y:.6f} {th:.6f} {k:.3f} h {k:.3f}")
    return ("\n".join(lines) + "\n").encode("ascii")


def json_text(n=300) -> bytes:
    """A valid Intel JSON document, one scan per line (so that a cut leaves complete lines)."""
    rng = np.random.default_rng(4)
    rows = [f'"{1000.0 + k:.6f}": {json.dumps({"range": rng.uniform(0.5, 8, 6).round(3).tolist(), "x": k, "y": 0.0, "theta": 0.0})}'
            for k in range(n)]
    return ('{"map": {\n' + ",\n".join(rows) + "\n}}\n").encode("ascii")


def relations_text(n=300) -> bytes:
    rng = np.random.default_rng(5)
    return "".join(f"{k:.3f} {k + 1:.3f} {rng.normal():.6f} 0.1 0 0 0 0.01\n" for k in range(n)).encode("ascii")


READERS = {  # name → (reader, file name, valid text)
    "carmen": (read_carmen, "scans.log.gz", carmen_text),
    "intel-json": (read_intel_json, "intel_gfs.json.gz", json_text),
    "relations": (read_relations, "loop.relations.gz", relations_text),
}


def one_line_error(reader, path, *phrases):
    """Call ``reader(path)``: it must raise one ValueError line that names the file and holds every phrase."""
    with pytest.raises(ValueError) as info:
        reader(path)
    msg = str(info.value)
    assert str(path) in msg, msg
    assert "\n" not in msg and "\r" not in msg, msg
    for phrase in phrases:
        assert phrase in msg, (phrase, msg)
    return msg


def complete_lines_in(cut: bytes) -> int:
    """Number of whole lines a gzip stream cut short still holds (what an independent zlib recovers)."""
    return zlib.decompressobj(wbits=31).decompress(cut).count(b"\n")


# --------------------------------------------------------------------------- gzip (CARMEN, Intel JSON, relations)


@pytest.fixture(params=sorted(READERS))
def gz_case(request, tmp_path):
    reader, name, text = READERS[request.param]
    raw = text()
    good = gzip.compress(raw, mtime=0)
    path = tmp_path / name
    path.write_bytes(good)
    reader(path)  # the undamaged file reads
    return reader, path, raw, good


def test_gzip_cut_in_half_says_truncated_after_which_line(gz_case):
    reader, path, _, good = gz_case
    cut = good[: len(good) // 2]
    path.write_bytes(cut)
    n = complete_lines_in(cut)
    assert n > 0
    msg = one_line_error(reader, path, "truncated", f"stops after line {n}, ", "download it again")
    assert "end-of-stream" not in msg  # our words, not zlib's


def test_gzip_cut_inside_the_header_or_the_first_line(gz_case):
    reader, path, _, good = gz_case
    path.write_bytes(good[:12])  # the gzip header and two bytes of data: not even line 1 is whole
    one_line_error(reader, path, "truncated", "inside line 1")


def test_gzip_with_a_wrong_crc_is_corrupt(gz_case):
    reader, path, raw, good = gz_case
    bad = bytearray(good)
    bad[-8] ^= 0xFF  # first byte of the CRC-32 in the trailer: every line decompresses, the check fails
    path.write_bytes(bytes(bad))
    n_lines = raw.count(b"\n")
    one_line_error(reader, path, "corrupt", "CRC", f"after line {n_lines} (", "download it again")


def test_gzip_with_a_byte_flipped_in_the_middle(gz_case):
    reader, path, _, good = gz_case
    bad = bytearray(good)
    bad[len(bad) // 2] ^= 0xFF
    path.write_bytes(bytes(bad))
    one_line_error(reader, path)  # corrupt data, a CRC mismatch or a malformed line: always one named line


def test_plain_text_named_gz_is_not_gzip(gz_case):
    reader, path, raw, _ = gz_case
    path.write_bytes(raw)
    one_line_error(reader, path, "not gzip", "download it again")


def test_empty_gz_file(gz_case):
    reader, path, _, _ = gz_case
    path.write_bytes(b"")
    one_line_error(reader, path, "empty", "download it again")


def test_html_error_page_saved_as_gz(gz_case):
    reader, path, _, _ = gz_case
    path.write_bytes(b"<!DOCTYPE html><html><body>404: Not Found</body></html>\n")
    one_line_error(reader, path, "not gzip")


def test_gzip_data_under_a_name_without_gz(tmp_path):
    path = tmp_path / "scans.log"
    path.write_bytes(gzip.compress(carmen_text()))
    one_line_error(read_carmen, path, "gzip-compressed", ".gz")


def test_gzip_of_invalid_json(tmp_path):
    path = tmp_path / "intel_gfs.json.gz"
    path.write_bytes(gzip.compress(json_text()[:-40] + b"\n"))  # the closing braces and some values missing
    one_line_error(read_intel_json, path, "not valid JSON", "line")


def test_gzip_of_invalid_utf8_json(tmp_path):
    path = tmp_path / "intel_gfs.json.gz"
    text = json_text().replace(b'"1000.000000"', b'"1000.0\xff\xfe"')
    path.write_bytes(gzip.compress(text))
    one_line_error(read_intel_json, path, f"{path}:2: not UTF-8 text (byte 0xff")


def test_gzip_of_binary_junk(tmp_path):
    path = tmp_path / "scans.log.gz"
    path.write_bytes(gzip.compress(np.random.default_rng(0).bytes(5000)))
    one_line_error(read_carmen, path)  # a line of junk: "no FLASER line" or a malformed line, named


# --------------------------------------------------------------------------- THOR .mat (LiDAR and joints)


@pytest.fixture
def lidar_mat(tmp_path):
    rng = np.random.default_rng(6)
    n = 6
    path = tmp_path / "train_lidar0.mat"
    write_thor_lidar(path, 1.2e9 + 0.025 * np.arange(n), rng.uniform(0.2, 20, (n, 1081)), rng.normal(size=(n, 3)))
    read_thor_lidar(path)
    return path


@pytest.fixture
def joints_mat(tmp_path):
    path = tmp_path / "train_joint0.mat"
    ts = 1.2e9 + 0.008 * np.arange(40)
    scipy.io.savemat(path, {"ts": ts[None, :], "head_angles": np.zeros((2, 40))})
    read_thor_joints(path)
    return path


MAT_READERS = {"lidar": read_thor_lidar, "joints": read_thor_joints}


@pytest.mark.parametrize("kind", sorted(MAT_READERS))
@pytest.mark.parametrize(
    "damage",
    [
        pytest.param(lambda b: b[: len(b) // 2], id="cut-in-half"),
        pytest.param(lambda b: b[:100], id="cut-inside-the-header"),
        pytest.param(lambda b: b"", id="empty"),
        pytest.param(lambda b: b"ts head_angles\n1 2 3\n" * 20, id="text-not-mat"),
        pytest.param(lambda b: gzip.compress(b), id="gzipped-mat"),
    ],
)
def test_damaged_mat_file(kind, damage, lidar_mat, joints_mat):
    path = lidar_mat if kind == "lidar" else joints_mat
    path.write_bytes(damage(path.read_bytes()))
    one_line_error(MAT_READERS[kind], path, "MATLAB", "download it again")


@pytest.mark.parametrize(
    "variables, phrase",
    [
        ({"ts": np.array(["abc"]), "head_angles": np.zeros((2, 1))}, "'ts' must be numeric, got text"),
        ({"ts": {"a": 1.0}, "head_angles": np.zeros((2, 1))}, "'ts' must be numeric, got a struct"),
        ({"ts": np.arange(3.0), "head_angles": np.ones((2, 3)) * 1j}, "'head_angles' must be numeric, got complex"),
        ({"ts": np.zeros((1, 0)), "head_angles": np.zeros((2, 0))}, "'ts' is empty"),
        ({"ts": np.arange(3.0)}, "no variable 'head_angles'"),
        ({"ts": np.arange(3.0), "head_angles": np.ones((3, 3))}, "head_angles must be (2, 3)"),
    ],
)
def test_joint_file_with_wrong_variables(tmp_path, variables, phrase):
    path = tmp_path / "train_joint0.mat"
    scipy.io.savemat(path, variables)
    one_line_error(read_thor_joints, path, phrase)


def lidar_cell(**fields):
    s = {"t": np.array([[1.0]]), "scan": np.ones((1, 5)), "delta_pose": np.zeros((1, 3))}
    s.update(fields)
    cells = np.empty((1, 1), dtype=object)
    cells[0, 0] = s
    return cells


@pytest.mark.parametrize(
    "lidar, phrase",
    [
        (lidar_cell(t="abc"), "lidar{1}: field 't' must be numeric, got text"),
        (lidar_cell(scan={"a": 1.0}), "lidar{1}: field 'scan' must be numeric, got a struct"),
        (lidar_cell(delta_pose=np.zeros((1, 3)) + 1j), "lidar{1}: field 'delta_pose' must be numeric, got complex"),
        (np.zeros((1, 3)), "'lidar' must be a non-empty 1 × N cell array"),
    ],
)
def test_lidar_file_with_wrong_fields(tmp_path, lidar, phrase):
    path = tmp_path / "train_lidar0.mat"
    scipy.io.savemat(path, {"lidar": lidar})
    one_line_error(read_thor_lidar, path, phrase)


# --------------------------------------------------------------------------- the command line


def cli_error(capsys, argv, path, *phrases):
    rc = main(argv)
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert rc == 1, captured
    assert len(err) == 1, err
    assert "Traceback" not in captured.err and "Traceback" not in captured.out
    assert err[0].startswith("fastslam-edu gridslam: error: ") and str(path) in err[0], err[0]
    for phrase in phrases:
        assert phrase in err[0], (phrase, err[0])


def test_cli_truncated_carmen_log(tmp_path, capsys):
    path = tmp_path / "truncated.log.gz"
    good = gzip.compress(carmen_text())
    path.write_bytes(good[: len(good) // 2])
    cli_error(capsys, ["gridslam", "--scans", str(path), "--quiet"], path, "truncated", "after line")


def test_cli_truncated_json_reference_and_corrupt_relations(tmp_path, capsys):
    scans = tmp_path / "scans.log"
    scans.write_bytes(carmen_text())
    ref = tmp_path / "intel_corrected_log.json.gz"
    good = gzip.compress(json_text())
    ref.write_bytes(good[: len(good) // 2])
    cli_error(capsys, ["gridslam", "--scans", str(scans), "--reference", str(ref), "--quiet"], ref, "truncated")
    rel = tmp_path / "loop.relations.gz"
    bad = bytearray(gzip.compress(relations_text()))
    bad[-8] ^= 0xFF
    rel.write_bytes(bytes(bad))
    cli_error(capsys, ["gridslam", "--scans", str(scans), "--relations", str(rel), "--quiet"], rel, "CRC")


def test_cli_damaged_thor_files(lidar_mat, joints_mat, capsys):
    good_joints = joints_mat.read_bytes()
    joints_mat.write_bytes(good_joints[: len(good_joints) // 2])
    argv = ["gridslam", "--scans", str(lidar_mat), "--joints", str(joints_mat), "--quiet"]
    cli_error(capsys, argv, joints_mat, "MATLAB", "truncated or damaged", "download it again")
    joints_mat.write_bytes(good_joints)
    lidar_mat.write_bytes(b"not a mat file at all" * 10)
    cli_error(capsys, argv, lidar_mat, "MATLAB", "truncated or damaged", "download it again")
