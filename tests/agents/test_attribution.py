"""Tests for sb3_sgfd.sgqn.attribution: SGQN's guided backprop, attribution mask, consistency term and predictor."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn
from torch.nn import functional as F

from sb3_sgfd.sgqn.attribution import (
    AttributionDecoder,
    attribution_loss,
    attribution_mask,
    consistency_loss,
    guided_backprop,
    guided_relus,
    mask_observations,
    overlay,
)

# f(x) = w2 . relu(W1 x): the third unit has a negative output weight, the fourth is inactive at x = (1, 2).
W1 = torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [-1.0, 0.0]])
W2 = torch.tensor([[1.0, -2.0, 3.0, 5.0]])
X = torch.tensor([[1.0, 2.0], [-1.0, 2.0]])


def tiny_net(inplace: bool = False) -> nn.Sequential:
    net = nn.Sequential(nn.Linear(2, 4, bias=False), nn.ReLU(inplace=inplace), nn.Linear(4, 1, bias=False))
    with torch.no_grad():
        net[0].weight.copy_(W1)
        net[2].weight.copy_(W2)
    return net


def plain_gradient(net: nn.Module, x: torch.Tensor) -> torch.Tensor:
    x = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(net(x).sum(), x)
    return grad


def relus(module: nn.Module) -> list[nn.ReLU]:
    return [m for m in module.modules() if isinstance(m, nn.ReLU)]


# --- guided_relus and guided_backprop ---


@pytest.mark.parametrize("inplace", [False, True])
def test_guided_backprop_matches_the_hand_computation(inplace):
    net = tiny_net(inplace)
    guided = guided_backprop(net, X, net)
    active = (X @ W1.T > 0).float()
    # Guided: the gradient reaching each ReLU output, w2, is clamped to >= 0 before the ReLU's own mask.
    manual = (W2.clamp_min(0) * active) @ W1
    assert torch.allclose(guided, manual)
    assert torch.allclose(guided, torch.tensor([[4.0, 3.0], [-2.0, 3.0]]))
    # The plain gradient lets the -2 through: (1, 2) -> (1 + 3, -2 + 3).
    plain = plain_gradient(net, X)
    assert torch.allclose(plain, torch.tensor([[4.0, 1.0], [-2.0, 1.0]]))
    assert not torch.allclose(guided, plain)
    # Hooks are gone: the same network gives the plain gradient again, and no parameter got a .grad.
    assert all(not relu._forward_hooks for relu in relus(net))
    assert torch.equal(plain_gradient(net, X), plain)
    assert all(p.grad is None for p in net.parameters())


def test_guided_backprop_clamps_at_every_relu():
    torch.manual_seed(0)
    layers = [nn.Linear(5, 7), nn.ReLU(), nn.Linear(7, 6), nn.ReLU(), nn.Linear(6, 1)]
    net = nn.Sequential(*layers)
    x = torch.randn(4, 5)
    a1 = layers[0](x)
    a2 = layers[2](a1.relu())
    # Backward by hand, each ReLU passing relu(grad_out) * 1[input > 0].
    g2 = (layers[4].weight.expand(4, -1)).clamp_min(0) * (a2 > 0)
    g1 = (g2 @ layers[2].weight).clamp_min(0) * (a1 > 0)
    manual = g1 @ layers[0].weight
    assert torch.allclose(guided_backprop(net, x, net), manual, atol=1e-6)
    assert not torch.allclose(plain_gradient(net, x), manual, atol=1e-6)


def test_guided_backprop_returns_floats_without_grad_and_leaves_inputs_alone():
    net = nn.Sequential(nn.Flatten(), nn.Linear(12, 3), nn.ReLU(), nn.Linear(3, 1))
    obs = torch.randint(0, 256, (2, 3, 2, 2), dtype=torch.uint8)
    with torch.no_grad():  # SAC calls it inside no_grad
        attribution = guided_backprop(net, obs, net)
    assert attribution.shape == obs.shape and attribution.dtype == torch.float32
    assert not attribution.requires_grad
    obs_float = torch.rand(2, 3, 2, 2, dtype=torch.float64)
    net.double()
    assert guided_backprop(net, obs_float, net).dtype == torch.float64
    assert not obs_float.requires_grad and obs_float.grad is None
    assert all(p.grad is None for p in net.parameters())


def test_guided_relus_removes_its_hooks_on_an_exception():
    net = tiny_net()
    with pytest.raises(RuntimeError, match="boom"), guided_relus(net):
        assert all(relu._forward_hooks for relu in relus(net))
        raise RuntimeError("boom")
    assert all(not relu._forward_hooks for relu in relus(net))
    assert torch.allclose(plain_gradient(net, X), torch.tensor([[4.0, 1.0], [-2.0, 1.0]]))


def test_guided_relus_leaves_forward_values_unchanged():
    net = tiny_net()
    with guided_relus(net) as same:
        assert same is net
        assert torch.equal(net(X), tiny_net()(X))


def test_guided_backprop_through_an_sb3_critic():
    from gymnasium import spaces
    from stable_baselines3.sac.policies import ContinuousCritic

    from sb3_sgfd.common.policies import PixelEncoder

    torch.manual_seed(0)
    obs_space = spaces.Box(0, 255, (6, 16, 16), dtype="uint8")
    action_space = spaces.Box(-1, 1, (2,))
    encoder = PixelEncoder(obs_space, features_dim=8, n_layers=2, n_filters=4)
    critic = ContinuousCritic(
        obs_space,
        action_space,
        net_arch=[16, 16],
        features_extractor=encoder,
        features_dim=8,
        share_features_extractor=False,
    )
    obs = torch.randint(0, 256, (3, 6, 16, 16), dtype=torch.uint8)
    actions = torch.rand(3, 2) * 2 - 1
    attribution = guided_backprop(lambda o: critic(o, actions)[0], obs, critic)
    assert attribution.shape == obs.shape and attribution.abs().sum() > 0
    assert all(p.grad is None for p in critic.parameters())
    assert all(not relu._forward_hooks for relu in relus(critic))
    # The guided ReLUs of the Q heads' MLPs matter: the attribution is not the plain gradient.
    plain = obs.float().requires_grad_(True)
    (grad,) = torch.autograd.grad(critic(plain, actions)[0].sum(), plain)
    assert not torch.allclose(attribution, grad)


def test_guided_backprop_rejects_bad_arguments():
    net = tiny_net()
    with pytest.raises(TypeError, match=r"inputs must be a torch\.Tensor"):
        guided_backprop(net, [[1.0, 2.0]], net)
    with pytest.raises(TypeError, match="fn must be callable"):
        guided_backprop(3, X, net)
    with pytest.raises(TypeError, match=r"module must be a torch\.nn\.Module"):
        guided_backprop(net, X, "net")
    with pytest.raises(ValueError, match="does not depend on its input"):
        guided_backprop(lambda x: net(x.detach()), X, net)
    with pytest.raises(ValueError, match="does not depend on its input"):
        guided_backprop(lambda x: net(X) + 0 * x.sum().detach(), X, net)


# --- attribution_mask ---


@pytest.mark.parametrize("quantile", [0.5, 0.9, 0.98])
@pytest.mark.parametrize(("h", "w"), [(10, 10), (7, 9)])
def test_mask_keeps_the_top_pixels_of_every_frame(quantile, h, w):
    n_pixels = h * w
    generator = torch.Generator().manual_seed(1)
    attribution = torch.zeros(2, 6, h, w)
    for sample in range(2):
        for frame in range(2):  # distinct values in the first channel of each frame, the others zero
            attribution[sample, 3 * frame] = torch.randperm(n_pixels, generator=generator).view(h, w) + 1.0
    mask = attribution_mask(attribution, quantile=quantile)
    assert mask.shape == attribution.shape and mask.dtype == torch.bool
    expected = n_pixels - math.ceil(quantile * (n_pixels - 1))
    assert expected in (math.floor((1 - quantile) * n_pixels), math.ceil((1 - quantile) * n_pixels))
    for sample in range(2):
        for frame in range(2):
            channels = mask[sample, 3 * frame : 3 * frame + 3]
            assert channels.sum().item() == 3 * expected
            assert torch.equal(channels[0], channels[1]) and torch.equal(channels[0], channels[2])
            # exactly the largest values
            assert torch.equal(channels[0], attribution[sample, 3 * frame] > n_pixels - expected)


def test_mask_takes_the_largest_magnitude_over_a_frames_channels():
    attribution = torch.arange(1.0, 33.0).view(1, 1, 4, 8).repeat(1, 6, 1, 1)
    attribution[0, 1, 0, 0] = -1000.0  # the weakest pixel of frame 0, made the strongest by its channel 1
    mask = attribution_mask(attribution, quantile=0.9)
    assert mask[0, 0:3, 0, 0].all()  # every channel of frame 0
    assert not mask[0, 3:6, 0, 0].any()  # frame 1 is untouched
    assert mask[0, 0].sum() == 32 - math.ceil(0.9 * 31)
    # frame 0 gave up its next-weakest salient pixel for it
    assert mask[0, 0].sum() == mask[0, 3].sum() and not torch.equal(mask[0, 0], mask[0, 3])


@pytest.mark.parametrize("channels_per_frame", [1, 3])
def test_mask_matches_the_quantile_definition(channels_per_frame):
    generator = torch.Generator().manual_seed(2)
    attribution = torch.randn(4, 9, 12, 12, generator=generator, dtype=torch.float64)
    mask = attribution_mask(attribution, channels_per_frame=channels_per_frame, quantile=0.95)
    for frame in range(9 // channels_per_frame):
        channels = slice(frame * channels_per_frame, (frame + 1) * channels_per_frame)
        magnitude = attribution[:, channels].abs().amax(dim=1)
        threshold = torch.quantile(magnitude.flatten(1), 0.95, dim=1)
        expected = (magnitude >= threshold[:, None, None]).unsqueeze(1).expand(-1, channels_per_frame, -1, -1)
        assert torch.equal(mask[:, channels], expected)


def test_mask_keeps_ties_at_the_threshold():
    assert attribution_mask(torch.zeros(2, 3, 4, 4)).all()


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"attribution": torch.zeros(3, 4, 4)}, ValueError, r"attribution must have shape \(n, C, H, W\)"),
        ({"attribution": "a"}, TypeError, "attribution must be a torch.Tensor"),
        ({"quantile": 1.0}, ValueError, r"quantile must be a number in \(0, 1\)"),
        ({"quantile": 0}, ValueError, "quantile"),
        ({"quantile": True}, ValueError, "quantile"),
        ({"channels_per_frame": 4}, ValueError, "not divisible by channels_per_frame=4"),
        ({"channels_per_frame": 0}, ValueError, "channels_per_frame must be a positive integer"),
        ({"attribution": torch.zeros(1, 3, 0, 4)}, ValueError, "at least one pixel"),
    ],
)
def test_mask_rejects_bad_arguments(kwargs, error, match):
    kwargs = {"attribution": torch.zeros(2, 6, 4, 4), **kwargs}
    with pytest.raises(error, match=match):
        attribution_mask(**kwargs)


# --- mask_observations and consistency_loss ---


def test_mask_observations_fills_the_masked_out_entries_with_one_value():
    generator = torch.Generator().manual_seed(3)
    obs = torch.randint(10, 200, (4, 6, 5, 5), generator=generator, dtype=torch.uint8)
    mask = torch.rand(4, 6, 5, 5, generator=generator) > 0.7
    state = torch.get_rng_state()
    masked = mask_observations(obs, mask, torch.Generator().manual_seed(0))
    assert torch.equal(torch.get_rng_state(), state)
    assert masked.dtype == torch.float32 and masked.shape == obs.shape
    assert torch.equal(masked[mask], obs[mask].float())
    fill = masked[~mask].unique()
    assert fill.numel() == 1 and obs.min() <= fill.item() <= obs.max()
    assert torch.equal(mask_observations(obs, mask, torch.Generator().manual_seed(0)), masked)
    assert not torch.equal(mask_observations(obs, mask, torch.Generator().manual_seed(1)), masked)


def test_mask_observations_keeps_float_dtype_and_gradient():
    obs = torch.rand(2, 3, 2, 2, dtype=torch.float64, requires_grad=True)
    mask = torch.zeros(2, 3, 2, 2, dtype=torch.bool)
    mask[0] = True
    masked = mask_observations(obs, mask, torch.Generator().manual_seed(0))
    assert masked.dtype == torch.float64
    masked.sum().backward()
    assert torch.equal(obs.grad, mask.double())


@pytest.mark.parametrize(
    ("obs", "mask", "error", "match"),
    [
        (torch.zeros(2, 3), torch.zeros(2, 3), TypeError, "mask must be a bool tensor"),
        (torch.zeros(2, 3), torch.zeros(3, 2, dtype=torch.bool), ValueError, r"mask must have the shape of obs"),
        (torch.zeros(0, 3), torch.zeros(0, 3, dtype=torch.bool), ValueError, "obs must not be empty"),
        (None, torch.zeros(2, dtype=torch.bool), TypeError, "obs must be a torch.Tensor"),
    ],
)
def test_mask_observations_rejects_bad_arguments(obs, mask, error, match):
    with pytest.raises(error, match=match):
        mask_observations(obs, mask)


def test_consistency_loss_is_half_the_sum_of_the_heads_mse():
    generator = torch.Generator().manual_seed(4)
    q = [torch.randn(8, 1, generator=generator, requires_grad=True) for _ in range(2)]
    masked = [torch.randn(8, 1, generator=generator, requires_grad=True) for _ in range(2)]
    loss = consistency_loss(q, masked)
    direct = 0.5 * (((q[0] - masked[0]) ** 2).mean() + ((q[1] - masked[1]) ** 2).mean())
    assert torch.allclose(loss, direct)
    loss.backward()  # neither side is detached
    assert all(t.grad is not None and t.grad.abs().sum() > 0 for t in q + masked)
    assert torch.allclose(consistency_loss((q[0],), (masked[0],)), 0.5 * F.mse_loss(q[0], masked[0]))


@pytest.mark.parametrize(
    ("q", "masked", "match"),
    [
        ([], [], "same number"),
        ([torch.zeros(2, 1)], [torch.zeros(2, 1)] * 2, "same number"),
        ([torch.zeros(2, 1)], [torch.zeros(3, 1)], "same shape"),
        ([torch.zeros(2, 1)], [[0.0, 0.0]], "masked_q_values"),
    ],
)
def test_consistency_loss_rejects_bad_arguments(q, masked, match):
    with pytest.raises((ValueError, TypeError), match=match):
        consistency_loss(q, masked)


# --- overlay ---


def image_bank() -> torch.Tensor:
    """Five constant images (value 10 * (k + 1) in every channel), so that each blend shows its image."""
    return (torch.arange(1, 6, dtype=torch.uint8) * 10).view(5, 1, 1, 1).expand(5, 3, 6, 6).contiguous()


def test_overlay_at_alpha_0_and_1():
    generator = torch.Generator().manual_seed(5)
    obs = torch.randint(0, 256, (32, 9, 6, 6), generator=generator, dtype=torch.uint8)
    assert torch.equal(overlay(obs, image_bank(), alpha=0.0), obs.float())
    state = torch.get_rng_state()
    tiled = overlay(obs, image_bank(), alpha=1.0, generator=torch.Generator().manual_seed(0))
    assert torch.equal(torch.get_rng_state(), state)
    # each sample is one bank image, the same over its three frames
    values = tiled.flatten(1)
    assert torch.equal(values, values[:, :1].expand_as(values))
    assert set(values[:, 0].tolist()) <= {10.0, 20.0, 30.0, 40.0, 50.0} and values[:, 0].unique().numel() > 1


def test_overlay_blends_within_the_observation_range():
    generator = torch.Generator().manual_seed(6)
    obs = torch.randint(0, 256, (16, 6, 6, 6), generator=generator).float()
    bank = torch.randint(0, 256, (4, 3, 6, 6), generator=generator, dtype=torch.uint8)
    blended = overlay(obs, bank, generator=torch.Generator().manual_seed(1))
    assert blended.dtype == torch.float32 and blended.shape == obs.shape
    assert blended.min() >= 0 and blended.max() <= 255
    image = 2 * blended - obs  # alpha 0.5: the image each sample got
    assert torch.equal(image[:, :3], image[:, 3:])
    assert all(any(torch.equal(img, b.float()) for b in bank) for img in image[:, :3])
    assert torch.equal(overlay(obs, bank, generator=torch.Generator().manual_seed(1)), blended)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"alpha": 1.5}, r"alpha must be a number in \[0, 1\]"),
        ({"alpha": -0.1}, "alpha"),
        ({"images": torch.zeros(2, 3, 5, 6)}, r"images must have shape \(N >= 1, 3, 6, 6\)"),
        ({"images": torch.zeros(0, 3, 6, 6)}, "images must have shape"),
        ({"images": torch.zeros(3, 6, 6)}, r"images must have shape \(n, C, H, W\)"),
        ({"channels_per_frame": 4}, "not divisible by channels_per_frame=4"),
    ],
)
def test_overlay_rejects_bad_arguments(kwargs, match):
    kwargs = {"obs": torch.zeros(2, 9, 6, 6), "images": torch.zeros(2, 3, 6, 6), **kwargs}
    with pytest.raises(ValueError, match=match):
        overlay(**kwargs)


# --- AttributionDecoder and attribution_loss ---


@pytest.mark.parametrize(
    ("image_shape", "grid"), [((9, 84, 84), (21, 21)), ((3, 20, 20), (5, 5)), ((3, 21, 18), (6, 5))]
)
def test_decoder_output_shape(image_shape, grid):
    decoder = AttributionDecoder(50, 6, image_shape)
    assert decoder.grid == grid and decoder.proj.out_features == 32 * grid[0] * grid[1]
    logits = decoder(torch.zeros(2, 50), torch.zeros(2, 6))
    assert logits.shape == (2, *image_shape)


def test_decoder_matches_the_official_layout_at_84():
    decoder = AttributionDecoder(50, 6, (9, 84, 84))
    assert decoder.proj.out_features == 14112
    convs = [m for m in decoder.net if isinstance(m, nn.Conv2d)]
    assert [(c.in_channels, c.out_channels, c.kernel_size, c.padding) for c in convs] == [
        (32, 128, (3, 3), (1, 1)),
        (128, 64, (3, 3), (1, 1)),
        (64, 9, (3, 3), (1, 1)),
    ]


def test_attribution_loss_is_the_mean_binary_cross_entropy():
    logits = torch.tensor([[[[2.0, -1.0], [0.0, 3.0]]]])
    mask = torch.tensor([[[[True, False], [True, False]]]])
    by_hand = (math.log1p(math.exp(-2.0)) + math.log1p(math.exp(-1.0)) + math.log(2.0) + math.log1p(math.exp(3.0))) / 4
    assert attribution_loss(logits, mask).item() == pytest.approx(by_hand)
    assert torch.allclose(attribution_loss(logits, mask), F.binary_cross_entropy_with_logits(logits, mask.float()))


def test_decoder_learns_a_fixed_mask():
    torch.manual_seed(7)
    features, actions = torch.randn(8, 10), torch.rand(8, 2) * 2 - 1
    mask = torch.rand(8, 3, 16, 16) > 0.8
    decoder = AttributionDecoder(10, 2, (3, 16, 16))
    optimizer = torch.optim.Adam(decoder.parameters(), lr=3e-3)
    losses = []
    for _ in range(150):
        loss = attribution_loss(decoder(features, actions), mask)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    # The best prediction blind to the features, the mask's frequency p everywhere, has loss H(p) ~ 0.5.
    p = mask.float().mean().item()
    blind = -(p * math.log(p) + (1 - p) * math.log(1 - p))
    assert losses[0] > 0.6 and losses[-1] < 0.5 * blind


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((0, 2, (3, 8, 8)), "features_dim must be a positive integer"),
        ((4, 2.0, (3, 8, 8)), "action_dim must be a positive integer"),
        ((4, 2, (8, 8)), r"image_shape must be \(C, H, W\)"),
        ((4, 2, (3, 0, 8)), r"image_shape\[1\] must be a positive integer"),
    ],
)
def test_decoder_rejects_bad_sizes(args, match):
    with pytest.raises(ValueError, match=match):
        AttributionDecoder(*args)


def test_decoder_and_loss_reject_bad_inputs():
    decoder = AttributionDecoder(4, 2, (3, 8, 8))
    with pytest.raises(ValueError, match=r"features must have shape \(n, 4\)"):
        decoder(torch.zeros(2, 5), torch.zeros(2, 2))
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 2\)"):
        decoder(torch.zeros(2, 4), torch.zeros(3, 2))
    with pytest.raises(ValueError, match="mask must have the shape of logits"):
        attribution_loss(torch.zeros(2, 3, 8, 8), torch.zeros(2, 3, 8, 7, dtype=torch.bool))


def test_overlay_images_over_their_pixel_limit_are_refused_before_they_are_decoded(tmp_path):
    # a 16000 x 16000 PNG's first chunk (its header, 60 bytes): refused by the pixels it declares, nothing decoded
    import struct
    import zlib

    from sb3_sgfd.sgqn.sgqn import read_images

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">IIBBBBB", 16000, 16000, 8, 2, 0, 0, 0)
    (tmp_path / "huge.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IEND", b""))
    with pytest.raises(ValueError, match=r"overlay_dir: .*huge.png' is 256000000 pixels, over the limit"):
        read_images(tmp_path)
