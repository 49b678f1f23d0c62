"""fetch_mrclam through a real HTTP server on 127.0.0.1 serving a synthetic dataset zip."""

from __future__ import annotations

import functools
import hashlib
import http.server
import threading
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fastslam_edu.datasets.fetch import FetchError, dataset_url, fetch_mrclam, main
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


class Server:
    """http.server on an ephemeral port in a thread, counting requests."""

    def __init__(self, root: Path):
        self.requests = 0
        outer = self

        class Handler(http.server.SimpleHTTPRequestHandler):
            def do_GET(self):
                outer.requests += 1
                super().do_GET()

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0),
                                                     functools.partial(Handler, directory=str(root)))
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/mrclam/"
        self.thread = threading.Thread(target=self.httpd.serve_forever, args=(0.05,), daemon=True)
        self.thread.start()

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join()


@pytest.fixture
def served(tmp_path):
    """(dataset, server, www folder): the dataset zipped under a top folder, served over HTTP."""
    ds = small_dataset()
    src = write_dataset(ds, tmp_path / "src")
    www = tmp_path / "www" / "mrclam"
    www.mkdir(parents=True)
    make_zip(src, www / f"MRCLAM_Dataset{N}.zip", prefix=f"MRCLAM_Dataset{N}/")
    server = Server(tmp_path / "www")
    yield ds, server, www
    server.close()


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
    with pytest.raises(ValueError, match=f"checksum mismatch for {dataset_url(N, server.url)}: expected sha256 0+"):
        fetch_mrclam(N, tmp_path / "d", base_url=server.url, sha256="0" * 64, progress=False)
    assert not (tmp_path / "d" / f"MRCLAM_Dataset{N}").exists()


def test_http_404_is_reported(served, tmp_path):
    _, server, _ = served
    with pytest.raises(FetchError, match=r"MRCLAM_Dataset9\.zip failed: HTTP 404"):
        fetch_mrclam(9, tmp_path / "d", base_url=server.url, progress=False)
    assert main([str(9), str(tmp_path / "d"), "--base-url", server.url, "--quiet"]) == 1


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
