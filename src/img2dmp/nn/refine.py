"""Refinement at prediction time: a few gradient steps that pull a predicted DMP onto the ink.

The rollout is exact and differentiable, so a prediction can be improved on the one image
it is for: minimise, over the normalised DMP vector ``z`` (eq. 8, normalised),

    J(z) = a A(y(z)) + c C(y(z)) + lambda |z - z_0|^2 / P

with ``A`` :func:`~img2dmp.nn.ink.ink_attraction` (the path on the ink), ``C``
:func:`~img2dmp.nn.ink.ink_coverage` (the ink reached), ``y(z)`` the DMP's path at the
given time stamps and ``z_0`` the network's output. The prior term keeps the movement
(its timing, its start and direction) close to what the network proposed; the image terms
move its shape onto the strokes. Adam, a fixed number of steps, no network involved.
"""

from __future__ import annotations

import torch

from ..dmp import DMPConfig
from ._refine_options import MAX_REFINE_STEPS, RefineOptions  # torch-free, re-exported here
from .costs import dmp_trajectory
from .ink import ink_attraction, ink_coverage, ink_distance_map
from .normalise import ParamNormaliser


def refine(
    z0: torch.Tensor,
    images: torch.Tensor,
    times: torch.Tensor,
    normaliser: ParamNormaliser,
    config: DMPConfig,
    options: RefineOptions | None = None,
) -> torch.Tensor:
    """Normalised DMP vectors ``[B, P]`` refined on their images ``[B, H, W]``.

    Parameters
    ----------
    z0 : tensor [B, P]
        The network's output (one hypothesis per image).
    images : tensor [B, H, W]
        The prepared images (ink = 1) the network saw.
    times : tensor [B, T]
        Time stamps at which the path is compared with the ink (e.g. 100 over [0, tau]).

    Returns
    -------
    tensor [B, P]
        ``z0`` after ``options.steps`` Adam steps on J (module docstring); detached.
    """
    o = options or RefineOptions()
    z0 = z0.detach().to(torch.float64)
    if o.steps == 0 or z0.shape[0] == 0:
        return z0.clone()
    imgs = images.detach().to(torch.float64)
    t = times.detach().to(torch.float64)
    dist = ink_distance_map(imgs)
    z = z0.clone().requires_grad_()
    adam = _Adam(z, o.lr)
    with torch.enable_grad():
        for _ in range(int(o.steps)):
            y = dmp_trajectory(z, t, normaliser, config)  # [B, T, d]
            j = o.prior_weight * ((z - z0) ** 2).mean(-1) + ink_terms(y, dist, imgs, o)  # [B]
            z.grad = None
            j.sum().backward()  # samples are independent: the sum's gradient is each one's
            adam.step()
    return z.detach()


class _Adam:
    """Adam (Kingma and Ba 2015) on one tensor, the same arithmetic as
    ``torch.optim.Adam(lr=lr)`` with its defaults on the CPU (betas 0.9 and 0.999, eps
    1e-8; ``tests/test_ink_and_hypotheses.py`` compares them bit for bit). Written out
    because creating a ``torch.optim`` optimiser imports ``torch._dynamo``, about 1.6 s
    of a one-image ``img2dmp predict``."""

    def __init__(self, param: torch.Tensor, lr: float, betas=(0.9, 0.999), eps: float = 1e-8):
        self.param, self.lr, self.betas, self.eps = param, float(lr), betas, eps
        self.m = torch.zeros_like(param)  # first moment
        self.v = torch.zeros_like(param)  # second moment
        self.n = 0

    @torch.no_grad()
    def step(self) -> None:
        (b1, b2), g = self.betas, self.param.grad
        self.n += 1
        self.m.lerp_(g, 1 - b1)
        self.v.mul_(b2).addcmul_(g, g, value=1 - b2)
        bias1, bias2 = 1 - b1**self.n, 1 - b2**self.n
        denom = (self.v.sqrt() / bias2**0.5).add_(self.eps)
        self.param.addcdiv_(self.m, denom, value=-self.lr / bias1)


__all__ = ["MAX_REFINE_STEPS", "RefineOptions", "refine"]


def ink_terms(y: torch.Tensor, dist: torch.Tensor, images: torch.Tensor, o) -> torch.Tensor:
    """Refinement's image terms per sample ``[B]`` of paths ``y [B, T, d]``: ``o``'s
    (:class:`RefineOptions`) weighted ink attraction (on the distance map ``dist``) and
    coverage of ``images``; 0 where both weights are 0."""
    j = torch.zeros(len(y), dtype=y.dtype, device=y.device)
    if o.ink_weight:
        j = j + o.ink_weight * ink_attraction(y, dist)
    if o.coverage_weight:
        j = j + o.coverage_weight * ink_coverage(y, images, tolerance_px=o.coverage_tolerance_px)
    return j
