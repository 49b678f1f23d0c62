"""Test configuration: property tests (hypothesis) are derandomised, so every run draws the same examples.

A test run that passes once passes again: the examples are a fixed function of the test, like a
fixed seed. Set HYPOTHESIS_PROFILE=explore to search with fresh random examples instead.
"""

import os
import sys
from pathlib import Path

from hypothesis import settings

# benchmarks/textbook_loop.py and benchmarks/grid_loop.py: the loops over particle objects the filters are tested against
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

settings.register_profile("fixed", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "fixed"))


# --- a web folder on 127.0.0.1, for the download tests (test_fetch.py, test_registry.py) ---------------------------

import functools  # noqa: E402
import http.server  # noqa: E402
import threading  # noqa: E402

import pytest  # noqa: E402


class FolderServer:
    """``root`` served by http.server on 127.0.0.1 (ephemeral port) in a thread.

    Counts GET requests (``requests``, ``paths``) and can answer the next
    ``failures`` requests with HTTP 503 (a flaky server, to exercise retries).
    """

    def __init__(self, root: Path):
        self.requests = 0
        self.paths: list[str] = []
        self.failures = 0
        lock = threading.Lock()
        outer = self

        class Handler(http.server.SimpleHTTPRequestHandler):
            def do_GET(self):
                with lock:
                    outer.requests += 1
                    outer.paths.append(self.path)
                    fail = outer.failures > 0
                    outer.failures -= fail
                if fail:
                    self.send_error(503, "Service Unavailable")
                else:
                    super().do_GET()

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Handler, directory=str(root)))
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, args=(0.05,), daemon=True)
        self.thread.start()

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join()


@pytest.fixture
def serve_folder():
    """``serve_folder(root) -> FolderServer``; every server started is shut down after the test."""
    servers = []

    def start(root: Path) -> FolderServer:
        servers.append(FolderServer(Path(root)))
        return servers[-1]

    yield start
    for server in servers:
        server.close()


@pytest.fixture
def closed_port_url():
    """``http://127.0.0.1:PORT`` where nothing listens (a port just bound and released): connection refused."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}"
