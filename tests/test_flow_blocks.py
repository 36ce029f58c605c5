"""Shapes and gradients of each block of the learned flow network, and the exactness of its operators."""

import pytest
import torch
import torch.nn.functional as F
from osslam.frontend.flow.blocks import (
    ConvGRU,
    ModulatedDeformConv,
    ResidualUnit,
    convex_upsample,
    modulated_deform_conv3x3,
    norm_layer,
    tanh,
)
from osslam.frontend.flow.correlation import CorrPyramid
from osslam.frontend.flow.encoder import MultiScaleEncoder
from osslam.frontend.flow.loss import LossConfig, sequence_loss
from osslam.frontend.flow.network import (
    FlowNetConfig,
    FlowPrediction,
    MultiScaleFlowNet,
)
from osslam.frontend.flow.update import MultiScaleUpdate, StandardUpdate


pytestmark = pytest.mark.usefixtures("one_torch_thread")


TINY = {"stem": 8, "widths": [8, 8, 8], "feature_dim": 8, "hidden": 8, "context": 8, "motion_dim": 8,
        "iterations": [2, 1, 1], "radius": 2}


def _grads_reach_all(module: torch.nn.Module) -> bool:
    return all(p.grad is not None and torch.isfinite(p.grad).all() for p in module.parameters())


def test_residual_unit_halves_resolution_and_passes_gradients():
    unit = ResidualUnit(4, 6, stride=2)
    x = torch.randn(2, 4, 16, 20, requires_grad=True)
    y = unit(x)
    assert y.shape == (2, 6, 8, 10)
    y.sum().backward()
    assert _grads_reach_all(unit) and x.grad.abs().sum() > 0


def test_conv_gru_keeps_state_shape_and_bounds():
    gru = ConvGRU(hidden=5, inputs=3, dilation=2)
    h = torch.tanh(torch.randn(1, 5, 9, 11))
    out = gru(h, torch.randn(1, 3, 9, 11))
    assert out.shape == h.shape and out.abs().max() <= 1.0
    out.sum().backward()
    assert _grads_reach_all(gru)


def test_deformable_conv_with_zero_offsets_is_a_plain_convolution():
    x, weight, bias = torch.randn(2, 3, 7, 9), torch.randn(4, 3, 3, 3), torch.randn(4)
    zero, ones = torch.zeros(2, 18, 7, 9), torch.ones(2, 9, 7, 9)
    expected = F.conv2d(x, weight, bias, padding=1)
    assert torch.allclose(modulated_deform_conv3x3(x, zero, ones, weight, bias), expected, atol=1e-5)


def test_deformable_conv_offsets_shift_the_sampling_and_masks_scale_it():
    x, weight = torch.randn(1, 2, 8, 10), torch.randn(3, 2, 3, 3)
    offset = torch.zeros(1, 18, 8, 10)
    offset[:, 1::2] = 1.0  # every tap one pixel to the right
    shifted = F.pad(x[..., 1:], (0, 1))
    out = modulated_deform_conv3x3(x, offset, torch.ones(1, 9, 8, 10), weight, None)
    assert torch.allclose(out[..., 1:-2], F.conv2d(shifted, weight, padding=1)[..., 1:-2], atol=1e-5)
    half = modulated_deform_conv3x3(x, torch.zeros_like(offset), torch.full((1, 9, 8, 10), 0.5), weight, None)
    assert torch.allclose(half, 0.5 * F.conv2d(x, weight, padding=1), atol=1e-5)


def test_deformable_module_learns_offsets():
    dcn = ModulatedDeformConv(channels=4, guide=6)
    x = torch.randn(1, 4, 6, 6)
    dcn(x, torch.randn(1, 6, 6, 6)).pow(2).sum().backward()
    assert dcn.offset_mask.weight.grad.abs().sum() > 0 and dcn.weight.grad.abs().sum() > 0


def test_convex_upsampling_of_constant_flow_is_constant_and_scaled():
    flow = torch.ones(1, 2, 5, 6) * torch.tensor([1.5, -2.0]).view(1, 2, 1, 1)
    up = convex_upsample(flow, torch.randn(1, 9 * 16, 5, 6), 4)
    assert up.shape == (1, 2, 20, 24)
    inner = up[:, :, 4:-4, 4:-4]
    assert torch.allclose(inner[:, 0], torch.full_like(inner[:, 0], 6.0), atol=1e-5)
    assert torch.allclose(inner[:, 1], torch.full_like(inner[:, 1], -8.0), atol=1e-5)


def _raft_lookup(f1, f2, coords, levels, radius):
    """RAFT's reference: the whole all-pairs volume, average-pooled, bilinearly sampled."""
    b, d, h, w = f1.shape
    corr = torch.einsum("bdn,bdm->bnm", f1.view(b, d, -1), f2.view(b, d, -1)).view(b * h * w, 1, h, w) / d ** 0.5
    pyramid = [corr]
    for _ in range(levels - 1):
        pyramid.append(F.avg_pool2d(pyramid[-1], 2, 2))
    r = torch.arange(-radius, radius + 1, dtype=torch.float32)
    dy, dx = torch.meshgrid(r, r, indexing="ij")
    delta = torch.stack([dx, dy], -1).view(1, 2 * radius + 1, 2 * radius + 1, 2)
    centre = coords.permute(0, 2, 3, 1).reshape(b * h * w, 1, 1, 2)
    out = []
    for level, volume in enumerate(pyramid):
        hl, wl = volume.shape[-2:]
        pos = centre / 2 ** level + delta
        grid = torch.stack([2 * pos[..., 0] / (wl - 1) - 1, 2 * pos[..., 1] / (hl - 1) - 1], -1)
        out.append(F.grid_sample(volume, grid, align_corners=True).view(b, h, w, -1))
    return torch.cat(out, -1).permute(0, 3, 1, 2)


def test_correlation_lookup_equals_raft_all_pairs_pyramid():
    torch.manual_seed(0)
    f1, f2 = torch.randn(2, 5, 8, 12), torch.randn(2, 5, 8, 12)
    coords = torch.rand(2, 2, 8, 12) * torch.tensor([12.0, 8.0]).view(1, 2, 1, 1)
    pyramid = CorrPyramid(f1, f2, levels=2, radius=2)
    got = pyramid(coords)
    assert got.shape == (2, pyramid.channels, 8, 12) == (2, 50, 8, 12)
    assert torch.allclose(got, _raft_lookup(f1, f2, coords, 2, 2), atol=1e-5)
    outside = torch.rand(2, 2, 8, 12) * 40 - 14  # windows partly or wholly beyond the image
    assert torch.allclose(pyramid(outside), _raft_lookup(f1, f2, outside, 2, 2), atol=1e-5)
    last = torch.channels_last  # the runtime's layout: the same values
    assert torch.allclose(CorrPyramid(f1.contiguous(memory_format=last), f2.contiguous(memory_format=last),
                                      levels=2, radius=2)(coords), got, atol=1e-6)


def test_fast_tanh_and_instance_norm_equal_torch():
    x = torch.linspace(-30, 30, 20001)
    assert torch.allclose(tanh(x), torch.tanh(x), atol=1e-6, rtol=0)
    y = torch.randn(2, 6, 9, 11) * 3 + 1
    assert torch.allclose(norm_layer("instance", 6)(y), F.instance_norm(y), atol=1e-5)


@pytest.mark.parametrize("unet", [True, False])
def test_encoder_gives_each_requested_scale(unet):
    enc = MultiScaleEncoder(8, (8, 12, 16), out_dim=10, strides=(16, 8, 4), unet=unet)
    out = enc(torch.randn(2, 3, 64, 96))
    assert {s: tuple(t.shape) for s, t in out.items()} == {16: (2, 10, 4, 6), 8: (2, 10, 8, 12), 4: (2, 10, 16, 24)}
    sum(t.sum() for t in out.values()).backward()
    assert _grads_reach_all(enc)


def test_unet_encoder_mixes_deep_features_into_shallow_ones():
    torch.manual_seed(0)
    image = torch.randn(1, 3, 64, 64)
    for unet, expect_change in ((True, True), (False, False)):
        enc = MultiScaleEncoder(8, (8, 8, 8), 8, (16, 8, 4), unet=unet)
        base = enc(image)[4]
        with torch.no_grad():
            enc.down16.conv2.bias += 1.0  # only the 1/16 path changes
        assert (not torch.allclose(enc(image)[4], base)) == expect_change


@pytest.mark.parametrize("update_cls", [MultiScaleUpdate, StandardUpdate])
def test_update_operators_shapes_and_gradients(update_cls):
    update = update_cls(hidden=8, context=6, corr_channels=18, motion_dim=10)
    step = update(torch.zeros(2, 8, 6, 7), torch.randn(2, 6, 6, 7), torch.randn(2, 18, 6, 7), torch.randn(2, 2, 6, 7))
    assert step.hidden.shape == (2, 8, 6, 7) and step.delta.shape == (2, 2, 6, 7) and step.features.shape[1] == 8
    (step.delta.sum() + step.hidden.sum()).backward()
    assert _grads_reach_all(update)


@pytest.mark.parametrize("overrides", [{}, {"scales": [8], "iterations": [3]}, {"update": "standard", "unet": False}])
def test_network_predicts_full_resolution_flow_at_every_step(overrides):
    cfg = FlowNetConfig(**{**TINY, **overrides})
    net = MultiScaleFlowNet(cfg)
    a, b = torch.randn(2, 3, 64, 80), torch.randn(2, 3, 64, 80)
    steps = net(a, b, all_steps=True)
    assert len(steps) == sum(cfg.iterations)
    assert [p.stride for p in steps] == [s for s, n in zip(cfg.scales, cfg.iterations) for _ in range(n)]
    assert all(p.flow.shape == (2, 2, 64, 80) for p in steps)
    final = net(a, b)
    assert len(final) == 1 and torch.allclose(final[0].flow, steps[-1].flow, atol=1e-5)
    sum(p.flow.abs().mean() for p in steps).backward()
    assert _grads_reach_all(net)


def test_final_upsampling_is_convex_for_the_first_items_and_bilinear_for_the_rest():
    torch.manual_seed(0)
    net = MultiScaleFlowNet(FlowNetConfig(**TINY))
    flow, features = torch.randn(3, 2, 4, 5), torch.randn(3, 8, 4, 5)
    with torch.no_grad():
        convex = convex_upsample(flow, net.up_final(features), 4)
        mixed = net._upsample_final(flow, features, 4, convex=1)
        assert torch.equal(net._upsample_final(flow, features, 4, convex=None), convex)
    assert mixed.shape == (3, 2, 16, 20)
    assert torch.allclose(mixed[:1], convex[:1], atol=1e-6)
    bilinear = F.interpolate(flow[1:], size=(16, 20), mode="bilinear", align_corners=False) * 4
    assert torch.allclose(mixed[1:], bilinear, atol=1e-6) and not torch.allclose(mixed[1:], convex[1:], atol=1e-2)


def test_network_config_rejects_bad_scales():
    with pytest.raises(ValueError, match="coarsest first"):
        FlowNetConfig(scales=[4, 8, 16])
    with pytest.raises(ValueError, match="one count"):
        FlowNetConfig(scales=[16, 8], iterations=[1])


def test_sequence_loss_weights_steps_and_scales():
    gt = torch.zeros(1, 2, 4, 4)
    valid = torch.ones(1, 4, 4)
    err = lambda v: torch.full((1, 2, 4, 4), v)  # error of v px per component
    preds = [FlowPrediction(8, err(3.0)), FlowPrediction(4, err(4.0)), FlowPrediction(4, err(0.0))]
    epe = LossConfig(gamma=0.5)
    assert sequence_loss(preds, gt, valid, epe).item() == pytest.approx(0.25 * 3 * 2 ** 0.5 + 0.5 * 4 * 2 ** 0.5, rel=1e-4)
    single = LossConfig(gamma=0.5, multiscale=False)
    assert sequence_loss(preds, gt, valid, single).item() == pytest.approx(0.5 * 4 * 2 ** 0.5, rel=1e-4)
    robust = LossConfig(kind="robust", gamma=0.5, multiscale=False)
    expected = 0.5 * (8 + 0.01) ** 0.7 + (0 + 0.01) ** 0.7
    assert sequence_loss(preds, gt, valid, robust).item() == pytest.approx(expected, rel=1e-4)
    assert sequence_loss(preds, gt, torch.zeros(1, 4, 4), epe).item() == 0.0
