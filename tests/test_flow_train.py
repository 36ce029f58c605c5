"""Training of the flow network: presets, a few steps lowering the loss, checkpoints, resume and weight files."""

import csv

import pytest
import torch
from osslam.frontend.flow.network import MultiScaleFlowNet
from osslam.frontend.flow.settings import load_train_config
from osslam.frontend.flow.train import make_stream, train, train_step
from osslam.frontend.flow.weights import load_weights, save_weights

from osslam.config import ConfigError
from osslam.errors import InputError, OsslamError

TINY = ["model.stem=8", "model.widths=[8, 8, 8]", "model.feature_dim=8", "model.hidden=8", "model.context=8",
        "model.motion_dim=8", "model.iterations=[1, 1, 1]", "model.radius=2", "optim.batch=2", "optim.crop=[48, 64]",
        "data.weights={procedural: 1.0}", "data.procedural.size=[48, 64]", "optim.log_every=1",
        "optim.checkpoint_every=2"]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_presets_load_and_overrides_apply():
    small = load_train_config("small")
    assert small.model.scales == [16, 8, 4] and small.model.levels == 2 and small.model.update == "multiscale"
    paper = load_train_config("paper")
    assert paper.model.stem == 64 and paper.model.radius == 4
    assert load_train_config("finetune").loss.kind == "robust"
    cfg = load_train_config("small", ["model.unet=false", "data.procedural.noise=1.5", "optim.steps=7"])
    assert cfg.model.unet is False and cfg.data.procedural.noise == 1.5 and cfg.optim.steps == 7
    with pytest.raises(ConfigError, match="unknown flow preset 'nope'"):
        load_train_config("nope")
    with pytest.raises(ConfigError, match="unknown key 'colour'"):
        load_train_config("small", ["model.colour=1"])
    with pytest.raises(ConfigError, match="coarsest first"):
        load_train_config("small", ["model.scales=[4, 8, 16]"])


def test_training_stream_is_a_function_of_seed_and_step():
    cfg = load_train_config("small", TINY)
    a, b = make_stream(cfg)(3), make_stream(cfg)(3)
    assert torch.equal(a.image1, b.image1) and torch.equal(a.flow, b.flow)
    assert a.image1.shape == (2, 3, 48, 64) and a.valid.shape == (2, 48, 64)
    assert torch.equal(a.image1[:, 0], a.image1[:, 1])  # grey, replicated
    assert not torch.equal(make_stream(cfg)(4).flow, a.flow)


def test_a_few_steps_lower_the_loss_on_a_fixed_batch():
    torch.manual_seed(0)
    cfg = load_train_config("small", TINY)
    net = MultiScaleFlowNet(cfg.model)
    opt = torch.optim.AdamW(net.parameters(), lr=3e-3)
    batch = make_stream(cfg)(0)
    losses = [train_step(net, opt, batch, cfg, torch.device("cpu"), None) for _ in range(8)]
    assert losses[-1] < 0.8 * losses[0]


def test_train_writes_log_checkpoint_and_weights_and_resumes(tmp_path):
    cfg = load_train_config("small", TINY + ["optim.steps=2"])
    first = train(cfg, tmp_path, progress=False)
    assert first.weights.is_file() and (tmp_path / "checkpoint.pt").is_file()
    cfg.optim.steps = 4
    train(cfg, tmp_path, resume=True, progress=False)
    rows = list(csv.DictReader((tmp_path / "train_log.csv").open()))
    assert [int(r["step"]) for r in rows] == [1, 2, 3, 4]
    net, meta = load_weights(tmp_path / "weights.pt")
    assert meta["steps"] == 4 and net.cfg.hidden == 8


def test_weights_round_trip_and_clear_errors(tmp_path):
    cfg = load_train_config("small", TINY)
    net = MultiScaleFlowNet(cfg.model).eval()
    save_weights(tmp_path / "w.pt", net, {"note": "x"})
    loaded, meta = load_weights(tmp_path / "w.pt")
    a, b = torch.randn(1, 3, 32, 48), torch.randn(1, 3, 32, 48)
    with torch.no_grad():
        assert torch.equal(net(a, b)[-1].flow, loaded(a, b)[-1].flow)
    assert meta == {"note": "x"}
    with pytest.raises(OsslamError, match="nowhere.pt: flow network weights not found"):
        load_weights(tmp_path / "nowhere.pt")
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="bad.pt"):
        load_weights(tmp_path / "bad.pt")
