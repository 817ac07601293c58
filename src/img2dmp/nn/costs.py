"""The two cost functions of Pahič et al. (ICRA 2018) and their weighted sum.

- Cost (9), :func:`parameter_cost`: squared error between the network's (normalised) DMP
  vector and the normalised vector of the DMP fitted to the demonstration.
- Cost (10), :func:`trajectory_cost`: squared distance between the demonstrated path and
  the path of the network's DMP, at the demonstration's own time stamps. The DMP is
  rolled out with the fast differentiable :func:`img2dmp.dmp.rollout`, so the gradient
  reaches every parameter, tau included (the paper's eqs. 11-27 by autograd).

Both return the mean over the batch; :class:`Cost` selects one by name or a weighted sum.
"""

from __future__ import annotations

import torch

from ..dmp import DMPConfig, rollout
from .normalise import ParamNormaliser

COST_NAMES = ("parameter", "trajectory", "combined")
# Accepted spellings: the paper's equation numbers as well as the names.
_ALIASES = {"9": "parameter", "10": "trajectory", "params": "parameter", "traj": "trajectory"}


def parameter_cost(z_pred: torch.Tensor, z_target: torch.Tensor) -> torch.Tensor:
    """Cost (9): mean over the batch of the squared error of the normalised DMP vector.

    ``C = 1/B sum_b 1/P || z_pred_b - z_target_b ||^2`` (divided by P so the number does
    not grow with the kernel count).

    Parameters
    ----------
    z_pred, z_target : tensor [B, P]
        Normalised parameter vectors (see :class:`ParamNormaliser`).
    """
    return ((z_pred - z_target) ** 2).mean()


def dmp_trajectory(
    z_pred: torch.Tensor,
    times: torch.Tensor,
    normaliser: ParamNormaliser,
    config: DMPConfig,
) -> torch.Tensor:
    """The network's DMP rolled out at given time stamps (differentiable).

    Parameters
    ----------
    z_pred : tensor [B, P]
        Normalised network output.
    times : tensor [B, T]
        Time stamps; shifted so that each sample's first stamp is t = 0.

    Returns
    -------
    tensor [B, T, d]
    """
    params = normaliser.denormalise(z_pred)
    t = times - times[:, :1]  # [B, T]
    return rollout(params, t, config, validate=False)


def trajectory_cost(
    z_pred: torch.Tensor,
    times: torch.Tensor,
    trajectories: torch.Tensor,
    normaliser: ParamNormaliser,
    config: DMPConfig,
) -> torch.Tensor:
    """Cost (10): mean squared distance (px^2) between demonstration and DMP trajectory.

    ``C = 1/B sum_b 1/T sum_t || y_demo_b(t) - y_dmp(t; theta_b) ||^2`` where ``theta_b``
    is the un-normalised network output and ``y_dmp`` the exact DMP solution (eqs. 3-7)
    at the demonstration's time stamps ``t``.

    Parameters
    ----------
    z_pred : tensor [B, P]
        Normalised network output.
    times : tensor [B, T]
        Demonstration time stamps (s).
    trajectories : tensor [B, T, d]
        Demonstrated positions (px).
    """
    y = dmp_trajectory(z_pred, times, normaliser, config)  # [B, T, d]
    return _mean_squared_distance(y, trajectories)


def _mean_squared_distance(y: torch.Tensor, y_demo: torch.Tensor) -> torch.Tensor:
    return ((y - y_demo) ** 2).sum(-1).mean()  # [B, T, d] -> scalar


def trajectory_error_px(y_dmp: torch.Tensor, y_demo: torch.Tensor) -> torch.Tensor:
    """Per-sample mean Euclidean distance (px) on x, y only (the metric of Table I).

    Parameters
    ----------
    y_dmp, y_demo : tensor [B, T, d]

    Returns
    -------
    tensor [B]
    """
    return torch.linalg.vector_norm(y_dmp[..., :2] - y_demo[..., :2], dim=-1).mean(-1)


def canonical_cost_name(name: str) -> str:
    key = _ALIASES.get(str(name), str(name))
    if key not in COST_NAMES:
        raise ValueError(f"cost.name must be one of {COST_NAMES} (or '9', '10'), got {name!r}")
    return key


class Cost:
    """A training cost selected by name.

    Parameters
    ----------
    name : {"parameter", "trajectory", "combined"} (or "9", "10")
        ``"parameter"`` is cost (9), ``"trajectory"`` cost (10), ``"combined"`` is
        ``parameter_weight * C9 + trajectory_weight * C10``.
    normaliser, config
        To un-normalise and roll out the network's output.
    parameter_weight, trajectory_weight : float
        Weights of the combined cost (C10 is in px^2, C9 in normalised units).
    """

    def __init__(
        self,
        name: str,
        normaliser: ParamNormaliser,
        config: DMPConfig,
        parameter_weight: float = 1.0,
        trajectory_weight: float = 1.0,
    ):
        self.name = canonical_cost_name(name)
        for k, v in (
            ("parameter_weight", parameter_weight),
            ("trajectory_weight", trajectory_weight),
        ):
            if not (float(v) >= 0):
                raise ValueError(f"cost.{k} must be >= 0, got {v!r}")
        self.normaliser, self.config = normaliser, config
        self.parameter_weight, self.trajectory_weight = (
            float(parameter_weight),
            float(trajectory_weight),
        )

    def __call__(
        self,
        z_pred: torch.Tensor,  # [B, P]
        z_target: torch.Tensor,  # [B, P]
        times: torch.Tensor,  # [B, T]
        trajectories: torch.Tensor,  # [B, T, d]
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Return ``(cost, y_dmp)``: ``y_dmp [B, T, d]`` (detached) when the cost rolled the
        DMP out anyway, else ``None``."""
        if self.name == "parameter":
            return parameter_cost(z_pred, z_target), None
        y = dmp_trajectory(z_pred, times, self.normaliser, self.config)  # [B, T, d]
        c10 = _mean_squared_distance(y, trajectories)
        if self.name == "combined":
            c9 = parameter_cost(z_pred, z_target)
            c10 = self.parameter_weight * c9 + self.trajectory_weight * c10
        return c10, y.detach()
