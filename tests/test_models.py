"""osslam models: the cache folder's precedence, download from a local mirror, checksums, verify."""

import functools
import shutil
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

import pytest

from osslam import models
from osslam.cli import main

from conftest import MODELS as SHARED_MODELS

pytestmark = pytest.mark.skipif(not (SHARED_MODELS / "README.md").is_file(), reason=f"{SHARED_MODELS} not present")


class _Quiet(SimpleHTTPRequestHandler):
    requests: list[str] = []

    def log_message(self, *args):
        pass

    def do_GET(self):
        _Quiet.requests.append(self.path)
        super().do_GET()


@pytest.fixture
def mirror(tmp_path):
    """A copy of the shared model files served on 127.0.0.1, laid out as the cache is."""
    root = tmp_path / "served"
    for model in models.MODELS.values():
        for f in model.files:
            (root / f.path).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(SHARED_MODELS / f.path, root / f.path)
    server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(root)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    _Quiet.requests = []
    yield root, f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_cache_folder_precedence(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv(models.ENV_VAR, raising=False)
    assert models.models_dir() == tmp_path / "xdg" / "osslam" / "models"
    monkeypatch.setenv(models.ENV_VAR, str(tmp_path / "env"))
    assert models.models_dir() == tmp_path / "env"
    assert models.models_dir(str(tmp_path / "cfg")) == tmp_path / "cfg"


def test_download_verifies_and_skips_what_is_there(mirror, tmp_path, capsys):
    _, url = mirror
    cache = tmp_path / "cache"
    assert main(["models", "download", "--dir", str(cache), "--mirror", url]) == 0
    n_files = sum(len(m.files) for m in models.MODELS.values())
    assert len(_Quiet.requests) == n_files
    assert all(st.verified for m in models.MODELS.values() for st in models.status(m, cache))
    assert main(["models", "download", "--dir", str(cache), "--mirror", url]) == 0
    assert len(_Quiet.requests) == n_files  # nothing fetched twice
    assert main(["models", "verify", "--dir", str(cache)]) == 0
    assert "missing" not in capsys.readouterr().out


def test_corrupt_download_is_rejected_and_removed(mirror, tmp_path):
    root, url = mirror
    target = models.MODELS["yolo-fastest-1.1"].files[0]
    (root / target.path).write_text("[net]\n# tampered\n")
    with pytest.raises(models.ModelError, match="SHA-256"):
        models.fetch(models.MODELS["yolo-fastest-1.1"], tmp_path / "cache", url)
    assert not (tmp_path / "cache" / target.path).exists()


def test_verify_reports_missing_and_corrupt_files(tmp_path, capsys):
    cache = tmp_path / "cache"
    model = models.MODELS["mediapipe-selfie-segmentation"]
    for f in model.files:
        (cache / f.path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(SHARED_MODELS / f.path, cache / f.path)
    (cache / model.files[1].path).write_bytes(b"broken")
    assert main(["models", "verify", "mediapipe-selfie-segmentation", "--dir", str(cache)]) == 1
    captured = capsys.readouterr()
    assert "CORRUPT" in captured.out and "1 model file(s)" in captured.err
    assert main(["models", "verify", "no-such-model", "--dir", str(cache)]) == 1
    assert "unknown model" in capsys.readouterr().err
