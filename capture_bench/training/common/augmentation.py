"""Random-shift augmentation of the pixel observation for training batches only (DrQ: Kostrikov,
Yarats & Fergus 2021; DrQ-v2: Yarats et al. 2022).

With ``augment_shift: p`` (train.py, pixels only), every image of the pixel observation (``image``
and, where asked for, ``ee_image``, each a stack of frames) is padded by p pixels on each side,
repeating its edge pixels, and cropped back to its size at a random offset in [0, 2p] on each
axis, drawn per sample and per image (the frames of one stack move together). It is applied where
the policy reads its features while in training mode: a forward pre-hook on its features
extractors (`install_random_shift`), active only while the module is in training mode, which SB3
sets for the updates (PPO's and A2C's minibatches; the DAgger fit too) and clears to collect
rollouts, validate and evaluate. The env's observations and the rollout buffer hold the images as
rendered; the stored policy is the plain extractor (the hook is not a parameter; evaluate.py plays
it unaugmented). PPO's ratio then compares the probability of an action under a shifted image
with that under the image the action was taken on, as RAD's PPO does.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F


def random_shift(
    images: torch.Tensor, pad: int, generator: torch.Generator | None = None
) -> torch.Tensor:
    """``images`` (B, C, H, W), each padded by ``pad`` pixels repeating its edges and cropped
    back to H x W at an offset drawn uniformly from {0, ..., 2 pad} on each axis (per sample);
    a new tensor of the same dtype."""
    if pad <= 0:
        return images
    b, c, h, w = images.shape
    padded = F.pad(images.float(), (pad, pad, pad, pad), mode="replicate").to(images.dtype)
    offsets = torch.randint(0, 2 * pad + 1, (b, 2), generator=generator, device=images.device)
    rows = offsets[:, 0, None] + torch.arange(h, device=images.device)  # (B, H)
    cols = offsets[:, 1, None] + torch.arange(w, device=images.device)  # (B, W)
    batch = torch.arange(b, device=images.device)[:, None, None, None]
    channel = torch.arange(c, device=images.device)[None, :, None, None]
    return padded[batch, channel, rows[:, None, :, None], cols[:, None, None, :]]


def image_keys(observation_space: Any) -> list[str]:
    """The keys of a ``Dict`` observation space whose Box is an image (3 axes)."""
    return [key for key, box in observation_space.spaces.items() if len(box.shape) == 3]


def install_random_shift(policy: Any, pad: int) -> list[Any]:
    """Shift the images every features extractor of ``policy`` reads by up to ``pad`` pixels
    (`random_shift`) while it is in training mode (module docstring); the hooks' handles
    (``remove()`` undoes them)."""
    keys = image_keys(policy.observation_space)

    def hook(module: torch.nn.Module, args: tuple[Any, ...]) -> tuple[Any, ...] | None:
        if not module.training:
            return None
        observations = dict(args[0])  # a new dict: the batch given is left as it is
        for key in keys:
            observations[key] = random_shift(observations[key], pad)
        return (observations, *args[1:])

    extractors = {
        id(m): m
        for name in ("features_extractor", "pi_features_extractor", "vf_features_extractor")
        if (m := getattr(policy, name, None)) is not None
    }
    return [m.register_forward_pre_hook(hook) for m in extractors.values()]
