"""The data registry and its pooch-based fetching, end to end against a web folder on 127.0.0.1.

Every test builds its own small registry of synthetic files (one in a
subfolder, one published uncompressed and stored gzipped) served from a
temporary folder laid out like a pinned source (``owner/repo/commit/path``);
no test reads the real data. The real registry is only checked for form.
"""

from __future__ import annotations

import gzip
import hashlib
import os
import random
import re
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

from fastslam_edu.app import cli
from fastslam_edu.datasets import (REGISTRY, DataFetchError, DataFile, DatasetEntry, dataset_path, fetch_datasets,
                                   mrclam_path)
from fastslam_edu.datasets import registry as registry_module
from fastslam_edu.datasets.registry import fetch_dataset, gzip_file, main

COMMIT = "0123456789abcdef0123456789abcdef01234567"


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def gzip_n(data: bytes) -> bytes:
    """``gzip -9 -n`` as zlib's own gzip wrapper writes it (mtime 0, xfl 2, OS 3): independent of gzip_file."""
    deflate = zlib.compressobj(9, zlib.DEFLATED, 31, 9)
    return deflate.compress(data) + deflate.flush()


def synthetic_files() -> dict[str, tuple[str, bytes]]:
    """data path -> (path in the source repository, bytes served there)."""
    rng = random.Random(7)
    log = "".join(f"ODOM {rng.uniform(-5, 5):.6f} {rng.uniform(-5, 5):.6f} 0.1 0 0 0 {i:.3f} pippo {i:.3f}\n"
                  for i in range(3000)).encode()
    return {
        "alpha/a.txt": ("data/a.txt", b"# a small text file\n1 2 3\n"),
        "alpha/sub/b.bin": ("data/deep/b.bin", rng.randbytes(5000)),
        "alpha/c.log.gz": ("raw/c.log", log),  # published uncompressed, stored gzipped
        "beta/d.csv": ("d.csv", b"Time,X,Y\n" + b"".join(b"%d,%d,%d\n" % (i, i * i, -i) for i in range(500))),
    }


def landed_bytes(path: str, served: bytes) -> bytes:
    """What must land in the data folder for the file served as ``served``."""
    return gzip_n(served) if path.endswith(".gz") else served


def make_registry(base_url: str) -> dict[str, DatasetEntry]:
    """Two datasets over :func:`synthetic_files`, their URLs under ``base_url``/owner/repo/COMMIT/."""
    files = {}
    for path, (repo_path, served) in synthetic_files().items():
        final = landed_bytes(path, served)
        extra = dict(download_sha256=sha256(served), download_size=len(served), gzip=True) if path.endswith(".gz") else {}
        files[path] = DataFile(path, f"{base_url}/owner/repo/{COMMIT}/{repo_path}", sha256(final), len(final), **extra)
    alpha = DatasetEntry("alpha", "alpha", "synthetic", tuple(f for p, f in files.items() if p.startswith("alpha/")))
    beta = DatasetEntry("beta", "beta", "synthetic", (files["beta/d.csv"],))
    return {"alpha": alpha, "beta": beta}


@pytest.fixture
def origin(tmp_path, serve_folder):
    """(server, registry, www): the synthetic files served in the layout of a pinned source."""
    www = tmp_path / "www"
    for path, (repo_path, served) in synthetic_files().items():
        target = www / "owner" / "repo" / COMMIT / repo_path
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(served)
    server = serve_folder(www)
    return server, make_registry(server.url), www


@pytest.fixture
def root(tmp_path, monkeypatch):
    """An empty data root, also set as $FASTSLAM_EDU_DATA; no mirror in the environment."""
    folder = tmp_path / "data"
    folder.mkdir()
    monkeypatch.setenv("FASTSLAM_EDU_DATA", str(folder))
    monkeypatch.delenv("FASTSLAM_EDU_MIRROR", raising=False)
    return folder


def snapshot(folder: Path) -> dict[str, tuple[int, int, int]]:
    """Every entry under ``folder`` (hidden ones too) -> (inode, size, mtime [ns])."""
    return {str(p.relative_to(folder)): (p.stat().st_ino, p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*"))} | {".": (folder.stat().st_ino, 0, folder.stat().st_mtime_ns)}


def leftovers(folder: Path) -> list[str]:
    """Hidden entries under ``folder``: staging folders or temporary files left behind."""
    return [str(p) for p in folder.rglob(".*")]


def assert_complete(root: Path) -> None:
    for path, (_, served) in synthetic_files().items():
        assert (root / path).read_bytes() == landed_bytes(path, served), path


def set_writable(folder: Path, writable: bool) -> None:
    """chmod every folder to 755/555 and file to 644/444 under ``folder`` (and itself)."""
    for p in [folder, *folder.rglob("*")]:
        mode = (0o755 if p.is_dir() else 0o644) if writable else (0o555 if p.is_dir() else 0o444)
        p.chmod(mode)


def one_line(text: str) -> str:
    assert "\n" not in text.rstrip("\n"), text
    return text.rstrip("\n")


# --- the real registry -----------------------------------------------------------------------------------------------

def test_real_registry_is_well_formed():
    pinned = re.compile(r"^https://raw\.githubusercontent\.com/[\w.-]+/[\w.-]+/[0-9a-f]{40}/[^\s]+$")
    paths = [f.path for e in REGISTRY.values() for f in e.files]
    assert len(paths) == len(set(paths)) == 38
    assert {n: len(e.files) for n, e in REGISTRY.items()} == {"mrclam1": 14, "mrclam6": 17, "intel": 4, "fr079": 2,
                                                              "thor": 1}
    for name, entry in REGISTRY.items():
        assert entry.name == name and entry.citation and "\n" not in entry.citation
        for f in entry.files:
            assert f.path.startswith(entry.folder + "/") and ".." not in f.path.split("/"), f.path
            assert re.fullmatch(r"[0-9a-f]{64}", f.sha256) and f.size > 0, f.path
            assert pinned.match(f.url), f.url
            assert not f.path.endswith("README.md")
            if f.gzip:
                assert f.path.endswith(".gz") and not f.url.endswith(".gz")
                assert re.fullmatch(r"[0-9a-f]{64}", f.download_sha256) and f.download_size > f.size > 0, f.path
            else:
                assert f.download_sha256 is None and f.download_size is None
    assert sum(f.gzip for e in REGISTRY.values() for f in e.files) == 3


# --- fetching -------------------------------------------------------------------------------------------------------

def test_fetch_into_empty_folder_lands_every_file(origin, root):
    server, registry, _ = origin
    folders = fetch_datasets(root=root, registry=registry, progress=False)
    assert folders == {"alpha": root / "alpha", "beta": root / "beta"}
    assert_complete(root)
    assert server.requests == 4
    assert leftovers(root) == []  # staging folders removed
    assert dataset_path("alpha", registry=registry) == root / "alpha"


def test_second_fetch_makes_no_request_and_writes_nothing(origin, root):
    server, registry, _ = origin
    fetch_datasets(root=root, registry=registry, progress=False)
    before, server.requests = snapshot(root), 0
    set_writable(root, False)  # as CI's read-only data folder (root ignores this: hence the snapshot)
    try:
        assert fetch_datasets(root=root, registry=registry, progress=False) == {"alpha": root / "alpha",
                                                                                 "beta": root / "beta"}
        report = fetch_dataset("alpha", root=root, registry=registry, progress=False)
        assert report.fetched == 0 and "present and verified" in report.line()
        assert dataset_path("beta", download=True, root=root, registry=registry) == root / "beta"
    finally:
        set_writable(root, True)
    assert server.requests == 0
    assert snapshot(root) == before


def test_file_altered_on_the_server_is_refused(origin, root):
    server, registry, www = origin
    served = www / "owner" / "repo" / COMMIT / "data" / "deep" / "b.bin"
    data = bytearray(served.read_bytes())
    data[100] ^= 0x01
    served.write_bytes(bytes(data))
    entry = registry["alpha"].files[1]
    with pytest.raises(DataFetchError) as err:
        fetch_datasets("alpha", root=root, registry=registry, progress=False, retries=0)
    message = one_line(str(err.value))
    target = root / "alpha" / "sub" / "b.bin"
    assert message.startswith("alpha/sub/b.bin: could not fetch ")
    for part in (entry.url, "sha256 mismatch", f"expected {entry.sha256}", f"got {sha256(bytes(data))}",
                 str(target), f"{entry.size} bytes"):
        assert part in message, part
    assert not target.exists()
    assert leftovers(root) == []


def test_gzipped_file_altered_on_the_server_is_refused_before_compressing(origin, root):
    _, registry, www = origin
    wrong = b"not the log\n"
    (www / "owner" / "repo" / COMMIT / "raw" / "c.log").write_bytes(wrong)
    entry = registry["alpha"].files[2]
    with pytest.raises(DataFetchError, match=f"sha256 mismatch: expected {entry.download_sha256}, got {sha256(wrong)}"):
        fetch_datasets("alpha", root=root, registry=registry, progress=False, retries=0)
    assert not (root / "alpha" / "c.log.gz").exists() and leftovers(root) == []


@pytest.mark.parametrize("change", ["flip a byte", "truncate", "delete"])
def test_file_altered_on_disk_is_fetched_again(origin, root, change):
    server, registry, _ = origin
    fetch_datasets(root=root, registry=registry, progress=False)
    path = root / "alpha" / "c.log.gz"
    data = bytearray(path.read_bytes())
    if change == "flip a byte":
        data[-20] ^= 0x01
        path.write_bytes(bytes(data))
    elif change == "truncate":
        path.write_bytes(bytes(data[:100]))
    else:
        path.unlink()
    server.requests = 0
    report = fetch_dataset("alpha", root=root, registry=registry, progress=False)
    assert (report.fetched, server.requests) == (1, 1)
    assert_complete(root)
    assert leftovers(root) == []


def test_gzip_transform_lands_the_registered_bytes(origin, root):
    _, registry, _ = origin
    fetch_datasets("alpha", root=root, registry=registry, progress=False)
    landed = (root / "alpha" / "c.log.gz").read_bytes()
    entry = registry["alpha"].files[2]
    assert entry.gzip and sha256(landed) == entry.sha256 and len(landed) == entry.size
    assert gzip.decompress(landed) == synthetic_files()["alpha/c.log.gz"][1]
    assert landed[:10] == b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x02\x03"  # no name, mtime 0: the same on every machine


def test_gzip_file_is_gzip_9_n_for_any_chunking(tmp_path):
    """Streamed in 1 MiB chunks, the output equals one-shot compression by zlib's gzip wrapper."""
    data = random.Random(3).randbytes(1_500_000) + b"abc" * 800_000
    (tmp_path / "raw").write_bytes(data)
    out = gzip_file(tmp_path / "raw", tmp_path / "raw.gz").read_bytes()
    assert out == gzip_n(data)
    assert gzip.decompress(out) == data


def test_mirror_serves_final_files_at_data_paths(tmp_path, root, serve_folder, monkeypatch):
    registry = make_registry("http://127.0.0.1:9")  # the pinned sources are unreachable: only the mirror is used
    mirror = tmp_path / "mirror"
    for path, (_, served) in synthetic_files().items():
        (mirror / path).parent.mkdir(parents=True, exist_ok=True)
        (mirror / path).write_bytes(landed_bytes(path, served))  # final form: already gzipped
    server = serve_folder(mirror)
    monkeypatch.setenv("FASTSLAM_EDU_MIRROR", server.url + "/")
    report = fetch_dataset("alpha", registry=registry, progress=False)
    assert report.fetched == 3 and report.sources == (server.url,)
    assert f"fetched 3 of 3 files from {server.url} in " in report.line()
    fetch_datasets(registry=registry, progress=False)
    assert_complete(root)
    assert sorted(server.paths) == ["/alpha/a.txt", "/alpha/c.log.gz", "/alpha/sub/b.bin", "/beta/d.csv"]


def test_flaky_server_is_retried(origin, root):
    server, registry, _ = origin
    server.failures = 1
    with pytest.raises(DataFetchError, match=r"alpha/a\.txt: could not fetch .*: HTTP 503"):
        fetch_datasets("alpha", root=root, registry=registry, progress=False, retries=0)
    server.failures = 1
    fetch_datasets("alpha", root=root, registry=registry, progress=False, retries=1)  # pooch waits 1 s, tries again
    assert server.requests == 1 + 1 + 3


def test_http_404_names_file_url_and_target(origin, root):
    _, registry, www = origin
    (www / "owner" / "repo" / COMMIT / "d.csv").unlink()
    with pytest.raises(DataFetchError) as err:
        fetch_datasets("beta", root=root, registry=registry, progress=False, retries=0)
    message = one_line(str(err.value))
    assert re.search(r"^beta/d\.csv: could not fetch http://127\.0\.0\.1:\d+/owner/repo/\w+/d\.csv: HTTP 404", message)
    assert f"put the file at {root / 'beta' / 'd.csv'} (sha256 {registry['beta'].files[0].sha256}" in message


def test_server_down_is_one_line(root, closed_port_url):
    registry = make_registry(closed_port_url)
    with pytest.raises(DataFetchError, match=r"^alpha/a\.txt: could not fetch .*: connection failed: .*refused") as err:
        fetch_datasets(root=root, registry=registry, progress=False, retries=0)
    one_line(str(err.value))
    assert not (root / "alpha" / "a.txt").exists() and leftovers(root) == []


def test_read_only_data_folder_with_a_missing_file(origin, root, monkeypatch):
    """A file to fetch into a folder that cannot be written: one line saying so (chmod, or simulated as root)."""
    _, registry, _ = origin
    if os.geteuid() == 0:  # root ignores permissions: make creating the staging folder fail as it would
        def refuse(*args, **kwargs):
            raise PermissionError(13, "Permission denied", str(root / "beta"))
        monkeypatch.setattr(registry_module.tempfile, "mkdtemp", refuse)
    (root / "beta").mkdir()
    set_writable(root, False)
    try:
        with pytest.raises(DataFetchError, match=r"^beta/d\.csv: could not fetch .*: cannot write there "
                                                 r"\(Permission denied: [^)]*beta[^)]*\)") as err:
            fetch_datasets("beta", root=root, registry=registry, progress=False)
    finally:
        set_writable(root, True)
    one_line(str(err.value))
    assert list((root / "beta").iterdir()) == []


def test_dataset_path(origin, root):
    server, registry, _ = origin
    with pytest.raises(FileNotFoundError) as err:
        dataset_path("beta", registry=registry)
    assert all(s in str(err.value) for s in ("make data", "fastslam-edu data beta", "FASTSLAM_EDU_DATA"))
    assert server.requests == 0
    assert dataset_path("beta", download=True, registry=registry) == root / "beta"
    assert dataset_path("beta", registry=registry) == root / "beta"
    with pytest.raises(ValueError, match="unknown dataset 'gamma'; known datasets: alpha, beta"):
        dataset_path("gamma", registry=registry)


def test_mrclam_path_downloads_1_and_6_from_the_registry_others_as_zip(monkeypatch, root):
    from fastslam_edu.datasets import fetch as fetch_module

    calls = []
    monkeypatch.setattr(registry_module, "dataset_path", lambda name, download: calls.append(name) or root / name)
    monkeypatch.setattr(fetch_module, "fetch_mrclam", lambda n, dest: calls.append((n, dest)) or dest / str(n))
    mrclam_path(1, download=True)
    mrclam_path(6, download=True)
    mrclam_path(4, download=True)
    assert calls == ["mrclam1", "mrclam6", (4, root / "mrclam")]
    with pytest.raises(FileNotFoundError, match="fastslam-edu data mrclam1"):
        mrclam_path(1)


# --- command line ---------------------------------------------------------------------------------------------------

def test_command_line_fetches_then_verifies(origin, root, capsys):
    server, registry, _ = origin
    assert main(["--quiet"], registry=registry) == 0
    out = capsys.readouterr()
    lines = out.out.splitlines()
    assert len(lines) == 2 and out.err == ""
    assert re.fullmatch(re.escape(f"alpha     3 files    0.0 MB  fetched 3 of 3 files from {server.url} in ")
                        + r"\d+\.\d s  " + re.escape(f"({root / 'alpha'})"), lines[0])
    assert lines[1].startswith("beta      1 file     0.0 MB  fetched 1 of 1 files from ")
    server.requests = 0
    assert main(["beta", "alpha", "--quiet"], registry=registry) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == ["beta", "alpha"]
    assert all("present and verified" in line for line in lines) and server.requests == 0


def test_check_only_verifies(origin, root, capsys):
    server, registry, _ = origin
    assert main(["--check"], registry=registry) == 1
    out = capsys.readouterr()
    assert out.out.splitlines() == [f"alpha     3 files    0.0 MB  missing (0 of 3 present)  ({root / 'alpha'})",
                                    f"beta      1 file     0.0 MB  missing (0 of 1 present)  ({root / 'beta'})"]
    assert one_line(out.err).startswith("error: 4 file(s) missing or altered")
    assert server.requests == 0 and list(root.iterdir()) == []
    fetch_datasets(root=root, registry=registry, progress=False)
    (root / "alpha" / "a.txt").write_bytes(b"changed")
    (root / "alpha" / "sub" / "b.bin").unlink()
    server.requests = 0
    assert main(["alpha", "--check"], registry=registry) == 1
    line = one_line(capsys.readouterr().out)
    assert "2 of 3 files missing or altered: a.txt altered, sub/b.bin missing" in line
    assert server.requests == 0
    fetch_datasets(root=root, registry=registry, progress=False)
    assert main(["--check"], registry=registry) == 0
    assert capsys.readouterr().out.count("present and verified") == 2


def test_command_line_failure_is_one_line_exit_1(root, closed_port_url, capsys):
    assert main(["--quiet", "--retries", "0"], registry=make_registry(closed_port_url)) == 1
    err = one_line(capsys.readouterr().err)
    assert err.startswith("error: alpha/a.txt: could not fetch ") and "refused" in err and "Traceback" not in err


def test_unknown_name_exit_2(capsys):
    assert main(["nope"]) == 2
    assert one_line(capsys.readouterr().err) == ("error: unknown dataset 'nope'; known datasets: "
                                                  "mrclam1, mrclam6, intel, fr079, thor")
    assert cli.main(["data", "intel", "nope", "--check"]) == 2
    assert "unknown dataset 'nope'" in one_line(capsys.readouterr().err)


@pytest.mark.parametrize("command", [[sys.executable, "-m", "fastslam_edu.datasets.registry"],
                                     [sys.executable, "-m", "fastslam_edu.app.cli", "data"]])
def test_real_command_lines_fail_in_one_line_when_the_mirror_is_down(command, tmp_path, closed_port_url):
    """The installed entry points, in a fresh interpreter, on the real registry with an unreachable mirror."""
    env = os.environ | {"FASTSLAM_EDU_DATA": str(tmp_path / "data"), "FASTSLAM_EDU_MIRROR": closed_port_url}
    done = subprocess.run([*command, "thor", "--retries", "0"], env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 1 and done.stdout == ""
    err = one_line(done.stderr)
    assert err.startswith(f"error: thor/train_joint0.mat: could not fetch {closed_port_url}/thor/train_joint0.mat: "
                          "connection failed: ")
    assert "Traceback" not in err and str(tmp_path / "data" / "thor" / "train_joint0.mat") in err
    check = subprocess.run([*command, "thor", "--check"], env=env, capture_output=True, text=True, timeout=60)
    assert check.returncode == 1 and "missing (0 of 1 present)" in check.stdout
