"""The one batched inference path: images -> network -> DMP trajectories.

Prediction (:class:`img2dmp.predict.Predictor`), evaluation (Table I) and training's
validation all run the network over many images in batches and roll the resulting DMPs
out at given time stamps; they do it through these two functions, so that the numbers
they report come from the same computation.

- :func:`network_outputs` - the normalised DMP vectors ``z [B, P]`` of images ``[B, H, W]``
- :func:`dmp_trajectories` - those DMPs rolled out, ``y [B, T, d]``
  (:func:`img2dmp.nn.costs.dmp_trajectory`, the exact solution of eqs. 3-7)

Both run the model in eval mode without gradients and give it back in the mode it came
in (training calls them between optimisation steps).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from numbers import Integral

import torch

from ..dmp import DMPConfig
from .costs import dmp_trajectory
from .model import split_hypotheses, top_hypothesis
from .normalise import ParamNormaliser


@contextlib.contextmanager
def _evaluating(model: torch.nn.Module) -> Iterator[None]:
    # Dropout and batch norm must not act on inference; the caller's mode is restored
    # even if the model raises.
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            yield
    finally:
        model.train(was_training)


def _check_batch_size(batch_size: int) -> int:
    if isinstance(batch_size, bool) or not isinstance(batch_size, Integral) or batch_size < 1:
        raise ValueError(f"batch_size must be an integer >= 1, got {batch_size!r}")
    return int(batch_size)


def _check_images(images: torch.Tensor) -> None:
    if not isinstance(images, torch.Tensor) or images.ndim != 3:
        shape = tuple(images.shape) if hasattr(images, "shape") else type(images).__name__
        raise ValueError(f"images must be a tensor of shape [B, H, W], got {shape}")


def network_outputs(
    model: torch.nn.Module, images: torch.Tensor, batch_size: int = 4096
) -> torch.Tensor:
    """The network's normalised DMP vectors for a stack of images, in batches.

    ``z_b = model(x_b)`` in eval mode, without gradients; the model's training flag is
    restored afterwards.

    Parameters
    ----------
    model : torch.nn.Module
        Maps ``[b, H, W] -> [b, P]`` (e.g. :class:`img2dmp.nn.EncoderDecoder`).
    images : tensor [B, H, W]
        Prepared images (ink = 1), on the model's device and in its dtype.
    batch_size : int
        Images per forward pass (memory, not results: each sample's output does not
        depend on its batch in eval mode).

    Returns
    -------
    tensor [B, P]
        Normalised units (eq. 8); ``[0, P]`` for no images.
    """
    batch_size = _check_batch_size(batch_size)
    _check_images(images)
    with _evaluating(model):
        if images.shape[0] == 0:
            return model(images)  # [0, P]: the model knows P
        outs = [model(images[lo : lo + batch_size]) for lo in range(0, images.shape[0], batch_size)]
        return torch.cat(outs)  # [B, P]


def dmp_trajectories(
    model: torch.nn.Module,
    normaliser: ParamNormaliser,
    dmp_config: DMPConfig,
    images: torch.Tensor,
    times: torch.Tensor,
    batch_size: int = 4096,
) -> torch.Tensor:
    """The network's DMPs for a stack of images, rolled out at given time stamps.

    ``y_b(t) = y_dmp(t - t_b0; theta_b)`` with ``theta_b = denormalise(model(x_b))``
    (eq. 8 inverted) and ``y_dmp`` the exact DMP solution (eqs. 3-7): the trajectory that
    cost (10) and Table I's error (:func:`img2dmp.nn.costs.trajectory_error_px`) compare
    with the demonstration. Built on :func:`network_outputs`; the rollouts are batched
    the same way, without gradients.

    Parameters
    ----------
    model : torch.nn.Module
        Maps ``[b, H, W] -> [b, P]`` normalised DMP vectors.
    normaliser : ParamNormaliser
        The model's output normalisation.
    dmp_config : DMPConfig
        The DMP constants (kernels, dimensions, gains).
    images : tensor [B, H, W]
        Prepared images.
    times : tensor [B, T]
        Time stamps (s) per sample; each row is shifted to start at 0.
    batch_size : int
        Samples per forward pass and rollout.

    Returns
    -------
    tensor [B, T, d]
        Positions (px); float32 for a float32 network and float32 time stamps.
    """
    k = getattr(model, "n_hypotheses", 1)
    times = _check_times(images, times)
    z = top_hypothesis(network_outputs(model, images, batch_size), k)  # [B, P]
    return rollout_outputs(z[:, None], times, normaliser, dmp_config, batch_size)[:, 0]


def hypothesis_trajectories(
    model: torch.nn.Module,
    normaliser: ParamNormaliser,
    dmp_config: DMPConfig,
    images: torch.Tensor,
    times: torch.Tensor,
    batch_size: int = 4096,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Every hypothesis of a multi-hypothesis network, rolled out, with its probability.

    Returns
    -------
    y : tensor [B, K, T, d]
        Hypothesis k of sample b at the sample's time stamps (shifted to start at 0).
    probs : tensor [B, K]
        Softmax of the scores; 1 for a one-hypothesis network.
    """
    times = _check_times(images, times)
    out = network_outputs(model, images, batch_size)  # [B, K (P + 1)] or [B, P]
    z, logits = split_hypotheses(out, getattr(model, "n_hypotheses", 1))  # [B, K, P], [B, K]
    y = rollout_outputs(z, times, normaliser, dmp_config, batch_size)
    return y, torch.softmax(logits, dim=1)


def rollout_outputs(
    z: torch.Tensor,
    times: torch.Tensor,
    normaliser: ParamNormaliser,
    dmp_config: DMPConfig,
    batch_size: int = 4096,
) -> torch.Tensor:
    """Normalised DMP vectors ``z [B, K, P]`` (K per sample) rolled out at the samples'
    time stamps ``[B, T]``, in batches, without gradients: ``[B, K, T, d]``."""
    batch_size = _check_batch_size(batch_size)
    b, k, p = z.shape
    if b == 0:
        return z.new_zeros(0, k, times.shape[-1], dmp_config.n_dims)
    flat_z = z.reshape(b * k, p)
    flat_t = times.repeat_interleave(k, dim=0) if k > 1 else times  # [B K, T]
    with torch.no_grad():
        parts = [
            dmp_trajectory(flat_z[lo : lo + batch_size], flat_t[lo : lo + batch_size],
                           normaliser, dmp_config)
            for lo in range(0, b * k, batch_size)
        ]  # fmt: skip
    y = torch.cat(parts)  # [B K, T, d]
    return y.reshape(b, k, *y.shape[1:])


def _check_times(images: torch.Tensor, times) -> torch.Tensor:
    _check_images(images)
    times = torch.as_tensor(times)
    if times.ndim != 2 or times.shape[0] != images.shape[0]:
        raise ValueError(
            f"times must have shape [B, T] with B = {images.shape[0]} (the images), got "
            f"{tuple(times.shape)}"
        )
    return times


__all__ = ["dmp_trajectories", "hypothesis_trajectories", "network_outputs", "rollout_outputs"]
