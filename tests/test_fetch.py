"""fetch_mrclam through a real HTTP server on 127.0.0.1 serving a synthetic dataset zip.

The server is conftest's ``serve_folder`` fixture; the download goes through pooch.
"""

from __future__ import annotations

import hashlib
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fastslam_edu.datasets.fetch import (FetchError, dataset_url, expected_files, fetch_mrclam, main,
                                         unpack_dataset)
from fastslam_edu.datasets.log import Dataset, RobotLog
from fastslam_edu.datasets.mrclam import read_dataset, write_dataset

N = 4  # the dataset number used in these tests


def small_dataset() -> Dataset:
    rng = np.random.default_rng(11)
    barcodes = {5: 1, 14: 2, 41: 3, 32: 4, 23: 5, 72: 6, 27: 7}
    landmarks = pd.DataFrame({"x": [1.0, 2.0], "y": [3.0, -4.0], "x_std": [1e-4, 1e-4], "y_std": [2e-4, 2e-4]},
                             index=pd.Index([6, 7], name="subject"))
    robots = {}
    for n in range(1, 6):
        t = np.sort(100.0 + rng.uniform(0, 10, 30))
        odo = pd.DataFrame({"time": t, "v": rng.normal(size=30), "omega": rng.normal(size=30)})
        tm = np.sort(100.0 + rng.uniform(0, 10, 8))
        meas = pd.DataFrame({"time": tm, "subject": rng.choice([6, 7], 8).astype(np.int64),
                             "range": rng.uniform(1, 5, 8), "bearing": rng.uniform(-0.5, 0.5, 8)})
        gt = pd.DataFrame({"time": t, "x": rng.normal(size=30), "y": rng.normal(size=30),
                           "theta": rng.uniform(-3, 3, 30)}) if n == 1 else None
        robots[n] = RobotLog(n, odo, meas, gt, {}, "synthetic")
    return Dataset(None, barcodes, landmarks, robots)


def make_zip(folder: Path, target: Path, prefix: str, compression: int = zipfile.ZIP_DEFLATED) -> Path:
    with zipfile.ZipFile(target, "w", compression) as zf:
        for p in sorted(folder.iterdir()):
            zf.write(p, prefix + p.name)
    return target


@pytest.fixture
def served(tmp_path, serve_folder):
    """(dataset, server, www folder): the dataset zipped under a top folder, served over HTTP at ``server.url``."""
    ds = small_dataset()
    src = write_dataset(ds, tmp_path / "src")
    www = tmp_path / "www" / "mrclam"
    www.mkdir(parents=True)
    make_zip(src, www / f"MRCLAM_Dataset{N}.zip", prefix=f"MRCLAM_Dataset{N}/")
    server = serve_folder(tmp_path / "www")
    server.url += "/mrclam/"
    yield ds, server, www


def assert_same(ds: Dataset, back: Dataset) -> None:
    assert back.barcodes == ds.barcodes
    pd.testing.assert_frame_equal(back.landmarks, ds.landmarks)
    assert sorted(back.robots) == [1, 2, 3, 4, 5]
    for n, log in ds.robots.items():
        pd.testing.assert_frame_equal(back.robots[n].odometry, log.odometry)
        pd.testing.assert_frame_equal(back.robots[n].measurements, log.measurements)
    pd.testing.assert_frame_equal(back.robots[1].groundtruth, ds.robots[1].groundtruth, check_flags=False)


def test_fetch_downloads_verifies_unpacks_and_reads_back(served, tmp_path):
    ds, server, www = served
    digest = hashlib.sha256((www / f"MRCLAM_Dataset{N}.zip").read_bytes()).hexdigest()
    dest = tmp_path / "data" / "mrclam"
    folder = fetch_mrclam(N, dest, base_url=server.url, sha256=digest.upper(), progress=False)
    assert folder == dest / f"MRCLAM_Dataset{N}"
    assert_same(ds, read_dataset(folder))
    assert [p.name for p in dest.iterdir()] == [f"MRCLAM_Dataset{N}"]  # temporary files removed
    assert server.requests == 1
    # a second call finds a complete folder and does not download
    assert fetch_mrclam(N, dest, base_url=server.url, progress=False) == folder
    assert server.requests == 1


def test_fetch_zip_without_top_folder(served, tmp_path):
    ds, server, www = served
    make_zip(tmp_path / "src", www / f"MRCLAM_Dataset{N}.zip", prefix="")
    folder = fetch_mrclam(N, tmp_path / "d", base_url=server.url, progress=False)
    assert_same(ds, read_dataset(folder))


def test_checksum_mismatch_is_reported(served, tmp_path):
    _, server, _ = served
    with pytest.raises(ValueError, match=f"checksum mismatch for {dataset_url(N, server.url)}: expected sha256 0+, got") as err:
        fetch_mrclam(N, tmp_path / "d", base_url=server.url, sha256="0" * 64, progress=False, retries=0)
    assert "\n" not in str(err.value)
    assert not (tmp_path / "d" / f"MRCLAM_Dataset{N}").exists()
    assert list((tmp_path / "d").iterdir()) == []  # pooch's temporary file and our folder are gone


def test_http_404_is_reported(served, tmp_path):
    _, server, _ = served
    with pytest.raises(FetchError, match=r"MRCLAM_Dataset9\.zip failed: HTTP 404 File not found") as err:
        fetch_mrclam(9, tmp_path / "d", base_url=server.url, progress=False, retries=0)
    assert "\n" not in str(err.value)
    assert main([str(9), str(tmp_path / "d"), "--base-url", server.url, "--quiet", "--retries", "0"]) == 1


def test_bad_zip_and_path_traversal_are_refused(served, tmp_path):
    _, server, www = served
    (www / f"MRCLAM_Dataset{N}.zip").write_bytes(b"<html>not a zip</html>")
    with pytest.raises(ValueError, match="is not a valid zip archive"):
        fetch_mrclam(N, tmp_path / "d", base_url=server.url, progress=False)
    stored = make_zip(tmp_path / "src", tmp_path / "stored.zip", prefix="", compression=zipfile.ZIP_STORED)
    data = stored.read_bytes()
    assert data.count(b"Landmark Groundtruth Data Format") == 1
    corrupted = data.replace(b"Landmark Groundtruth Data Format", b"Landmark Groundtruth Data Furmat")
    (www / f"MRCLAM_Dataset{N}.zip").write_bytes(corrupted)  # same length, wrong CRC
    with pytest.raises(ValueError, match=r"member 'Landmark_Groundtruth\.dat' is corrupted \(CRC"):
        fetch_mrclam(N, tmp_path / "d", base_url=server.url, progress=False)
    with zipfile.ZipFile(www / f"MRCLAM_Dataset{N}.zip", "w") as zf:
        for p in sorted((tmp_path / "src").iterdir()):
            zf.write(p, p.name)
        zf.writestr("../evil.txt", "x")
    with pytest.raises(ValueError, match=r"refusing to unpack member '\.\./evil\.txt'"):
        fetch_mrclam(N, tmp_path / "d", base_url=server.url, progress=False)
    assert not (tmp_path / "evil.txt").exists() and not (tmp_path / "d" / "evil.txt").exists()


def test_zip_missing_files_is_refused(served, tmp_path):
    _, server, www = served
    with zipfile.ZipFile(www / f"MRCLAM_Dataset{N}.zip", "w") as zf:
        for p in sorted((tmp_path / "src").iterdir()):
            if p.name != "Robot5_Measurement.dat":
                zf.write(p, p.name)
    with pytest.raises(ValueError, match=r"missing expected files \['Robot5_Measurement\.dat'\]"):
        fetch_mrclam(N, tmp_path / "d", base_url=server.url, progress=False)


def test_command_line(served, tmp_path, capsys):
    ds, server, _ = served
    assert main([str(N), str(tmp_path / "cli"), "--base-url", server.url, "--quiet"]) == 0
    folder = Path(capsys.readouterr().out.strip())
    assert folder == tmp_path / "cli" / f"MRCLAM_Dataset{N}"
    assert_same(ds, read_dataset(folder))


def test_connection_refused_is_one_line(tmp_path, closed_port_url, capsys):
    with pytest.raises(FetchError, match=r"MRCLAM_Dataset4\.zip failed: connection failed: .*refused") as err:
        fetch_mrclam(N, tmp_path / "d", base_url=closed_port_url, progress=False, retries=0)
    assert "\n" not in str(err.value)
    assert main([str(N), str(tmp_path / "d"), "--base-url", closed_port_url, "--quiet", "--retries", "0"]) == 1
    err_lines = capsys.readouterr().err.splitlines()
    assert len(err_lines) == 1 and err_lines[0].startswith("error: download of ")


def test_a_failed_attempt_is_retried(served, tmp_path):
    ds, server, _ = served
    server.failures = 1  # the first request gets HTTP 503
    folder = fetch_mrclam(N, tmp_path / "d", base_url=server.url, progress=False, retries=1)
    assert server.requests == 2
    assert_same(ds, read_dataset(folder))


def one_line_naming(err: pytest.ExceptionInfo, archive_name: str) -> bool:
    text = str(err.value)
    return "\n" not in text and archive_name in text


def test_truncated_zip_is_one_line_error(served, tmp_path):
    """A zip cut in half (an interrupted copy) is refused with one line naming the archive."""
    _, server, www = served
    zpath = www / f"MRCLAM_Dataset{N}.zip"
    zpath.write_bytes(zpath.read_bytes()[: zpath.stat().st_size // 2])
    with pytest.raises(ValueError, match="is not a valid zip archive") as err:
        fetch_mrclam(N, tmp_path / "d", base_url=server.url, progress=False)
    assert one_line_naming(err, f"MRCLAM_Dataset{N}.zip")
    assert not (tmp_path / "d" / f"MRCLAM_Dataset{N}").exists()


def test_flipped_bytes_in_a_deflated_member_are_one_line_error(served, tmp_path):
    """Bytes flipped inside a member's deflate stream: a ValueError naming archive and member, not a zlib traceback."""
    _, server, www = served
    zpath = www / f"MRCLAM_Dataset{N}.zip"
    with zipfile.ZipFile(zpath) as zf:
        info = zf.getinfo(f"MRCLAM_Dataset{N}/Robot1_Odometry.dat")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    data = bytearray(zpath.read_bytes())
    for k in range(start + 20, start + 40):
        data[k] ^= 0xFF
    zpath.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"member 'MRCLAM_Dataset4/Robot1_Odometry\.dat' is corrupted") as err:
        fetch_mrclam(N, tmp_path / "d", base_url=server.url, progress=False)
    assert one_line_naming(err, f"MRCLAM_Dataset{N}.zip")
    assert not (tmp_path / "d" / f"MRCLAM_Dataset{N}").exists()


def test_any_flipped_byte_gives_the_dataset_or_a_one_line_value_error(tmp_path):
    """Flip one byte of the zip at a time (every 2nd of the central directory, every 37th elsewhere): unpacking either
    gives back the exact expected files or raises a one-line ValueError naming the archive; nothing else escapes."""
    src = write_dataset(small_dataset(), tmp_path / "src")
    good = make_zip(src, tmp_path / "good.zip", prefix="").read_bytes()
    with zipfile.ZipFile(tmp_path / "good.zip") as zf:
        central = min(i.header_offset for i in zf.infolist()) + sum(
            30 + len(i.filename.encode()) + len(i.extra) + i.compress_size for i in zf.infolist())
    positions = sorted(set(range(0, central, 37)) | set(range(central, len(good), 2)))
    archive = tmp_path / "bad.zip"
    outcomes = {"ok": 0, "refused": 0}
    for k in positions:
        data = bytearray(good)
        data[k] ^= 0xFF
        archive.write_bytes(bytes(data))
        out = tmp_path / f"out{k}"
        try:
            unpack_dataset(archive, out)
        except ValueError as exc:
            assert "\n" not in str(exc) and str(archive) in str(exc), (k, str(exc))
            outcomes["refused"] += 1
        else:
            for name in expected_files():
                assert (out / name).read_bytes() == (src / name).read_bytes(), (k, name)
            outcomes["ok"] += 1
    assert outcomes["refused"] > len(positions) // 2
