"""The learned flow backend at runtime, and ``osslam flow eval`` scoring backends on ground-truth flow."""

import json

import cv2
import numpy as np
import pytest
import torch
from osslam.frontend.flow import make_flow_estimator
from osslam.frontend.flow.base import checked_flow
from osslam.frontend.flow.data.mix import to_network
from osslam.frontend.flow.network import FlowNetConfig, MultiScaleFlowNet
from osslam.frontend.flow.weights import BUNDLED, load_weights, save_weights

from osslam.cli import main
from osslam.config import FlowConfig
from osslam.datasets.synthetic import SyntheticConfig, SyntheticSequence
from osslam.errors import OsslamError


@pytest.fixture(autouse=True)
def one_thread():
    """One CPU thread; restored afterwards."""
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


@pytest.fixture
def tiny_weights(tmp_path):
    torch.manual_seed(0)
    cfg = FlowNetConfig(stem=8, widths=[8, 8, 8], feature_dim=8, hidden=8, context=8, motion_dim=8,
                        iterations=[1, 1, 1], radius=2)
    return save_weights(tmp_path / "tiny.pt", MultiScaleFlowNet(cfg), {})


def _shifted_pair(dx: int, dy: int):
    """A textured grey image and the same image moved by (dx, dy) pixels."""
    noise = np.random.default_rng(1).uniform(0, 255, (240 + 40, 320 + 40)).astype(np.float32)
    image = np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0) * 3 - 255, 0, 255).astype(np.uint8)
    return image[20:260, 20:340], image[20 - dy:260 - dy, 20 - dx:340 - dx]


def test_learned_backend_gives_full_resolution_flow_and_validity(tiny_weights):
    est = make_flow_estimator(FlowConfig(backend="learned", weights=str(tiny_weights), working_width=160))
    src, tgt = _shifted_pair(2, 1)
    field = est.compute(src, tgt)
    assert field.flow.shape == (240, 320, 2) and field.flow.dtype == np.float32
    assert field.valid.shape == (240, 320) and field.valid.dtype == bool


def test_checked_flow_scales_each_axis_to_full_resolution():
    src = tgt = _shifted_pair(0, 0)[0]  # 320 x 240, worked at 160 x 100: x scaled by 2, y by 2.4

    def constant(a, b):
        assert a.shape == b.shape == (100, 160)
        return np.full((100, 160, 2), [1.0, 2.0], np.float32), np.full((100, 160, 2), [-1.0, -2.0], np.float32)

    field = checked_flow(src, tgt, (160, 100), constant, FlowConfig())
    assert field.flow.shape == (240, 320, 2) and field.flow.dtype == np.float32
    assert np.allclose(field.flow[..., 0], 2.0) and np.allclose(field.flow[..., 1], 4.8)
    assert field.valid[100:140, 100:200].all() and not field.valid[-1].any()  # consistent; targets beyond the image
    strided = np.zeros((2, 240, 320, 2), np.float32)
    same_size = checked_flow(src, tgt, (320, 240), lambda a, b: (strided[:, :, :, 0].transpose(1, 2, 0),) * 2,
                             FlowConfig())
    assert same_size.flow.shape == (240, 320, 2) and same_size.flow.flags["C_CONTIGUOUS"]


def test_kept_encodings_and_grey_stem_give_the_network_flow(tiny_weights):
    est = make_flow_estimator(FlowConfig(backend="learned", weights=str(tiny_weights), working_width=320))
    a, b = _shifted_pair(2, 1)
    c = np.roll(b, 1, axis=1)
    est.compute(a, b)
    streamed = est.compute(b, c)  # b's encodings are reused
    fresh = make_flow_estimator(FlowConfig(backend="learned", weights=str(tiny_weights), working_width=320))
    assert np.allclose(streamed.flow, fresh.compute(b, c).flow, atol=1e-4)
    net, _ = load_weights(tiny_weights)  # the unchanged network on 3-channel images
    images = [torch.from_numpy(to_network(x, True))[None] for x in (b, c)]
    with torch.inference_mode():
        reference = net(*images)[-1].flow[0].permute(1, 2, 0).numpy()
    assert np.allclose(streamed.flow, reference, atol=1e-4)


def test_weights_with_separate_gru_gates_load_as_the_same_network(tiny_weights, tmp_path):
    state = torch.load(tiny_weights, weights_only=True)
    old = {}
    for key, value in state["state_dict"].items():  # the layout before the gates shared one convolution
        if ".convzr." in key:
            z, r = value.chunk(2)
            old[key.replace(".convzr.", ".convz.")], old[key.replace(".convzr.", ".convr.")] = z, r
        else:
            old[key] = value
    torch.save({**state, "state_dict": old}, tmp_path / "old.pt")
    net, _ = load_weights(tmp_path / "old.pt")
    reference, _ = load_weights(tiny_weights)
    assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), reference.state_dict().values()))


def test_iterations_override_and_missing_weights_are_reported(tiny_weights, tmp_path):
    est = make_flow_estimator(FlowConfig(backend="learned", weights=str(tiny_weights), iterations=[2, 2, 3]))
    assert est.model.iterations == [2, 2, 3]
    with pytest.raises(OsslamError, match="flow.iterations"):
        make_flow_estimator(FlowConfig(backend="learned", weights=str(tiny_weights), iterations=[2]))
    with pytest.raises(OsslamError, match="absent.pt: flow network weights not found"):
        make_flow_estimator(FlowConfig(backend="learned", weights=str(tmp_path / "absent.pt")))
    with pytest.raises(OsslamError, match="no bundled flow weights for flow.learned_preset 'huge'"):
        make_flow_estimator(FlowConfig(backend="learned", learned_preset="huge"))


def test_bundled_weights_recover_a_translation():
    assert BUNDLED.is_file() and BUNDLED.stat().st_size < 5e6
    est = make_flow_estimator(FlowConfig(backend="learned"))
    src, tgt = _shifted_pair(4, -2)
    field = est.compute(src, tgt)
    inner = (slice(30, -30), slice(30, -30))
    err = np.linalg.norm(field.flow[inner] - np.array([4.0, -2.0]), axis=2)
    assert np.median(err) < 0.5 and field.valid[inner].mean() > 0.5


def test_flow_eval_cli_scores_backends_on_rigid_flow(tmp_path, capsys):
    seq = SyntheticSequence(SyntheticConfig(n_frames=3, seed=5, depth_noise=False, dropout=0.0, holes=False))
    folder = seq.write_tum(tmp_path / "room")
    code = main(["flow", "eval", f"tum:{folder}", "--backend", "dis:ultrafast", "--backend", "dis:medium",
                 "--out", str(tmp_path / "eval")])
    assert code == 0
    printed = capsys.readouterr().out
    assert "| dis:ultrafast | 2 |" in printed and "| dis:medium | 2 |" in printed
    results = json.loads((tmp_path / "eval" / "results.json").read_text())["results"]
    medium = results[1]["all"]
    assert 0 < medium["epe"] < 3 and medium["pixels"] > 0 and 0 <= medium["fl_all"] <= 100


def test_flow_eval_cli_rejects_unknown_data_and_backends(tmp_path, capsys):
    assert main(["flow", "eval", "flickr:somewhere"]) == 1
    assert "evaluation data kind 'flickr' unknown" in capsys.readouterr().err
    seq = SyntheticSequence(SyntheticConfig(n_frames=2, seed=5))
    folder = seq.write_tum(tmp_path / "room")
    assert main(["flow", "eval", f"tum:{folder}", "--backend", "raft"]) == 1
    assert "backend 'raft' unknown" in capsys.readouterr().err
