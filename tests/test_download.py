"""TUM downloads against a local HTTP server on 127.0.0.1: resume, integrity, safe extraction, catalogue, CLI."""

import io
import os
import tarfile
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from osslam.cli import main
from osslam.datasets.catalogue import TUM_SEQUENCES, CatalogueError, tum_entry
from osslam.datasets.download import DownloadError, check_archive, download, fetch_tum, safe_extract

ENTRY = tum_entry("fr1/xyz")
PAYLOAD = os.urandom(300_000)  # incompressible, so the archive is large enough to cut mid-way


def _archive(members: dict[str, bytes], links: dict[str, str] | None = None) -> bytes:
    """A .tgz with regular files ``members`` and symlinks ``links`` (name -> target)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        for name, target in (links or {}).items():
            info = tarfile.TarInfo(name)
            info.type = tarfile.SYMTYPE
            info.linkname = target
            tar.addfile(info)
    return buffer.getvalue()


def _sequence_archive() -> bytes:
    folder = ENTRY.folder
    return _archive({f"{folder}/rgb.txt": b"# rgb\n", f"{folder}/depth.txt": b"# depth\n",
                     f"{folder}/rgb/blob.bin": PAYLOAD})


class _Server:
    """Serves ``files`` (path -> bytes) with Range support; cuts the first ``cuts`` responses after ``cut_at`` bytes."""

    def __init__(self):
        self.files: dict[str, bytes] = {}
        self.cuts = 0
        self.cut_at = 0
        self.requests: list[tuple[str, str | None]] = []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                server.requests.append((self.path, self.headers.get("Range")))
                data = server.files.get(self.path)
                if data is None:
                    self.send_error(404)
                    return
                start = 0
                if self.headers.get("Range"):
                    start = int(self.headers["Range"].removeprefix("bytes=").split("-")[0])
                    if start >= len(data):
                        self.send_response(416)
                        self.send_header("Content-Range", f"bytes */{len(data)}")
                        self.end_headers()
                        return
                    self.send_response(206)
                    self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
                else:
                    self.send_response(200)
                self.send_header("Content-Length", str(len(data) - start))
                self.end_headers()
                body = data[start:]
                if server.cuts > 0:
                    server.cuts -= 1
                    self.wfile.write(body[: server.cut_at])
                    self.wfile.flush()
                    self.close_connection = True
                    return
                self.wfile.write(body)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def serve(self, path: str, data: bytes) -> str:
        self.files[path] = data
        return self.url + path


@pytest.fixture
def server():
    s = _Server()
    s.thread.start()
    yield s
    s.httpd.shutdown()
    s.httpd.server_close()


def _tum_path(entry=ENTRY) -> str:
    return f"/freiburg{entry.freiburg}/{entry.folder}.tgz"


def test_fetch_resumes_after_cut_connections_then_skips(server, tmp_path):
    archive = _sequence_archive()
    server.serve(_tum_path(), archive)
    server.cuts, server.cut_at = 2, 100_000
    result = fetch_tum(ENTRY, tmp_path, base_url=server.url, retry_delay=0)
    assert result.status == "downloaded" and result.bytes_downloaded == len(archive)
    assert (result.folder / "rgb" / "blob.bin").read_bytes() == PAYLOAD
    assert [r for _, r in server.requests] == [None, "bytes=100000-", "bytes=200000-"]
    assert not list(tmp_path.glob("*.tgz*")), "archive and .part are removed after extraction"
    assert not list(tmp_path.glob(".*")), "no staging folder is left"
    again = fetch_tum(ENTRY, tmp_path, base_url=server.url)
    assert again.status == "present" and len(server.requests) == 3


def test_download_resumes_an_existing_part_file(server, tmp_path):
    data = os.urandom(50_000)
    url = server.serve("/f.bin", data)
    (tmp_path / "f.bin.part").write_bytes(data[:20_000])
    download(url, tmp_path / "f.bin", retry_delay=0)
    assert (tmp_path / "f.bin").read_bytes() == data
    assert server.requests == [("/f.bin", "bytes=20000-")]


def test_download_gives_up_after_retries_and_keeps_the_part(server, tmp_path):
    url = server.serve("/f.bin", os.urandom(10_000))
    server.cuts, server.cut_at = 100, 0
    with pytest.raises(DownloadError, match="failed"):
        download(url, tmp_path / "f.bin", retries=2, retry_delay=0)
    assert not (tmp_path / "f.bin").exists()


def test_a_folder_that_cannot_be_made_is_reported_before_any_request(server, tmp_path, capsys):
    url = server.serve("/f.bin", os.urandom(1000))
    (tmp_path / "taken").write_text("a file where the folder should be")
    with pytest.raises(DownloadError, match=r"taken/sub: cannot create the folder"):
        download(url, tmp_path / "taken" / "sub" / "f.bin", retry_delay=0)
    assert main(["models", "download", "yolo-fastest-1.1", "--dir", str(tmp_path / "taken"),
                 "--mirror", server.url]) == 1
    assert "cannot create the folder" in capsys.readouterr().err
    assert server.requests == []


def test_http_error_is_reported(server, tmp_path):
    with pytest.raises(DownloadError, match="404"):
        download(server.url + "/missing.tgz", tmp_path / "x.tgz", retry_delay=0)


@pytest.mark.parametrize("damage", ["flip", "truncate"])
def test_corrupt_archive_is_rejected_and_removed(server, tmp_path, damage):
    archive = bytearray(_sequence_archive())
    if damage == "flip":
        archive[len(archive) // 2] ^= 0xFF
    else:
        archive = archive[: len(archive) - 5000]
    server.serve(_tum_path(), bytes(archive))
    with pytest.raises(DownloadError, match="corrupt"):
        fetch_tum(ENTRY, tmp_path, base_url=server.url, retry_delay=0)
    assert not (tmp_path / ENTRY.folder).exists()
    assert not (tmp_path / f"{ENTRY.folder}.tgz").exists()


@pytest.mark.parametrize("members,links", [
    ({"rgbd_dataset_freiburg1_xyz/../../evil.txt": b"x"}, None),
    ({"/tmp/evil.txt": b"x"}, None),
    ({"rgbd_dataset_freiburg1_xyz/rgb.txt": b""}, {"rgbd_dataset_freiburg1_xyz/link": "../../../etc/passwd"}),
    ({"rgbd_dataset_freiburg1_xyz/rgb.txt": b""}, {"rgbd_dataset_freiburg1_xyz/abs": "/etc/passwd"}),
])
def test_path_traversal_is_rejected(server, tmp_path, members, links):
    target = tmp_path / "data"
    server.serve(_tum_path(), _archive(members, links))
    with pytest.raises(DownloadError, match="unsafe|outside"):
        fetch_tum(ENTRY, target, base_url=server.url, retry_delay=0)
    assert not (tmp_path / "evil.txt").exists()
    assert not (target / ENTRY.folder).exists()


def test_check_and_extract_a_good_archive(tmp_path):
    path = tmp_path / "a.tgz"
    path.write_bytes(_sequence_archive())
    assert check_archive(path) == 3
    safe_extract(path, tmp_path / "out")
    assert (tmp_path / "out" / ENTRY.folder / "rgb" / "blob.bin").read_bytes() == PAYLOAD


def test_catalogue_names_and_addresses():
    assert len(TUM_SEQUENCES) >= 45
    for name in ("fr3/walking_xyz", "fr3/walking_static", "fr3/walking_halfsphere", "fr3/walking_rpy",
                 "fr3/sitting_xyz", "fr3/sitting_static", "fr1/360", "fr2/360_hemisphere", "fr2/desk_with_person"):
        assert name in TUM_SEQUENCES
    entry = tum_entry("rgbd_dataset_freiburg3_walking_xyz")
    assert entry is tum_entry("freiburg3_walking_xyz") is tum_entry("fr3/walking_xyz")
    assert entry.url() == "https://cvg.cit.tum.de/rgbd/dataset/freiburg3/rgbd_dataset_freiburg3_walking_xyz.tgz"
    with pytest.raises(CatalogueError):
        tum_entry("fr4/nothing")


def test_cli_download_and_list(server, tmp_path, capsys):
    server.serve(_tum_path(), _sequence_archive())
    assert main(["download", "tum", "fr1/xyz", "--to", str(tmp_path), "--mirror", server.url]) == 0
    assert "downloaded" in capsys.readouterr().out
    assert main(["download", "tum", "fr1/xyz", "--to", str(tmp_path), "--mirror", server.url]) == 0
    assert "already present" in capsys.readouterr().out
    assert main(["download", "tum", "--list"]) == 0
    assert "fr3/walking_xyz" in capsys.readouterr().out
    assert main(["download", "tum", "fr9/x", "--to", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown TUM sequence" in err[0]
