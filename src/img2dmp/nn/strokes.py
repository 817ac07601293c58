"""Characters as sequences of strokes, each stroke its own DMP (issue 32, part 4).

One DMP with a pen coordinate cannot hold the two to ten strokes of a character: the pen
channel smears the strokes' ends and the travel between them is drawn. A *stroke model*
predicts a character as up to S strokes instead, each the paper's 2-D DMP with its own
tau, g and y0 (55 numbers for 25 kernels), plus per stroke a *presence* logit (is this
slot a stroke of the character?) and an *order* key (when is it written?). The network
is the same :class:`~img2dmp.nn.model.EncoderDecoder`: its output per hypothesis is
``S (P + 2)`` numbers, slot by slot ``[z_1 .. z_P, presence, order]``.

Training (:class:`StrokeCost`) compares each predicted stroke's *shape* with the true
strokes': both at ``n_points`` instants evenly spaced over their own duration (the DMP
rolled out at ``t = u tau``, ``u`` in [0, 1], which does not depend on tau), matched
predicted slot to true stroke by the least total cost (Hungarian; ``matching="order"``
pairs slot i with stroke i instead). The matched slots learn their duration (tau, in the
normaliser's units), presence 1 and the stroke's place in the writing order; the others
presence 0. With K hypotheses the least-cost hypothesis wins as for one-DMP models.

A character (:func:`character_paths`) is its present strokes in the order of their keys,
each rolled out over its own tau, with straight pen-up travel between them: a path
``[T, 3]`` (x, y, pen) like every other path of img2dmp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..dmp.rollout import rollout
from ._stroke_layout import (  # noqa: F401 (re-exported: the torch-free names)
    COUNT_VIEW_RANGES,
    COUNT_VIEWS,
    MATCHINGS,
    MAX_COUNT_VIEWS,
    MAX_SLOTS,
    MIN_STROKE_S,
    STROKE_REFINE,
    StrokeLayout,
    character_paths,
    count_probabilities,
    count_views,
    ink_pieces,
    read_strokes,
    split_slots_numpy,
    stroke_dmp_config,
)
from .normalise import ParamNormaliser


@dataclass
class StrokeSamplers:
    """Where each row's strokes are read off its path: the first S strokes at
    ``n_points`` instants evenly spaced in time, as linear interpolation between
    instants ``i0`` and ``i1`` of the row (``frac`` the weight of ``i1``).

    ``i0``, ``i1`` int64 ``[N, S, n]``, ``frac`` ``[N, S, n]``, ``present`` bool
    ``[N, S]``, ``duration`` ``[N, S]`` (s, at least :data:`MIN_STROKE_S`),
    ``n_strokes`` ``[N]`` (all of a row's strokes, also beyond S).
    """

    i0: np.ndarray
    i1: np.ndarray
    frac: np.ndarray
    present: np.ndarray
    duration: np.ndarray
    n_strokes: np.ndarray

    def rows(self, idx) -> StrokeSamplers:
        return StrokeSamplers(
            *(getattr(self, k)[idx] for k in ("i0", "i1", "frac", "present", "duration")),
            self.n_strokes[idx],
        )


def stroke_samplers(spans: list, times: np.ndarray, layout: StrokeLayout) -> StrokeSamplers:
    """:class:`StrokeSamplers` of rows whose strokes are ``spans[r]`` (``[first, last]``
    instants, :meth:`img2dmp.data.store.DigitData.stroke_spans`) at ``times [N, T]``.

    A row of more than S strokes keeps its first S (``n_strokes`` still counts them all,
    so such a row's count can never be read right). A row of no stroke is refused.
    """
    times = np.asarray(times, dtype=np.float64)
    n, s, m = len(spans), layout.slots, layout.n_points
    i0 = np.zeros((n, s, m), np.int64)
    i1 = np.zeros((n, s, m), np.int64)
    frac = np.zeros((n, s, m))
    present = np.zeros((n, s), bool)
    duration = np.full((n, s), MIN_STROKE_S)
    counts = np.zeros(n, np.int64)
    u = np.linspace(0.0, 1.0, m)
    for r, row in enumerate(spans):
        if not len(row):
            raise ValueError(f"row {r} has no stroke")
        counts[r] = len(row)
        for k, (a, b) in enumerate(row[:s]):
            t = times[r, a : b + 1]
            q = t[0] + u * (t[-1] - t[0])
            j = np.clip(np.searchsorted(t, q, side="right") - 1, 0, max(b - a - 1, 0))
            j1 = np.minimum(j + 1, b - a)
            dt = t[j1] - t[j]
            frac[r, k] = np.where(dt > 0, (q - t[j]) / np.where(dt > 0, dt, 1.0), 0.0)
            i0[r, k], i1[r, k] = a + j, a + j1
            present[r, k] = True
            duration[r, k] = max(float(t[-1] - t[0]), MIN_STROKE_S)
    return StrokeSamplers(i0, i1, frac, present, duration, counts)


def pen_spans(path: np.ndarray) -> list[tuple[int, int]]:
    """The strokes ``[(first, last), ...]`` of one path ``[T, d]``: its runs of pen > 0.5
    (d = 3; a path whose pen is never down, and any d = 2 path, is one stroke)."""
    if path.shape[-1] < 3:
        return [(0, len(path) - 1)]
    down = np.concatenate([[False], path[:, 2] > 0.5, [False]])
    edges = np.flatnonzero(np.diff(down.astype(np.int8)))
    if not len(edges):
        return [(0, len(path) - 1)]
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def stroke_targets(trajectories: torch.Tensor, times: torch.Tensor, layout: StrokeLayout):
    """A batch's true strokes from its paths ``[B, T, d]`` at ``times [B, T]``: points
    ``[B, S, n, 2]``, ``present [B, S]``, ``duration [B, S]`` (s), stroke counts ``[B]``."""
    host = trajectories.detach().cpu().numpy()
    spans = [pen_spans(p) for p in host]
    s = stroke_samplers(spans, times.detach().cpu().numpy(), layout)
    dev = trajectories.device
    i0, i1 = torch.as_tensor(s.i0, device=dev), torch.as_tensor(s.i1, device=dev)
    pts = stroke_points(trajectories, i0, i1, torch.as_tensor(s.frac, device=dev))
    as_t = torch.as_tensor
    return pts, as_t(s.present, device=dev), as_t(s.duration, device=dev), as_t(s.n_strokes)


def stroke_points(paths: torch.Tensor, i0, i1, frac) -> torch.Tensor:
    """The strokes' points ``[B, S, n, 2]`` of paths ``[B, T, d]`` (x, y) read with the
    samplers' ``i0``, ``i1``, ``frac`` ``[B, S, n]`` (tensors)."""
    b, s, m = i0.shape
    xy = paths[..., :2]
    g0 = torch.gather(xy, 1, i0.reshape(b, s * m, 1).expand(-1, -1, 2))
    g1 = torch.gather(xy, 1, i1.reshape(b, s * m, 1).expand(-1, -1, 2))
    f = frac.reshape(b, s * m, 1).to(xy.dtype)
    return ((1 - f) * g0 + f * g1).reshape(b, s, m, 2)


def fit_stroke_vectors(points: np.ndarray, duration: np.ndarray, layout: StrokeLayout):
    """Flat DMP vectors ``[M, P]`` fitted to strokes ``points [M, n, 2]`` lasting
    ``duration [M]`` s (the normaliser's training set), and their mean fit error (px)."""
    from ..dmp.fit import fit_dmp

    u = np.linspace(0.0, 1.0, points.shape[1])
    t = u[None] * np.asarray(duration, dtype=np.float64)[:, None]
    res = fit_dmp(t, np.asarray(points, dtype=np.float64), layout.config, ridge=1e-6)
    return np.asarray(res.params.to_vector()), float(np.mean(res.error_px))


def fit_stroke_normaliser(points, duration, layout: StrokeLayout) -> ParamNormaliser:
    """The output normalisation of stroke DMPs fitted to training strokes."""
    vectors, _ = fit_stroke_vectors(points, duration, layout)
    return ParamNormaliser.fit(vectors, layout.config)


def split_slots(out: torch.Tensor, layout: StrokeLayout, hypotheses: int):
    """Network output ``[B, K (S (P + 3) + 1)]`` (or ``[B, S (P + 3)]`` for K = 1) as
    stroke vectors ``[B, K, S, P]``, presence logits ``[B, K, S]``, order keys
    ``[B, K, S]``, stroke-count logits ``[B, K, S]`` (count 1 to S) and hypothesis scores
    ``[B, K]``."""
    from .model import split_hypotheses

    v, scores = split_hypotheses(out, hypotheses)  # [B, K, S (P + 3)], [B, K]
    s, p = layout.slots, layout.n_params
    z = v[..., : s * layout.slot_width].reshape(*v.shape[:2], s, layout.slot_width)
    return z[..., :p], z[..., p], z[..., p + 1], v[..., s * layout.slot_width :], scores


def stroke_shapes(z: torch.Tensor, normaliser: ParamNormaliser, layout: StrokeLayout):
    """Each stroke vector ``z [..., P]`` rolled out at ``n_points`` instants over its own
    tau: shapes ``[..., n, 2]`` (differentiable; independent of tau)."""
    params = normaliser.denormalise(z.reshape(-1, z.shape[-1]))
    u = torch.linspace(0.0, 1.0, layout.n_points, dtype=z.dtype, device=z.device)
    t = u[None] * params.tau[:, None]
    y = rollout(params, t, layout.config, validate=False)  # [M, n, 2]
    return y.reshape(*z.shape[:-1], layout.n_points, 2)


def _assignment(cost: np.ndarray, present: np.ndarray, matching: str) -> np.ndarray:
    """Slot matched to each true stroke, ``[B, K, S]`` (-1 where no stroke), from the
    detached pair costs ``[B, K, S_pred, S_true]``."""
    from scipy.optimize import linear_sum_assignment

    b, k, s, _ = cost.shape
    match = np.full((b, k, s), -1, np.int64)
    for i in range(b):
        cols = np.flatnonzero(present[i])
        for h in range(k):
            if matching == "order":
                match[i, h, cols] = cols
            else:
                rows, cc = linear_sum_assignment(cost[i, h][:, cols])
                match[i, h, cols[cc]] = rows
    return match


class StrokeCost:
    """Training cost of a stroke model (see the module docstring).

    ``strokes_cost(out, target, present, duration, n_strokes, images=None)``: network output
    ``[B, ...]``, true strokes ``target [B, S, n, 2]`` (px), ``present`` bool ``[B, S]``,
    ``duration`` ``[B, S]`` (s), each character's stroke count ``[B]`` and, for the ink
    terms, the images ``[B, H, W]``. Returns the cost (a scalar tensor) and, per sample,
    the top hypothesis' mean shape error over its true strokes (px, detached, ``[B]``).

    Per sample and hypothesis: the mean over true strokes of the matched slot's mean
    squared distance (px^2) + ``tau_weight`` times its squared tau error (normalised
    units) + ``order_weight`` times its order key's squared error (the stroke's place
    ``j / (S - 1)``; ``matching="best"`` only), plus ``presence_weight`` times the
    presence cross-entropy over all slots, ``count_weight`` times the stroke count's
    cross-entropy (counts above S as S) and, with images, ``ink_weight`` times the ink
    attraction and ``coverage_weight`` times the ink coverage (:mod:`img2dmp.nn.ink`) of
    the matched slots' union. K > 1: relaxed winner takes all and the scores'
    cross-entropy, as :class:`img2dmp.nn.costs.Cost`.
    """

    def __init__(
        self,
        layout: StrokeLayout,
        normaliser: ParamNormaliser,
        hypotheses: int = 1,
        *,
        presence_weight: float = 2.0,
        count_weight: float = 1.0,
        tau_weight: float = 0.1,
        order_weight: float = 2.0,
        ink_weight: float = 0.0,
        coverage_weight: float = 0.0,
        coverage_tolerance_px: float = 1.0,
        score_weight: float = 0.1,
        wta_relax: float = 0.05,
    ):
        self.layout, self.normaliser, self.hypotheses = layout, normaliser, int(hypotheses)
        self.presence_weight, self.count_weight = presence_weight, count_weight
        self.tau_weight, self.order_weight = tau_weight, order_weight
        self.ink_weight, self.coverage_weight = ink_weight, coverage_weight
        self.coverage_tolerance_px = coverage_tolerance_px
        self.score_weight, self.wta_relax = score_weight, wta_relax

    @property
    def uses_images(self) -> bool:
        return self.ink_weight > 0 or self.coverage_weight > 0

    def __call__(self, out, z_target, times, trajectories, images=None):
        """The cost with :class:`img2dmp.nn.costs.Cost`'s signature: the true strokes read
        off ``trajectories [B, T, d]`` (their pen runs) at ``times [B, T]``; ``z_target``
        the stroke count's target distributions ``[B, S]``
        (:func:`img2dmp.training.data.count_targets`), or empty ``[B, 0]`` for each
        path's own count. Returns the cost and the per-sample shape error (px)."""
        target, present, duration, n = stroke_targets(trajectories, times, self.layout)
        counts = z_target if z_target.shape[-1] == self.layout.slots else None
        return self.strokes_cost(
            out, target.to(out.dtype), present, duration, n, images, count_target=counts
        )

    def errors_px(self, z, y, times, trajectories) -> torch.Tensor:
        """A training step's per-sample error: what the cost returned beside itself."""
        return y

    def strokes_cost(
        self, out, target, present, duration, n_strokes, images=None, count_target=None
    ):
        lay = self.layout
        z, presence, order, count, scores = split_slots(out, lay, self.hypotheses)
        y = stroke_shapes(z, self.normaliser, lay)  # [B, K, S, n, 2]
        d2 = ((y[:, :, :, None] - target[:, None, None]) ** 2).sum(-1).mean(-1)  # [B,K,S,S]
        ti = self.normaliser.tau_index
        tau_true = self._tau_units(duration, z)  # [B, S]
        dtau = (z[..., ti][..., :, None] - tau_true[:, None, None, :]) ** 2  # [B, K, S, S]
        pair = d2 + self.tau_weight * dtau
        match = _assignment(pair.detach().cpu().numpy(), present.cpu().numpy(), lay.matching)
        m = torch.as_tensor(match, device=pair.device)  # [B, K, S_true]: slot, or -1
        per, used = self._matched(pair, m, presence, order)
        per = per + self.count_weight * self._count_ce(count, n_strokes, count_target)
        if images is not None and self.uses_images:
            per = per + self._ink(y, used, images)
        err = self._shape_error(d2, m, scores)
        return self._winner(per, scores), err

    def _count_ce(self, count, n_strokes, count_target=None) -> torch.Tensor:
        """The count logits' ``[B, K, S]`` cross-entropy ``[B, K]`` against each
        character's count (above S as S), or against ``count_target`` ``[B, S]``
        (distributions over the counts 1 to S)."""
        b, k, s = count.shape
        if count_target is None:
            n = (n_strokes.to(count.device).clamp(1, s) - 1)[:, None].expand(-1, k)
            target = n.flatten()
        else:
            target = count_target.to(count)[:, None].expand(-1, k, -1).flatten(0, 1)
        ce = torch.nn.functional.cross_entropy(count.flatten(0, 1), target, reduction="none")
        return ce.reshape(b, k)

    def _tau_units(self, duration: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        ti = self.normaliser.tau_index
        c = float(self.normaliser.centre[ti])
        s = float(self.normaliser.scale[ti])
        return (torch.log(duration.to(like.dtype)) - c) / s

    def _matched(self, pair, m, presence, order):
        """Each hypothesis' cost of its matched slots ``[B, K]`` and which slots are
        matched ``[B, K, S]`` (float 0/1)."""
        s = presence.shape[-1]
        has = m >= 0
        slot = m.clamp_min(0)
        picked = torch.gather(pair, 2, slot[:, :, None, :]).squeeze(2)  # [B, K, S_true]
        n_true = has.sum(-1).clamp_min(1)
        per = (picked * has).sum(-1) / n_true  # [B, K]
        used = torch.zeros_like(presence).scatter_add_(2, slot, has.to(presence.dtype))
        used = used.clamp_max(1)
        bce = torch.nn.functional.binary_cross_entropy_with_logits(
            presence, used, reduction="none"
        ).mean(-1)
        per = per + self.presence_weight * bce
        if self.layout.matching == "best":
            place = torch.arange(s, device=pair.device, dtype=pair.dtype) / max(s - 1, 1)
            key = torch.gather(order, 2, slot)  # [B, K, S_true]
            per = per + self.order_weight * (((key - place) ** 2) * has).sum(-1) / n_true
        return per, used

    def _ink(self, y, used, images):
        """The ink terms of each hypothesis' matched slots, ``[B, K]``."""
        from .ink import ink_attraction, ink_coverage, ink_distance_map

        b, k, s, n = y.shape[:4]
        pen = used[..., None, None].expand(-1, -1, -1, n, 1).to(y.dtype)
        path = torch.cat([y, pen], -1).reshape(b * k, s * n, 3)
        imgs = images.to(y.dtype).repeat_interleave(k, dim=0)
        cost = y.new_zeros(b * k)
        if self.ink_weight > 0:
            cost = cost + self.ink_weight * ink_attraction(path, ink_distance_map(imgs))
        if self.coverage_weight > 0:
            cov = ink_coverage(path, imgs, tolerance_px=self.coverage_tolerance_px)
            cost = cost + self.coverage_weight * cov
        return cost.reshape(b, k)

    def _shape_error(self, d2, m, scores) -> torch.Tensor:
        """The top-scored hypothesis' root mean squared shape error per true stroke,
        averaged over the strokes (px, detached) ``[B]``."""
        has = m >= 0
        slot = m.clamp_min(0)
        err = torch.gather(d2, 2, slot[:, :, None, :]).squeeze(2).clamp_min(0).sqrt()
        err = ((err * has).sum(-1) / has.sum(-1).clamp_min(1)).detach()  # [B, K]
        best = scores.detach().argmax(1)
        return err[torch.arange(len(err), device=err.device), best]

    def _winner(self, per: torch.Tensor, scores: torch.Tensor) -> torch.Tensor:
        k = per.shape[1]
        if k == 1:
            return per.mean()
        winner = per.detach().argmin(dim=1)
        w = torch.full_like(per, self.wta_relax / (k - 1))
        w.scatter_(1, winner[:, None], 1.0 - self.wta_relax)
        ce = torch.nn.functional.cross_entropy(scores, winner)
        return (w * per).sum(1).mean() + self.score_weight * ce


def _padded(strokes: list, p: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Characters' stroke vectors as ``[B, S_max, P]`` (float64) and their mask ``[B, S_max]``."""
    s_max = max((len(v) for v, _ in strokes), default=1)
    z = torch.zeros(len(strokes), s_max, p, dtype=torch.float64)
    mask = torch.zeros(len(strokes), s_max, dtype=torch.bool)
    for i, (v, _) in enumerate(strokes):
        z[i, : len(v)] = torch.as_tensor(np.asarray(v, dtype=np.float64))
        mask[i, : len(v)] = True
    return z, mask


def refine_strokes(strokes: list, images, normaliser, layout: StrokeLayout, options=None):
    """:func:`read_strokes`' characters refined on their images ``[B, H, W]``: the
    :mod:`img2dmp.nn.refine` objective (ink attraction and coverage of the union of a
    character's strokes, prior ``|z - z_0|^2 / P``) over all of its strokes' vectors at
    once, Adam for ``options.steps`` steps. A stroke's shape does not depend on its tau
    (the DMP runs on ``t / tau``): tau is left as the network gave it (its gradient,
    zero but for rounding, would otherwise drift it under Adam's normalised steps).
    The same list shape, vectors replaced; :func:`img2dmp.nn._refine_numpy.
    refine_strokes_numpy` is the same in NumPy."""
    from .ink import ink_distance_map
    from .refine import RefineOptions, _Adam, ink_terms

    o = options or RefineOptions()
    if o.steps == 0 or not strokes:
        return strokes
    z0, mask = _padded(strokes, layout.n_params)
    imgs = torch.as_tensor(np.asarray(images), dtype=torch.float64)
    dist = ink_distance_map(imgs)
    pen = mask.to(torch.float64)[:, :, None].expand(-1, -1, layout.n_points)
    pen = pen.reshape(len(z0), -1, 1)  # [B, S_max n, 1]
    z = z0.clone().requires_grad_()
    adam = _Adam(z, o.lr)
    with torch.enable_grad():
        for _ in range(int(o.steps)):
            xy = stroke_shapes(z, normaliser, layout).reshape(len(z), -1, 2)
            y = torch.cat([xy, pen], -1)  # [B, S_max n, 3]
            prior = (((z - z0) ** 2).mean(-1) * mask).sum(-1) / mask.sum(-1)
            j = o.prior_weight * prior + ink_terms(y, dist, imgs, o)
            z.grad = None
            j.sum().backward()
            z.grad[..., normaliser.tau_index] = 0.0
            adam.step()
    z = z.detach().numpy()
    return [(z[i, : len(v)], p) for i, (v, p) in enumerate(strokes)]
