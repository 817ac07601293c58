"""The two cost functions of Pahič et al. (ICRA 2018) and their weighted sum.

- Cost (9), :func:`parameter_cost`: squared error between the network's (normalised) DMP
  vector and the normalised vector of the DMP fitted to the demonstration.
- Cost (10), :func:`trajectory_cost`: squared distance between the demonstrated path and
  the path of the network's DMP, at the demonstration's own time stamps. The DMP is
  rolled out with the fast differentiable :func:`img2dmp.dmp.rollout`, so the gradient
  reaches every parameter, tau included (the paper's eqs. 11-27 by autograd).

Both return the mean over the batch; :class:`Cost` selects one by name or a weighted sum.

Cost (9) may weight its units (:class:`ParameterWeighting`, ``cost.parameter_weighting``):
``"none"`` gives every normalised unit the same weight (the paper); ``"trajectory"``
weights unit ``u`` by how much it moves the trajectory, the diagonal of the Gauss-Newton
matrix of cost (10) at the fitted parameters, averaged over the training set
(:func:`trajectory_sensitivity`); ``"trajectory-full"`` uses that whole matrix as the
metric of the parameter error. The cost stays a pure parameter-space cost: the weights
are computed once, before training, and saved with the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..config import check_positive
from ..dmp import DMPConfig, rollout
from .normalise import ParamNormaliser

COST_NAMES = ("parameter", "trajectory", "combined")
PARAMETER_WEIGHTINGS = ("none", "trajectory", "trajectory-full")
# Accepted spellings: the paper's equation numbers as well as the names.
_ALIASES = {"9": "parameter", "10": "trajectory", "params": "parameter", "traj": "trajectory"}


def parameter_cost(
    z_pred: torch.Tensor, z_target: torch.Tensor, weights: torch.Tensor | None = None
) -> torch.Tensor:
    """Cost (9): mean over the batch of the squared error of the normalised DMP vector.

    ``C = 1/B sum_b 1/P e_b^T Lambda e_b`` with ``e_b = z_pred_b - z_target_b`` (divided
    by P so the number does not grow with the kernel count). ``Lambda`` is the identity
    without weights, ``diag(lambda)`` for a weight vector, or a symmetric positive definite
    matrix.

    Parameters
    ----------
    z_pred, z_target : tensor [B, P]
        Normalised parameter vectors (see :class:`ParamNormaliser`).
    weights : tensor [P] or [P, P], optional
        Per-unit weights ``lambda_u`` or the matrix ``Lambda``
        (:meth:`ParameterWeighting.tensor`); None = unweighted.
    """
    e = z_pred - z_target  # [B, P]
    if weights is None:
        return (e**2).mean()
    weights = weights.to(e.dtype)
    if weights.ndim == 1:
        return (e**2 * weights).mean()
    return ((e @ weights) * e).mean()


@torch.no_grad()
def trajectory_gauss_newton(
    params: np.ndarray | torch.Tensor,
    times: np.ndarray | torch.Tensor,
    normaliser: ParamNormaliser,
    config: DMPConfig,
    step: float = 1e-4,
    batch_size: int = 128,
) -> np.ndarray:
    """Mean Gauss-Newton matrix of cost (10) in normalised units (px^2 per unit^2).

    ``H = 1/M sum_b 1/T sum_t J_b(t)^T J_b(t)`` with ``J_b(t) = d y_b(t) / d z`` ([d, P]) at
    the fitted parameters ``z_b`` of the M samples, at their own time stamps (shifted to
    start at 0, as in cost 10). To second order, an error ``e`` of the normalised vector
    adds ``e^T H_b e`` px^2 to a sample's cost (10); ``H`` is that metric averaged over
    the samples, and its diagonal ``s_u = H_uu`` (:func:`trajectory_sensitivity`) is the
    mean squared trajectory sensitivity of unit u.

    The derivatives are central differences in float64 with step ``step`` (normalised
    units). y is affine in w, g and y0, so for those units they are exact up to rounding;
    for tau (through log tau) the error is O(step^2).

    Parameters
    ----------
    params : [M, P]
        Fitted DMP vectors (``DMPParams.to_vector``, tau > 0).
    times : [M, T]
        The demonstrations' time stamps (s).

    Returns
    -------
    ndarray [P, P], symmetric positive semi-definite
    """
    v = torch.as_tensor(np.asarray(params), dtype=torch.float64)
    t_all = torch.as_tensor(np.asarray(times), dtype=torch.float64)
    if v.ndim != 2 or v.shape[1] != normaliser.n_params or t_all.shape[0] != v.shape[0]:
        raise ValueError(
            f"need params [M, {normaliser.n_params}] and times [M, T] with the same M, got "
            f"{tuple(v.shape)} and {tuple(t_all.shape)}"
        )
    if v.shape[0] < 1 or not step > 0:
        raise ValueError(f"need at least one sample and step > 0, got {v.shape[0]}, {step}")
    p = normaliser.n_params
    total = torch.zeros(p, p, dtype=torch.float64)
    eye = torch.eye(p, dtype=torch.float64) * step  # [P, P]
    for lo in range(0, v.shape[0], batch_size):
        z = normaliser.normalise(v[lo : lo + batch_size])  # [b, P]
        t = t_all[lo : lo + batch_size]  # [b, T]
        jac = torch.stack(
            [
                dmp_trajectory(z + eye[u], t, normaliser, config)
                - dmp_trajectory(z - eye[u], t, normaliser, config)
                for u in range(p)
            ],
            dim=-1,
        ) / (2 * step)  # [b, T, d, P]
        total += torch.einsum("btdu,btdv->uv", jac, jac) / jac.shape[1]
    h = total / v.shape[0]
    return (0.5 * (h + h.T)).numpy()


def trajectory_sensitivity(
    params: np.ndarray | torch.Tensor,
    times: np.ndarray | torch.Tensor,
    normaliser: ParamNormaliser,
    config: DMPConfig,
    step: float = 1e-4,
) -> np.ndarray:
    """Mean squared trajectory sensitivity of every normalised unit (px^2 per unit^2).

    ``s_u = 1/M sum_b 1/T sum_t || d y_b(t) / d z_u ||^2``: the diagonal of
    :func:`trajectory_gauss_newton` (the Gauss-Newton matrix of cost 10, half its Hessian
    at a perfect fit). A small error ``dz_u`` in unit u alone adds ``s_u dz_u^2`` px^2 to
    cost (10), to second order. Returns ndarray [P].
    """
    return np.diag(trajectory_gauss_newton(params, times, normaliser, config, step)).copy()


@dataclass
class ParameterWeighting:
    """Weights of cost (9), saved with the model (checkpoint field ``parameter_weighting``;
    a checkpoint without it was trained unweighted).

    Attributes
    ----------
    kind : str
        ``"trajectory"``: per-unit weights ``lambda = max(s / mean(s), floor)`` with ``s``
        the diagonal of the mean Gauss-Newton matrix ``H`` of cost (10)
        (:func:`trajectory_gauss_newton`), so the weights average about 1 and cost (9)
        stays on the scale of the unweighted one. ``"trajectory-full"``: the whole matrix,
        ``Lambda = H / mean(s) + floor * I`` (couplings between units included; the floor
        keeps it positive definite).
    weights : ndarray [P] or [P, P]
        ``lambda`` or ``Lambda`` of :func:`parameter_cost`.
    sensitivity : ndarray [P]
        ``s_u = H_uu`` (px^2 per normalised unit^2), for the record.
    floor : float
        Smallest weight relative to the mean, so that no unit is left unconstrained.
    """

    kind: str
    weights: np.ndarray
    sensitivity: np.ndarray
    floor: float

    def __post_init__(self) -> None:
        self.weights = np.asarray(self.weights, dtype=np.float64)
        self.sensitivity = np.asarray(self.sensitivity, dtype=np.float64)
        if self.kind not in PARAMETER_WEIGHTINGS or self.kind == "none":
            raise ValueError(f"unknown parameter weighting kind {self.kind!r}")
        p = self.sensitivity.shape[0] if self.sensitivity.ndim == 1 else -1
        shape = (p,) if self.kind == "trajectory" else (p, p)
        if self.weights.shape != shape:
            raise ValueError(
                f"{self.kind!r} parameter weights have shape {self.weights.shape}, expected "
                f"{shape} for a sensitivity of shape {self.sensitivity.shape}"
            )
        if not np.isfinite(self.weights).all():
            raise ValueError("parameter weights must be finite")
        if self.weights.ndim == 1 and not (self.weights > 0).all():
            raise ValueError("parameter weights must be > 0")
        if self.weights.ndim == 2 and not (
            np.allclose(self.weights, self.weights.T) and np.linalg.eigvalsh(self.weights)[0] > 0
        ):
            raise ValueError(
                "the parameter weight matrix must be symmetric positive definite (> 0)"
            )

    @property
    def n_params(self) -> int:
        return int(self.sensitivity.shape[0])

    def tensor(self, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """The weights for :func:`parameter_cost`: [P] or [P, P]."""
        return torch.as_tensor(self.weights, dtype=dtype)

    @classmethod
    def from_gauss_newton(
        cls, h: np.ndarray, kind: str = "trajectory", floor: float = 1e-3
    ) -> ParameterWeighting:
        """Weights of the given kind from a mean Gauss-Newton matrix ``h`` [P, P]."""
        h = np.asarray(h, dtype=np.float64)
        s = np.diag(h).copy() if h.ndim == 2 else np.array([])
        if h.ndim != 2 or h.shape[0] != h.shape[1] or not np.isfinite(h).all():
            raise ValueError(f"need a finite square Gauss-Newton matrix, got shape {h.shape}")
        if not ((s >= 0).all() and s.sum() > 0):
            raise ValueError("trajectory sensitivities must be >= 0 and not all 0")
        if not 0 < float(floor) <= 1:
            raise ValueError(f"cost.parameter_weight_floor must be in (0, 1], got {floor!r}")
        if kind == "trajectory":
            w = np.maximum(s / s.mean(), float(floor))
        elif kind == "trajectory-full":
            w = h / s.mean() + float(floor) * np.eye(len(s))
            w = 0.5 * (w + w.T)
        else:
            raise ValueError(f"unknown parameter weighting kind {kind!r}")
        return cls(kind, w, s, float(floor))

    @classmethod
    def from_sensitivity(cls, sensitivity: np.ndarray, floor: float = 1e-3) -> ParameterWeighting:
        """Per-unit (``"trajectory"``) weights from the diagonal ``s`` alone."""
        return cls.from_gauss_newton(np.diag(np.asarray(sensitivity, np.float64)), floor=floor)

    @classmethod
    def fit(
        cls,
        params: np.ndarray,
        times: np.ndarray,
        normaliser: ParamNormaliser,
        config: DMPConfig,
        floor: float = 1e-3,
        kind: str = "trajectory",
    ) -> ParameterWeighting:
        """Weights from a training set's fitted DMPs and time stamps (see the class)."""
        h = trajectory_gauss_newton(params, times, normaliser, config)
        return cls.from_gauss_newton(h, kind, floor)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "weights": self.weights.tolist(),
            "sensitivity": self.sensitivity.tolist(),
            "floor": self.floor,
        }

    @classmethod
    def from_dict(cls, d: dict | None) -> ParameterWeighting | None:
        """The record of :meth:`to_dict`; ``None`` (an unweighted run) gives ``None``."""
        if d is None:
            return None
        missing = [k for k in ("kind", "weights", "sensitivity", "floor") if k not in d]
        if missing:
            raise ValueError(f"parameter weighting record is missing field(s) {missing}")
        return cls(d["kind"], d["weights"], d["sensitivity"], float(d["floor"]))


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


def resample_by_arc_length(y: torch.Tensor, n_points: int = 64) -> torch.Tensor:
    """Paths ``[B, T, >=2]`` at ``n_points`` evenly spaced arc lengths, ``[B, n, 2]``
    (x, y; linear between the samples), differentiable in the positions.

    The torch twin of :func:`img2dmp.metrics.resample_by_arc_length` for d = 2: which
    segment holds each arc length is found without gradient, the point on it is a
    differentiable interpolation, so the gradient moves the shape, not the timing.
    """
    xy = y[..., :2]
    seg = torch.sqrt(((xy[:, 1:] - xy[:, :-1]) ** 2).sum(-1) + 1e-12)  # [B, T-1]
    s = torch.cat([seg.new_zeros(seg.shape[0], 1), torch.cumsum(seg, dim=1)], dim=1)  # [B, T]
    u = s / s[:, -1:]  # [B, T], 0 .. 1
    grid = torch.linspace(0.0, 1.0, n_points, dtype=u.dtype, device=u.device)
    grid = grid.expand(u.shape[0], n_points).contiguous()
    idx = torch.searchsorted(u.detach().contiguous(), grid, right=True)
    idx = idx.clamp(1, u.shape[1] - 1)  # [B, n]: the segment [idx - 1, idx]
    u0, u1 = torch.gather(u, 1, idx - 1), torch.gather(u, 1, idx)
    w = ((grid - u0) / (u1 - u0).clamp_min(1e-12)).clamp(0.0, 1.0)[..., None]  # [B, n, 1]
    p0 = torch.gather(xy, 1, (idx - 1)[..., None].expand(-1, -1, 2))
    p1 = torch.gather(xy, 1, idx[..., None].expand(-1, -1, 2))
    return p0 + w * (p1 - p0)


def path_cost(y: torch.Tensor, y_demo: torch.Tensor, n_points: int = 64) -> torch.Tensor:
    """Timing-free squared path distance (px^2) per sample, ``[B]``: both paths resampled
    by arc length (:func:`resample_by_arc_length`) and compared point by point, the
    square of :func:`img2dmp.metrics.path_error_px`'s distances. It rewards the right
    shape written in the right order whatever the speed, which an image does not show."""
    a = resample_by_arc_length(y, n_points)
    with torch.no_grad():
        b = resample_by_arc_length(y_demo.to(a.dtype), n_points)
    return ((a - b) ** 2).sum(-1).mean(-1)


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
    """A training cost selected by name, for one or several hypotheses, with ink terms.

    Parameters
    ----------
    name : {"parameter", "trajectory", "combined"} (or "9", "10")
        ``"parameter"`` is cost (9), ``"trajectory"`` cost (10), ``"combined"`` is
        ``parameter_weight * C9 + trajectory_weight * C10``.
    normaliser, config
        To un-normalise and roll out the network's output.
    parameter_weight, trajectory_weight : float
        Weights of the combined cost (C10 is in px^2, C9 in normalised units).
    weighting : ParameterWeighting, optional
        Per-unit weights of cost (9) (also in the combined cost); None = unweighted.
    hypotheses : int
        K DMPs per image (:func:`img2dmp.nn.model.split_hypotheses`). With K > 1 the cost
        is winner-takes-all: each sample's cost is that of its best hypothesis, relaxed
        so that no head dies (weight ``1 - wta_relax`` on the winner, ``wta_relax / (K -
        1)`` on each other), plus ``score_weight`` times the cross-entropy that teaches
        the scores which hypothesis wins. K = 1 is the single-head cost, exactly.
    ink_weight, coverage_weight : float
        Weights of the image-consistency terms (:mod:`img2dmp.nn.ink`, px^2):
        :func:`~img2dmp.nn.ink.ink_attraction` on every hypothesis and
        :func:`~img2dmp.nn.ink.ink_coverage` on each sample's winning one (the one that
        is to write the whole digit). 0 (default) = off. They need the images.
    path_weight : float
        Weight of :func:`path_cost` (px^2), the timing-free distance between the paths,
        added to each hypothesis' cost. 0 (default) = off.
    """

    def __init__(
        self,
        name: str,
        normaliser: ParamNormaliser,
        config: DMPConfig,
        parameter_weight: float = 1.0,
        trajectory_weight: float = 1.0,
        weighting: ParameterWeighting | None = None,
        *,
        hypotheses: int = 1,
        wta_relax: float = 0.05,
        score_weight: float = 0.1,
        ink_weight: float = 0.0,
        coverage_weight: float = 0.0,
        coverage_tolerance_px: float = 1.0,
        path_weight: float = 0.0,
    ):
        self.name = canonical_cost_name(name)
        for k, v in (
            ("parameter_weight", parameter_weight),
            ("trajectory_weight", trajectory_weight),
            ("ink_weight", ink_weight),
            ("coverage_weight", coverage_weight),
            ("score_weight", score_weight),
            ("path_weight", path_weight),
        ):
            check_positive(f"cost.{k}", v, allow_zero=True)
        if not 0 <= float(wta_relax) < 1:
            raise ValueError(f"cost.wta_relax must be in [0, 1), got {wta_relax!r}")
        self.normaliser, self.config = normaliser, config
        self.parameter_weight, self.trajectory_weight = (
            float(parameter_weight),
            float(trajectory_weight),
        )
        self.hypotheses = int(hypotheses)
        self.wta_relax, self.score_weight = float(wta_relax), float(score_weight)
        self.ink_weight, self.coverage_weight = float(ink_weight), float(coverage_weight)
        self.coverage_tolerance_px = float(coverage_tolerance_px)
        self.path_weight = float(path_weight)
        self.weighting = weighting
        self._weights = None
        if weighting is not None:
            if weighting.n_params != normaliser.n_params:
                raise ValueError(
                    f"parameter weights have shape {weighting.weights.shape}, the DMP vector "
                    f"has {normaliser.n_params} units"
                )
            self._weights = weighting.tensor()

    @property
    def uses_images(self) -> bool:
        return self.ink_weight > 0 or self.coverage_weight > 0

    def __call__(
        self,
        z_pred: torch.Tensor,  # [B, P] or [B, K (P + 1)]
        z_target: torch.Tensor,  # [B, P]
        times: torch.Tensor,  # [B, T]
        trajectories: torch.Tensor,  # [B, T, d]
        images: torch.Tensor | None = None,  # [B, H, W], for the ink terms
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Return ``(cost, y_dmp)``: ``y_dmp [B, T, d]`` (detached, the top hypothesis)
        when the cost rolled the DMPs out anyway, else ``None``."""
        if self.hypotheses == 1 and not self.uses_images and not self.path_weight:
            return self._single(z_pred, z_target, times, trajectories)
        return self._general(z_pred, z_target, times, trajectories, images)

    def _single(self, z_pred, z_target, times, trajectories):
        # The paper's costs, one hypothesis: eqs. (9) and (10) as written.
        if self.name == "parameter":
            return parameter_cost(z_pred, z_target, self._weights), None
        y = dmp_trajectory(z_pred, times, self.normaliser, self.config)  # [B, T, d]
        c10 = _mean_squared_distance(y, trajectories)
        if self.name == "combined":
            c9 = parameter_cost(z_pred, z_target, self._weights)
            c10 = self.parameter_weight * c9 + self.trajectory_weight * c10
        return c10, y.detach()

    def _general(self, z_pred, z_target, times, trajectories, images):
        from .model import split_hypotheses

        z, logits = split_hypotheses(z_pred, self.hypotheses)  # [B, K, P], [B, K]
        b = z.shape[0]
        y = None
        if self.name != "parameter" or self.uses_images or self.path_weight:
            y = self._rollouts(z, times)  # [B, K, T, d]
        per = self._per_hypothesis(z, z_target, y, trajectories)  # [B, K]
        cost = self._winner_takes_all(per, logits)
        if self.uses_images:
            if images is None:
                raise ValueError("the ink terms of the cost need the images")
            cost = cost + self._ink_terms(y, images, per.detach().argmin(dim=1))
        if y is None:
            return cost, None
        top = logits.argmax(dim=1)  # [B]
        return cost, y[torch.arange(b), top].detach()

    def errors_px(self, z_pred, y, times, trajectories) -> torch.Tensor:
        """Table I's error per sample ``[b]`` (px) of a training step: the cost's own
        rollout ``y`` of the top hypothesis (cost 10), or, for ``y`` None (cost 9), one
        more rollout of it at ``times``."""
        if y is None:
            from .model import top_hypothesis

            top = top_hypothesis(z_pred, self.hypotheses)  # [b, P]
            y = dmp_trajectory(top, times, self.normaliser, self.config)  # [b, T, d]
        return trajectory_error_px(y, trajectories)

    def image_terms(self, z_pred: torch.Tensor, images: torch.Tensor, times: torch.Tensor):
        """The ink terms alone (no demonstration needed): for images without a recorded
        path. ``z_pred [B, ...]`` network outputs, ``images [B, H, W]``, ``times [B, T]``."""
        from .model import split_hypotheses

        z, logits = split_hypotheses(z_pred, self.hypotheses)
        return self._ink_terms(self._rollouts(z, times), images, logits.detach().argmax(dim=1))

    def _rollouts(self, z: torch.Tensor, times: torch.Tensor) -> torch.Tensor:
        """Every hypothesis ``z [B, K, P]`` rolled out at ``times [B, T]``: ``[B, K, T, d]``."""
        b, k, p = z.shape
        t = times.repeat_interleave(k, dim=0)  # [B K, T]
        y = dmp_trajectory(z.reshape(b * k, p), t, self.normaliser, self.config)
        return y.reshape(b, k, *y.shape[1:])

    def _ink_terms(self, y: torch.Tensor, images: torch.Tensor, chosen: torch.Tensor):
        """Weighted ink terms of hypotheses ``y [B, K, T, d]``: attraction on every one,
        coverage on the ``chosen [B]`` one (the winner, or the top-scored one without a
        demonstration), which is the path that is to write the whole digit."""
        from .ink import ink_attraction, ink_coverage, ink_distance_map

        b, k = y.shape[:2]
        cost = y.new_zeros(())
        if self.ink_weight > 0:
            flat = y.reshape(b * k, *y.shape[2:])  # [B K, T, d]
            dist = ink_distance_map(images).repeat_interleave(k, dim=0)  # once per image
            cost = cost + self.ink_weight * ink_attraction(flat, dist).mean()
        if self.coverage_weight > 0:
            one = y[torch.arange(b, device=y.device), chosen]  # [B, T, d]
            cov = ink_coverage(one, images, tolerance_px=self.coverage_tolerance_px)
            cost = cost + self.coverage_weight * cov.mean()
        return cost

    def _per_hypothesis(self, z, z_target, y, trajectories) -> torch.Tensor:
        """Each sample's cost (9), (10) or their sum for each of its hypotheses, [B, K]."""
        per = 0.0
        if self.name in ("parameter", "combined"):
            e = z - z_target[:, None, :]  # [B, K, P]
            w = self._weights
            if w is None:
                c9 = (e**2).mean(-1)
            elif w.ndim == 1:
                c9 = (e**2 * w.to(e.dtype)).mean(-1)
            else:
                c9 = ((e @ w.to(e.dtype)) * e).mean(-1)
            per = c9 if self.name == "parameter" else self.parameter_weight * c9
        if self.name in ("trajectory", "combined"):
            c10 = ((y - trajectories[:, None]) ** 2).sum(-1).mean(-1)  # [B, K]
            per = per + (c10 if self.name == "trajectory" else self.trajectory_weight * c10)
        if self.path_weight:
            b, k = y.shape[:2]
            demo = trajectories.repeat_interleave(k, dim=0)  # [B K, T, d]
            cp = path_cost(y.reshape(b * k, *y.shape[2:]), demo).reshape(b, k)
            per = per + self.path_weight * cp
        return per

    def _winner_takes_all(self, per: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
        """Relaxed min over the hypotheses plus the scores' cross-entropy (K > 1)."""
        k = per.shape[1]
        if k == 1:
            return per.mean()
        winner = per.detach().argmin(dim=1)  # [B]
        w = torch.full_like(per, self.wta_relax / (k - 1))
        w.scatter_(1, winner[:, None], 1.0 - self.wta_relax)
        ce = torch.nn.functional.cross_entropy(logits, winner)
        return (w * per).sum(1).mean() + self.score_weight * ce
