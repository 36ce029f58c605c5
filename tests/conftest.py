"""Shared fixtures: one `osslam run` of TUM fr1/xyz from ../shared, reused by every test that needs it."""

import contextlib
import io
from dataclasses import dataclass
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"  # beside the checkout; tests read it, never copy it
FR1_XYZ = SHARED / "data" / "tum" / "rgbd_dataset_freiburg1_xyz"
MODELS = SHARED / "models"


@dataclass
class CliRun:
    """A finished `osslam run`: its exit code, what it printed and its output folder."""

    code: int
    printed: str
    out: Path


@pytest.fixture(scope="session", autouse=True)
def _onnx_cache_of_the_session(tmp_path_factory):
    """Detector ONNX exports go to a folder of this test session, not the user's cache."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("OSSLAM_ONNX_CACHE", str(tmp_path_factory.mktemp("onnx_cache")))
        yield


@pytest.fixture(scope="session")
def fr1_xyz_run(tmp_path_factory) -> CliRun:
    """`osslam run` on fr1/xyz with the default preset; skips only when the sequence is absent."""
    if not (FR1_XYZ / "rgb.txt").is_file():
        pytest.skip(f"{FR1_XYZ} not present")
    from osslam.cli import main

    out = tmp_path_factory.mktemp("fr1_xyz") / "run"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["run", str(FR1_XYZ), "--out", str(out), "--no-progress"])
    return CliRun(code, printed.getvalue(), out)


@pytest.fixture
def one_torch_thread():
    """Torch on one CPU thread, as the runtime uses; restored afterwards."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
