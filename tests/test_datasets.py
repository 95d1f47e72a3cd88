"""Datasets fetched by name: sources in order (mirror, $SLMLAB_DATA_URL, original URL), SHA-256 on every use,
one-line errors that leave nothing in the cache, the command line. A local HTTP server, never the internet."""

import functools
import hashlib
import json
import os
import re
import socket
import subprocess
import sys
import threading
from contextlib import contextmanager
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

import slmlab
from slmlab import datasets
from slmlab.cli import main
from slmlab.datasets import registry

FOLDER = "tiny-folder"
CONTENT = {"a.txt": b"first file\n", "sub/b.bin": bytes(range(256)) * 4, "sub/deeper/c.csv": b"x,y\n1,2\n"}


class _QuietHandler(SimpleHTTPRequestHandler):
    requests: list = []

    def log_message(self, *args):
        pass

    def do_GET(self):
        self.requests.append(self.path)
        super().do_GET()


@contextmanager
def serve(directory: Path):
    """An HTTP server over ``directory`` on a free local port: ``.url`` and ``.requests`` (paths asked for)."""
    handler = type("Handler", (_QuietHandler,), {"requests": []})
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(handler, directory=str(directory)))
    threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    httpd.url, httpd.root, httpd.requests = f"http://127.0.0.1:{httpd.server_port}", directory, handler.requests
    try:
        yield httpd
    finally:
        httpd.shutdown()
        httpd.server_close()


@pytest.fixture
def server(tmp_path):
    """A server over ``tmp_path/www``, which holds the dataset's folder."""
    root = tmp_path / "www"
    for rel, data in CONTENT.items():
        (root / FOLDER / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / FOLDER / rel).write_bytes(data)
    with serve(root) as httpd:
        yield httpd


def closed_port_url() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"http://127.0.0.1:{s.getsockname()[1]}"


@pytest.fixture
def tiny(tmp_path, monkeypatch):
    """A registry of one dataset ``tiny`` (three files in nested folders), an empty cache, no mirror, no server;
    ``tiny(original=URL)`` rewrites the registry's original addresses."""
    monkeypatch.setenv("SLMLAB_DATA_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("SLMLAB_DATA_MIRROR", "")
    monkeypatch.delenv("SLMLAB_DATA_URL", raising=False)

    def make(original: str = "https://example.invalid/upstream") -> Path:
        files = [{"path": rel, "size": len(data), "sha256": hashlib.sha256(data).hexdigest(),
                  "url": f"{original}/{FOLDER}/{rel}"} for rel, data in CONTENT.items()]
        reg = {"format": "slmlab-datasets/1", "datasets": {"tiny": {
            "folder": FOLDER, "title": "three small files", "licence": "CC0", "repository": original,
            "commit": "0" * 40, "files": files}}}
        path = tmp_path / f"registry-{len(list(tmp_path.glob('registry-*')))}.json"
        path.write_text(json.dumps(reg))
        monkeypatch.setattr(registry, "REGISTRY_FILE", path)
        return tmp_path / "cache" / FOLDER

    return make


def cached_files(cache: Path) -> dict:
    return {p.relative_to(cache).as_posix(): p.read_bytes() for p in cache.rglob("*") if p.is_file()}


def test_fetch_from_a_server_puts_every_file_in_the_cache_and_checks_it_on_every_use(tiny, server, monkeypatch):
    cache = tiny()
    monkeypatch.setenv("SLMLAB_DATA_URL", server.url + "/")
    assert datasets.fetch("tiny") == cache
    assert cached_files(cache) == CONTENT
    assert sorted(server.requests) == sorted(f"/{FOLDER}/{rel}" for rel in CONTENT)
    (cache / "sub" / "b.bin").write_bytes(b"altered")        # an altered file is fetched again, only it
    assert datasets.fetch("tiny") == cache and cached_files(cache) == CONTENT
    assert server.requests[len(CONTENT):] == [f"/{FOLDER}/sub/b.bin"]
    assert datasets.status().set_index("name").loc["tiny", "cached"] == "yes"


def test_without_a_server_the_original_address_is_used(tiny, server):
    cache = tiny(original=server.url)
    assert datasets.fetch("tiny") == cache and cached_files(cache) == CONTENT
    assert len(server.requests) == len(CONTENT)


def test_a_local_mirror_comes_first(tiny, server, monkeypatch):
    cache = tiny(original=closed_port_url())
    monkeypatch.setenv("SLMLAB_DATA_URL", closed_port_url())
    monkeypatch.setenv("SLMLAB_DATA_MIRROR", str(server.root))
    assert datasets.status().set_index("name").loc["tiny", "source"] == f"mirror {server.root / FOLDER}"
    assert datasets.fetch("tiny") == cache and cached_files(cache) == CONTENT
    assert server.requests == []


@pytest.mark.parametrize("source", ["server", "mirror"])
def test_a_checksum_mismatch_names_the_file_and_its_address_and_leaves_nothing(tiny, server, monkeypatch, source):
    cache = tiny(original=closed_port_url())
    (server.root / FOLDER / "sub" / "b.bin").write_bytes(b"not the registered content")
    if source == "server":
        monkeypatch.setenv("SLMLAB_DATA_URL", server.url)
        address = f"{server.url}/{FOLDER}/sub/b.bin"
    else:
        monkeypatch.setenv("SLMLAB_DATA_MIRROR", str(server.root))
        address = str(server.root / FOLDER / "sub" / "b.bin")
    with pytest.raises(slmlab.SlmlabError) as err:
        datasets.fetch("tiny")
    msg = str(err.value)
    assert "\n" not in msg and f"{FOLDER}/sub/b.bin" in msg and address in msg, msg
    assert "SHA-256" in msg and "python -m slmlab data fetch tiny" in msg and "SLMLAB_DATA_URL" in msg, msg
    assert set(cached_files(cache)) == {"a.txt"}          # the good file stays, nothing half-written
    assert not (cache / "sub").exists()
    assert not datasets.available("tiny")


def test_an_unreachable_source_is_one_line_with_the_remedy_and_an_empty_cache(tiny, monkeypatch):
    cache = tiny()
    url = closed_port_url()
    monkeypatch.setenv("SLMLAB_DATA_URL", url)
    with pytest.raises(slmlab.SlmlabError, match=re.escape(f"from {url}/{FOLDER}/a.txt")) as err:
        datasets.fetch("tiny")
    assert "\n" not in str(err.value) and "python -m slmlab data fetch tiny" in str(err.value)
    assert not cache.exists()
    assert datasets.available("tiny") is False


def test_a_missing_file_on_the_server_is_named_with_its_http_status(tiny, server, monkeypatch):
    tiny()
    (server.root / FOLDER / "sub" / "deeper" / "c.csv").unlink()
    monkeypatch.setenv("SLMLAB_DATA_URL", server.url)
    with pytest.raises(slmlab.SlmlabError, match=r"sub/deeper/c\.csv could not be fetched from .*\(HTTP 404\)"):
        datasets.fetch("tiny")


def test_unknown_names_are_errors_not_missing_data(tiny):
    tiny()
    for call in (datasets.fetch, datasets.available):
        with pytest.raises(slmlab.SlmlabError, match="unknown dataset 'tinny'; the datasets are tiny"):
            call("tinny")


def test_the_command_line_fetches_lists_and_refuses_unknown_names(tiny, server, monkeypatch, capsys):
    cache = tiny()
    monkeypatch.setenv("SLMLAB_DATA_URL", server.url)
    assert main(["data", "list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"cache: {cache.parent}"
    assert re.fullmatch(rf"\s*tiny\s+3\s+0\.0\s+no\s+{re.escape(server.url)}/{FOLDER}", out[2]), out
    assert main(["data", "fetch", "tiny", "nope"]) == 2    # every name is checked before anything is fetched
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown dataset 'nope'" in err and not cache.exists()
    assert main(["data", "fetch"]) == 0
    assert capsys.readouterr().out.startswith(f"tiny: 3 files, 0.0 MB, SHA-256 checked, in {cache}")
    assert main(["data", "list"]) == 0 and re.search(r"tiny\s+3\s+0\.0\s+yes", capsys.readouterr().out)


def test_the_command_line_exits_2_with_one_line(tmp_path):
    env = {"SLMLAB_DATA_DIR": str(tmp_path), "SLMLAB_DATA_MIRROR": "", "SLMLAB_DATA_URL": closed_port_url()}
    r = subprocess.run([sys.executable, "-m", "slmlab", "data", "fetch", "no-such-data"], capture_output=True,
                       text=True, timeout=120, env={**os.environ, **env})
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "unknown dataset 'no-such-data'" in r.stderr
    r = subprocess.run([sys.executable, "-m", "slmlab", "data", "fetch", "opencv-stereo-chessboard"],
                       capture_output=True, text=True, timeout=120, env={**os.environ, **env})
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "opencv-stereo-chessboard-9x6/" in r.stderr and env["SLMLAB_DATA_URL"] in r.stderr
    assert not any(tmp_path.iterdir())


# ------------------------------------------------------------------------------------- the real registry
REPO_RAW = re.compile(r"https://raw\.githubusercontent\.com/([\w.-]+/[\w.-]+)/([0-9a-f]{40})/\S+")


def test_the_registry_names_every_file_at_a_fixed_commit_with_its_sha256():
    derived = {"points_camera_01.csv", "points_camera_03.csv", "stereo_common_points.csv", "PROVENANCE.md"}
    for name in datasets.names():
        ds = datasets.dataset(name)
        paths = [f.path for f in ds.files]
        assert len(set(paths)) == len(paths) and ds.files
        for f in ds.files:
            m = REPO_RAW.fullmatch(f.url)
            assert m and f"https://github.com/{m.group(1)}" == ds.repository and m.group(2) == ds.commit, f.url
            assert re.fullmatch(r"[0-9a-f]{64}", f.sha256) and f.size > 0
            assert not f.path.startswith("/") and ".." not in f.path.split("/") and Path(f.path).name not in derived
    piv = datasets.dataset("pivchallenge-case-e").files
    assert sum(f.path.endswith(".tif") for f in piv) == 14 and sum(f.path.endswith(".xml") for f in piv) == 14


def test_a_real_dataset_arrives_whole_over_http(tmp_path, monkeypatch):
    """The chessboard pairs (0.7 MB) from a local server over the mirror, as from a lab's own server."""
    mirror = datasets.mirror_dir()
    if mirror is None:
        pytest.skip("no local mirror of the datasets to serve")
    monkeypatch.setenv("SLMLAB_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("SLMLAB_DATA_MIRROR", "")
    with serve(mirror) as httpd:
        monkeypatch.setenv("SLMLAB_DATA_URL", httpd.url)
        folder = datasets.fetch("opencv-stereo-chessboard")
    ds = datasets.dataset("opencv-stereo-chessboard")
    got = {p.relative_to(folder).as_posix(): p for p in folder.rglob("*") if p.is_file()}
    assert sorted(got) == sorted(f.path for f in ds.files)
    assert all(hashlib.sha256(got[f.path].read_bytes()).hexdigest() == f.sha256 for f in ds.files)
