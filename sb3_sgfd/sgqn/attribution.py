"""Saliency-guided Q-networks (SGQN, Bertoin et al., NeurIPS 2022, "Look where you look!").

Pure torch, no Stable-Baselines3 import. Read top to bottom next to the paper and its official code
(SuReLI/SGQN, ``DMC/src``):

1. ``guided_relus`` and ``guided_backprop``: the attribution of Q1(s, a) to the pixels of s, by guided
   backpropagation (every ReLU passes back only positive gradients; captum's ``GuidedBackprop`` there).
2. ``attribution_mask``: the binarised attribution M_rho(s, a): per stacked frame, the pixels whose largest
   |attribution| over the frame's channels reaches the rho-quantile of that frame (``compute_attribution_mask``).
3. ``mask_observations`` and ``consistency_loss``: the consistency term, Q(s, a) against Q(s * M, a) with the
   masked-out pixels set to one random value, added to the critic loss (``SGSAC.update_critic``).
4. ``overlay``: the observation blended with a natural image (``random_overlay``), the input of the attribution
   predictor; the caller supplies the image bank (the official code draws from Places365).
5. ``AttributionDecoder`` and ``attribution_loss``: self-supervised attribution prediction, a decoder from the
   critic encoder's features and the action to logits of M, trained by binary cross-entropy (``AttributionDecoder``,
   ``SGSAC.compute_attribution_loss``).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from sb3_sgfd.common.validation import check_positive_int


def _check_tensor(x: object, name: str, dim: int | None = None) -> None:
    """Refuse ``x`` unless it is a tensor, with ``dim`` dimensions where given."""
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if dim is not None and x.dim() != dim:
        layout = "(n, C, H, W)" if dim == 4 else f"{dim} dimensions"
        raise ValueError(f"{name} must have shape {layout}, got {tuple(x.shape)}")


def _check_frames(channels: int, channels_per_frame: int, name: str) -> None:
    """Refuse a frame size that does not divide the ``channels`` of the stacked images ``name``."""
    check_positive_int(channels_per_frame=channels_per_frame)
    if channels % channels_per_frame != 0:
        raise ValueError(
            f"the {channels} channels of {name} are not divisible by channels_per_frame={channels_per_frame}"
        )


def _float_copy(x: Tensor) -> Tensor:
    """``x`` detached, as floats (its own dtype if floating, else torch's default one)."""
    x = x.detach()
    return x if x.is_floating_point() else x.to(torch.get_default_dtype())


def _sample_device(generator: torch.Generator | None, device: torch.device) -> torch.device:
    # Sample where the generator lives (a CPU generator cannot fill a CUDA tensor), then move.
    return generator.device if generator is not None else device


# --- 1. Guided backpropagation ---


class _GuidedReLU(torch.autograd.Function):
    """relu(x) whose backward is relu(grad_out) * 1[x > 0]: the ReLU's input gradient clamped to >= 0."""

    @staticmethod
    def forward(ctx: torch.autograd.function.FunctionCtx, x: Tensor) -> Tensor:
        out = x.clamp_min(0)
        ctx.save_for_backward(out)
        return out

    @staticmethod
    def backward(ctx: torch.autograd.function.FunctionCtx, grad_out: Tensor) -> Tensor:
        (out,) = ctx.saved_tensors  # type: ignore[attr-defined]
        # relu(grad_out * 1[x > 0]) = relu(grad_out) * 1[x > 0]; the gradient at x = 0 is 0, as in torch's relu.
        return grad_out.clamp_min(0) * (out > 0)


def _guided_output(module: nn.Module, args: tuple[Tensor, ...], output: Tensor) -> Tensor | None:
    """Forward hook of an nn.ReLU: the same values, from ``_GuidedReLU`` so that its backward is guided."""
    if not torch.is_grad_enabled():
        return None
    # An inplace ReLU has already overwritten its input with relu(x): relu of that is the same, and the mask
    # (relu(x) > 0) = (x > 0), so the guided gradient is right either way.
    return _GuidedReLU.apply(args[0])


@contextlib.contextmanager
def guided_relus(module: nn.Module) -> Iterator[nn.Module]:
    """While active, every ``nn.ReLU`` submodule of ``module`` (``module`` itself included) passes back only
    positive gradients: its input gradient becomes relu(grad), as in guided backpropagation.

    A forward hook on each ReLU reroutes its output through an autograd function with that backward, so it
    works for inplace ReLUs and for SB3's MLPs (one ``nn.ReLU`` instance per layer) alike; only graphs built
    inside the context are affected. Functional ``F.relu`` calls are not nn.ReLU modules and stay plain (the
    official code's captum hooks also see modules only). The hooks are removed on exit, even on an exception.

    :param module: network whose ReLU modules are guided, e.g. the critic
    :return: ``module``
    """
    if not isinstance(module, nn.Module):
        raise TypeError(f"module must be a torch.nn.Module, got {type(module).__name__}")
    handles = []
    try:
        for submodule in module.modules():
            if isinstance(submodule, nn.ReLU):
                handles.append(submodule.register_forward_hook(_guided_output))
        yield module
    finally:
        for handle in handles:
            handle.remove()


def guided_backprop(fn: Callable[[Tensor], Tensor], inputs: Tensor, module: nn.Module) -> Tensor:
    """Guided-backpropagation attribution of fn(inputs).sum() to ``inputs`` (SGQN's attribution of Q1).

    For SGQN, ``fn = lambda obs: critic(obs, actions)[0]`` and ``module = critic``: samples do not interact,
    so the gradient of the sum is each sample's d Q1(s_k, a_k) / d s_k. The gradient is taken with
    ``torch.autograd.grad`` with respect to a float copy of ``inputs``: the parameters' ``.grad`` and
    ``inputs`` itself are left untouched (the official code sets requires_grad on the observation batch).
    Grad mode is switched on inside, so callers may be in ``torch.no_grad()``. Train/eval mode is left as is.

    :param fn: maps a batch like ``inputs`` (as floats) to outputs whose sum is attributed, e.g. Q1 values (n, 1)
    :param inputs: observations, e.g. (n, C, H, W) pixels, any dtype (converted to floats, values unchanged)
    :param module: the network whose ``nn.ReLU`` modules are guided (see ``guided_relus``)
    :return: attribution of the shape of ``inputs``, floating point, without grad
    """
    if not callable(fn):
        raise TypeError(f"fn must be callable, got {type(fn).__name__}")
    _check_tensor(inputs, "inputs")
    x = _float_copy(inputs).clone().requires_grad_(True)
    with torch.enable_grad(), guided_relus(module):
        output = fn(x)
        if not isinstance(output, Tensor):
            raise TypeError(f"fn must return a torch.Tensor, got {type(output).__name__}")
        if not output.requires_grad:
            # e.g. SB3's ContinuousCritic with share_features_extractor=True runs its encoder under no_grad.
            raise ValueError("fn's output does not depend on its input with grad; nothing to attribute")
        (grad,) = torch.autograd.grad(output.sum(), x, allow_unused=True)
    if grad is None:
        raise ValueError("fn's output does not depend on its input with grad; nothing to attribute")
    return grad.detach()


# --- 2. Attribution mask ---


def attribution_mask(attribution: Tensor, channels_per_frame: int = 3, quantile: float = 0.9) -> Tensor:
    """The binarised attribution M_rho: per sample and stacked frame, the pixels whose attribution reaches the
    ``quantile`` of that frame's pixels, repeated over the frame's channels.

    Frame f holds channels [f * channels_per_frame, (f + 1) * channels_per_frame). A pixel's attribution in a
    frame is its largest |attribution| over those channels; the threshold is the quantile over the frame's
    H * W pixels with linear interpolation (``torch.quantile``'s default, which the official code uses; sorted
    here, which has no limit on the input size), and a pixel is salient when its attribution is >= the
    threshold. With distinct values that keeps H*W - ceil(quantile * (H*W - 1)) pixels, floor or ceil of
    (1 - quantile) * H * W; ties at the threshold are all kept (an all-zero frame is wholly salient), and a
    frame with NaN attributions has no salient pixel.

    :param attribution: (n, C, H, W), e.g. from ``guided_backprop``
    :param channels_per_frame: channels of one stacked frame (3 for RGB)
    :param quantile: rho in (0, 1); the official default is 0.9, its DMC scripts use 0.98
    :return: bool mask of the shape of ``attribution``
    """
    _check_tensor(attribution, "attribution", dim=4)
    n, c, h, w = attribution.shape
    _check_frames(c, channels_per_frame, "attribution")
    if isinstance(quantile, bool) or not isinstance(quantile, (int, float)) or not 0 < quantile < 1:
        raise ValueError(f"quantile must be a number in (0, 1), got {quantile!r}")
    if h * w == 0:
        raise ValueError(f"attribution must have at least one pixel, got {tuple(attribution.shape)}")
    frames = c // channels_per_frame
    magnitude = _float_copy(attribution).abs().reshape(n, frames, channels_per_frame, h * w).amax(dim=2)
    values = magnitude.sort(dim=-1).values
    # torch.quantile's "linear": interpolate between the order statistics around position q * (N - 1).
    position = quantile * (h * w - 1)
    below = math.floor(position)
    above = min(below + 1, h * w - 1)
    threshold = torch.lerp(values[..., below], values[..., above], position - below)
    salient = magnitude >= threshold.unsqueeze(-1)  # (n, frames, H*W)
    return salient.reshape(n, frames, 1, h, w).expand(n, frames, channels_per_frame, h, w).reshape(n, c, h, w)


# --- 3. Consistency term ---


def mask_observations(obs: Tensor, mask: Tensor, generator: torch.Generator | None = None) -> Tensor:
    """s * M with every masked-out entry set to one random value, uniform in [min(obs), max(obs)] of the batch.

    One value for the whole batch, as in the official code (``random.uniform(obs.min(), obs.max())``). The
    minimum and maximum stay on the device (no host synchronisation).

    :param obs: observations, any shape, e.g. (n, C, H, W) pixels in 0..255
    :param mask: bool tensor of the same shape, True where salient (``attribution_mask``)
    :param generator: source of the random value, sampled on its device and then moved, so the global RNG is
        left untouched; None draws it from the global RNG
    :return: masked observations, floating point (obs's dtype if floating, else torch's default), on obs's device;
        differentiable with respect to ``obs`` where the mask is True
    """
    _check_tensor(obs, "obs")
    _check_tensor(mask, "mask")
    if mask.dtype != torch.bool:
        raise TypeError(f"mask must be a bool tensor, got {mask.dtype}")
    if mask.shape != obs.shape:
        raise ValueError(f"mask must have the shape of obs {tuple(obs.shape)}, got {tuple(mask.shape)}")
    if obs.numel() == 0:
        raise ValueError(f"obs must not be empty, got shape {tuple(obs.shape)}")
    x = obs if obs.is_floating_point() else obs.to(torch.get_default_dtype())
    low, high = x.detach().min(), x.detach().max()
    u = torch.rand((), generator=generator, device=_sample_device(generator, x.device)).to(x)
    fill = low + (high - low) * u
    return torch.where(mask.to(x.device), x, fill)


def consistency_loss(q_values: Sequence[Tensor], masked_q_values: Sequence[Tensor]) -> Tensor:
    """SGQN's consistency term 0.5 * sum_i MSE(Q_i(s, a), Q_i(s * M, a)), over the critic's heads.

    Neither side is detached (the official code backpropagates through both). For SAC's two heads it is the
    mean of the two MSEs; the caller adds it to the critic loss.

    :param q_values: each head's Q(s, a), e.g. the tuple a twin critic returns
    :param masked_q_values: each head's Q(s * M, a), in the same order and shapes
    :return: scalar loss
    """
    q_values, masked_q_values = list(q_values), list(masked_q_values)
    if not q_values or len(q_values) != len(masked_q_values):
        raise ValueError(
            "q_values and masked_q_values must hold the same number (>= 1) of heads, "
            f"got {len(q_values)} and {len(masked_q_values)}"
        )
    for i, (q, masked) in enumerate(zip(q_values, masked_q_values, strict=True)):
        _check_tensor(q, f"q_values[{i}]")
        _check_tensor(masked, f"masked_q_values[{i}]")
        if q.shape != masked.shape:
            raise ValueError(
                f"q_values[{i}] and masked_q_values[{i}] must have the same shape, "
                f"got {tuple(q.shape)} and {tuple(masked.shape)}"
            )
    errors = [F.mse_loss(q, masked) for q, masked in zip(q_values, masked_q_values, strict=True)]
    return 0.5 * torch.stack(errors).sum()


# --- 4. Overlay ---


def overlay(
    obs: Tensor,
    images: Tensor,
    alpha: float = 0.5,
    channels_per_frame: int = 3,
    generator: torch.Generator | None = None,
) -> Tensor:
    """(1 - alpha) * s + alpha * image, one random image of the bank per sample, the same over all its frames.

    The official ``random_overlay`` blends Places365 images (alpha 0.5) into the observation in [0, 1] and
    rescales by 255; with the images already in the observation's range (0..255) that is this formula. Images
    must have the observation's height and width (resize the bank once, beforehand); keep the bank on the
    observations' device to avoid a copy per call.

    :param obs: observations (n, C, H, W), C = frames * channels_per_frame, e.g. pixels in 0..255
    :param images: image bank (N, channels_per_frame, H, W), float or uint8, in the range of ``obs``
    :param alpha: weight in [0, 1] of the image; 0 returns ``obs`` (as floats), 1 the tiled images
    :param channels_per_frame: channels of one stacked frame (3 for RGB)
    :param generator: source of the image indices, sampled on its device and then moved, so the global RNG is
        left untouched; None draws them from the global RNG
    :return: blended observations (n, C, H, W), floating point (obs's dtype if floating, else torch's default)
    """
    _check_tensor(obs, "obs", dim=4)
    _check_tensor(images, "images", dim=4)
    n, c, h, w = obs.shape
    _check_frames(c, channels_per_frame, "obs")
    if images.shape[0] < 1 or images.shape[1:] != (channels_per_frame, h, w):
        raise ValueError(
            f"images must have shape (N >= 1, {channels_per_frame}, {h}, {w}) to match obs, got {tuple(images.shape)}"
        )
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0 <= alpha <= 1:
        raise ValueError(f"alpha must be a number in [0, 1], got {alpha!r}")
    x = obs if obs.is_floating_point() else obs.to(torch.get_default_dtype())
    index = torch.randint(0, images.shape[0], (n,), generator=generator, device=_sample_device(generator, x.device))
    chosen = images[index.to(images.device)].to(device=x.device, dtype=x.dtype)
    return (1 - alpha) * x + alpha * chosen.repeat(1, c // channels_per_frame, 1, 1)


# --- 5. Attribution prediction ---


class AttributionDecoder(nn.Module):
    """SGQN's attribution predictor head: logits of the mask M from the critic encoder's features and the action.

    Linear(features_dim + action_dim -> 32 * H/4 * W/4) -> (32, H/4, W/4) -> ReLU -> conv 3x3 32->128 -> nearest
    upsample x2 -> ReLU -> conv 3x3 128->64 -> upsample x2 -> ReLU -> conv 3x3 64->C (all convolutions padded by
    1), as in the official code for 84 x 84 x 9 (32 * 21 * 21 = 14112 projected units). For H or W not divisible
    by 4 the grid is ceil(H/4) x ceil(W/4) and the logits are resized to (H, W) at the end, bilinearly (the
    official decoder is fixed to 84 x 84).

    :param features_dim: size of the encoder's features
    :param action_dim: size of the action
    :param image_shape: (C, H, W) of the observations (channel first)
    """

    def __init__(self, features_dim: int, action_dim: int, image_shape: tuple[int, int, int]) -> None:
        super().__init__()
        check_positive_int(features_dim=features_dim, action_dim=action_dim)
        self.features_dim = features_dim
        self.action_dim = action_dim
        if not isinstance(image_shape, Sequence) or len(image_shape) != 3:
            raise ValueError(f"image_shape must be (C, H, W), got {image_shape!r}")
        check_positive_int(**{f"image_shape[{i}]": size for i, size in enumerate(image_shape)})
        c, h, w = image_shape
        self.image_shape = (c, h, w)
        self.grid = (math.ceil(h / 4), math.ceil(w / 4))
        self.proj = nn.Linear(features_dim + action_dim, 32 * self.grid[0] * self.grid[1])
        self.net = nn.Sequential(
            nn.ReLU(),
            nn.Conv2d(32, 128, kernel_size=3, padding=1),
            nn.Upsample(scale_factor=2, mode="nearest"),
            nn.ReLU(),
            nn.Conv2d(128, 64, kernel_size=3, padding=1),
            nn.Upsample(scale_factor=2, mode="nearest"),
            nn.ReLU(),
            nn.Conv2d(64, c, kernel_size=3, padding=1),
        )

    def forward(self, features: Tensor, actions: Tensor) -> Tensor:
        """:param features: encoder features (n, features_dim)
        :param actions: actions (n, action_dim)
        :return: mask logits (n, C, H, W)"""
        _check_tensor(features, "features")
        _check_tensor(actions, "actions")
        if features.dim() != 2 or features.shape[1] != self.features_dim:
            raise ValueError(f"features must have shape (n, {self.features_dim}), got {tuple(features.shape)}")
        if actions.shape != (features.shape[0], self.action_dim):
            raise ValueError(
                f"actions must have shape ({features.shape[0]}, {self.action_dim}), got {tuple(actions.shape)}"
            )
        x = self.proj(torch.cat([features, actions.to(features.dtype)], dim=1))
        logits = self.net(x.view(-1, 32, *self.grid))
        size = self.image_shape[1:]
        if logits.shape[-2:] != size:
            logits = F.interpolate(logits, size=size, mode="bilinear", align_corners=False)
        return logits


def attribution_loss(logits: Tensor, mask: Tensor) -> Tensor:
    """Binary cross-entropy of the predicted mask logits against the attribution mask M (mean over entries).

    :param logits: ``AttributionDecoder`` output (n, C, H, W)
    :param mask: target mask of the same shape, bool or floats in [0, 1]; detached
    :return: scalar loss
    """
    _check_tensor(logits, "logits")
    _check_tensor(mask, "mask")
    if mask.shape != logits.shape:
        raise ValueError(f"mask must have the shape of logits {tuple(logits.shape)}, got {tuple(mask.shape)}")
    return F.binary_cross_entropy_with_logits(logits, mask.detach().to(logits.dtype))
