"""The torch-free part of stroke models (:mod:`img2dmp.nn.strokes`): the layout of the
network's output, reading it as each character's strokes, and rolling those out as one
path with the pen. Prediction on the NumPy backend imports this and never torch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dmp.config import DMPConfig

#: How predicted strokes are paired with the true ones in training.
MATCHINGS = ("best", "order")
#: The shortest stroke duration a DMP is given (s): a dot lasts no time at all.
MIN_STROKE_S = 0.02
#: The refinement settings of stroke models (:class:`~img2dmp.nn.refine.RefineOptions`
#: fields beside ``steps``): a weaker prior and larger steps than one-DMP models', chosen
#: on Omniglot's validation drawers (RESULTS 8.0).
STROKE_REFINE = {"lr": 0.04, "prior_weight": 0.3}
#: The largest number of stroke slots a model may have.
MAX_SLOTS = 32
#: How many views of an image a stroke model reads its stroke count from: the image and
#: ``COUNT_VIEWS - 1`` small affine copies of it (:data:`COUNT_VIEW_RANGES`), whose count
#: probabilities are averaged (chosen on Omniglot's validation drawers, RESULTS 8.1).
COUNT_VIEWS = 8
#: The most views a count may be read from.
MAX_COUNT_VIEWS = 64
#: The copies' transforms (:class:`~img2dmp.data.affine.AffineRanges` fields), drawn once
#: from a fixed seed: the same views of every image, every run.
COUNT_VIEW_RANGES = {"translation_rel": (-0.03, 0.03), "rotation_deg": (-6.0, 6.0),
                     "scale": (0.93, 1.07), "shear_deg": (-6.0, 6.0)}  # fmt: skip
#: The ink level and the fewest pixels of a piece of ink (:func:`ink_pieces`).
PIECE_LEVEL, PIECE_MIN_PX = 0.5, 2


def stroke_dmp_config(n_kernels: int = 25) -> DMPConfig:
    """The DMP of one stroke: 2-D, forcing term unscaled (closed strokes stay well-posed)."""
    return DMPConfig(n_kernels=n_kernels, n_dims=2, scaling="none")


@dataclass(frozen=True)
class StrokeLayout:
    """How a stroke model's output is laid out and compared.

    Attributes
    ----------
    slots : int
        S, the most strokes one character can have (1-``MAX_SLOTS``).
    n_kernels : int
        Kernels per dimension of each stroke's DMP.
    n_points : int
        Instants per stroke at which shapes are compared (>= 2).
    matching : {"best", "order"}
        Predicted slots to true strokes by least cost, or slot i to stroke i.
    """

    slots: int = 8
    n_kernels: int = 25
    n_points: int = 32
    matching: str = "best"

    def __post_init__(self) -> None:
        for name, lo, hi in (("slots", 1, MAX_SLOTS), ("n_points", 2, 1000)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValueError(f"strokes.{name} must be an integer from {lo} to {hi}, got {v!r}")
        if self.matching not in MATCHINGS:
            raise ValueError(f"strokes.matching must be one of {MATCHINGS}, got {self.matching!r}")
        stroke_dmp_config(self.n_kernels)  # checks n_kernels

    @property
    def config(self) -> DMPConfig:
        return stroke_dmp_config(self.n_kernels)

    @property
    def n_params(self) -> int:
        """P, the numbers of one stroke's DMP."""
        return self.config.n_params

    @property
    def slot_width(self) -> int:
        return self.n_params + 2

    @property
    def n_outputs(self) -> int:
        """The network's output per hypothesis: ``S (P + 2)`` numbers of the slots, then
        ``S`` logits of the stroke count (1 to S)."""
        return self.slots * (self.slot_width + 1)

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("slots", "n_kernels", "n_points", "matching")}

    @classmethod
    def from_dict(cls, d: dict) -> StrokeLayout:
        return cls(**{k: d[k] for k in ("slots", "n_kernels", "n_points", "matching")})


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def split_slots_numpy(out: np.ndarray, layout: StrokeLayout, hypotheses: int):
    """:func:`img2dmp.nn.strokes.split_slots` in NumPy: stroke vectors ``[B, K, S, P]``,
    presence logits, order keys, count logits ``[B, K, S]`` and scores ``[B, K]``."""
    out = np.asarray(out, dtype=np.float64)
    k = int(hypotheses)
    if out.ndim != 2 or out.shape[1] != layout.n_outputs * k + (k if k > 1 else 0):
        raise ValueError(
            f"network outputs have shape {out.shape}, a stroke model of {layout.slots} "
            f"slots and {k} hypotheses gives [B, {layout.n_outputs * k + (k if k > 1 else 0)}]"
        )
    if k == 1:
        v, scores = out[:, None, :], np.zeros((len(out), 1))
    else:
        v, scores = out[:, : k * layout.n_outputs].reshape(-1, k, layout.n_outputs), out[:, -k:]
    s, p, width = layout.slots, layout.n_params, layout.slot_width
    z = v[..., : s * width].reshape(*v.shape[:2], s, width)
    return z[..., :p], z[..., p], z[..., p + 1], v[..., s * width :], scores


def count_views(images: np.ndarray, n_views: int = COUNT_VIEWS) -> np.ndarray:
    """The ``n_views - 1`` affine copies ``[n_views - 1, B, H, W]`` of prepared images
    ``[B, H, W]`` that a stroke count is also read from (:data:`COUNT_VIEW_RANGES`; NumPy)."""
    from ..data.affine import AffineRanges, sample_affine, warp_images_numpy

    x = np.asarray(images, dtype=np.float32)
    rng = np.random.default_rng(0)
    m = sample_affine(rng, n_views - 1, tuple(x.shape[-2:]), AffineRanges(**COUNT_VIEW_RANGES))
    if not len(m):
        return np.zeros((0, *x.shape), np.float32)
    return np.stack([warp_images_numpy(x, mi) for mi in m])


def ink_pieces(images: np.ndarray) -> np.ndarray:
    """Pieces of ink ``[B]`` of prepared images ``[B, H, W]``: 8-connected sets of at
    least :data:`PIECE_MIN_PX` pixels above :data:`PIECE_LEVEL`. A stroke is one
    unbroken line, so a character has at least as many strokes as pieces."""
    from scipy.ndimage import label

    out = []
    for im in np.asarray(images):
        labels, n = label(im > PIECE_LEVEL, structure=np.ones((3, 3), bool))
        out.append(int((np.bincount(labels.ravel(), minlength=n + 1)[1:] >= PIECE_MIN_PX).sum()))
    return np.asarray(out, dtype=np.int64)


def count_probabilities(count_logits: np.ndarray) -> np.ndarray:
    """The stroke count's probabilities ``[B, K, S]`` from its logits read off several
    views of each image ``[V, B, K, S]`` (or one view ``[B, K, S]``): their softmax,
    averaged over the views."""
    a = np.asarray(count_logits, dtype=np.float64)
    e = np.exp(a - a.max(-1, keepdims=True))
    p = e / e.sum(-1, keepdims=True)
    return p.mean(0) if p.ndim == 4 else p


def read_strokes(
    out, layout: StrokeLayout, hypotheses: int, hypothesis=None, count_probs=None,
    min_counts=None,
) -> list:  # fmt: skip
    """The strokes of each image from network outputs ``out [B, ...]``: per sample the
    chosen hypothesis' (``hypothesis`` [B], or the top-scored one) strokes in writing
    order, as (normalised vectors ``[c, P]``, presence probabilities ``[c]``) pairs. c is
    the most probable stroke count (by ``count_probs [B, K, S]``, :func:`count_probabilities`,
    or else the outputs' own count logits) of those at least ``min_counts [B]`` (e.g.
    :func:`ink_pieces`; capped at S); the strokes are the first c slots
    (``matching="order"``) or the c most probably present ones in the order of their
    keys (``"best"``)."""
    z, presence, order, count, scores = split_slots_numpy(out, layout, hypotheses)
    rows = np.arange(len(z))
    h = scores.argmax(1) if hypothesis is None else np.asarray(hypothesis)
    prob = _sigmoid(presence[rows, h])  # [B, S]
    p_count = count_probabilities(count if count_probs is None else count_probs)[rows, h]
    if min_counts is not None:
        least = np.clip(np.asarray(min_counts), 1, layout.slots)[:, None]  # [B, 1]
        p_count = np.where(np.arange(1, layout.slots + 1)[None] >= least, p_count, -1.0)
    c = p_count.argmax(-1) + 1  # [B]
    result = []
    for i in rows:
        if layout.matching == "order":
            on = np.arange(c[i])
        else:
            on = np.sort(np.argsort(-prob[i], kind="stable")[: c[i]])
            on = on[np.argsort(order[i, h[i], on], kind="stable")]
        result.append((z[i, h[i], on], prob[i, on]))
    return result


def stroke_params(vectors: np.ndarray, normaliser):
    """Normalised stroke vectors ``[M, P]`` as :class:`~img2dmp.dmp.DMPParams` ``[M]``."""
    from ..dmp.params import DMPParams

    v = normaliser.denormalise_numpy(np.asarray(vectors, dtype=np.float64))
    return DMPParams.from_vector(v, normaliser.n_kernels, normaliser.n_dims)


def character_paths(
    strokes: list, normaliser, layout: StrokeLayout, n_per_stroke: int = 40, n_travel: int = 4
) -> list[np.ndarray]:
    """Each character's strokes (:func:`read_strokes`) as one path ``[T, 3]``: every
    stroke's DMP rolled out at ``n_per_stroke`` instants over its own tau (pen 1), then
    ``n_travel`` points of straight pen-up travel to the next stroke's start (pen 0).
    NumPy (:func:`img2dmp.dmp._numpy_rollout.rollout_numpy`)."""
    from ..dmp._numpy_rollout import rollout_numpy

    counts = [len(v) for v, _ in strokes]
    if not sum(counts):
        return [np.zeros((0, 3)) for _ in strokes]
    params = stroke_params(np.concatenate([v for v, _ in strokes if len(v)]), normaliser)
    u = np.linspace(0.0, 1.0, n_per_stroke)
    y = rollout_numpy(params, u[None] * params.tau[:, None], layout.config, validate=False)
    paths, at = [], 0
    f = np.linspace(0.0, 1.0, n_travel + 2)[1:-1, None]
    for c in counts:
        parts = []
        for j in range(c):
            s = y[at + j]
            parts.append(np.column_stack([s, np.ones(len(s))]))
            if j + 1 < c:
                a, b = s[-1], y[at + j + 1][0]
                parts.append(np.column_stack([a + f * (b - a), np.zeros(n_travel)]))
        at += c
        paths.append(np.concatenate(parts) if parts else np.zeros((0, 3)))
    return paths


def padded_paths(paths: list[np.ndarray], length: int | None = None) -> np.ndarray:
    """Paths of different lengths ``[T_i, 3]`` as one array ``[M, T, 3]``: each repeats
    its last point, pen up, to the longest (or ``length``); measures along the pen-down
    path are unchanged."""
    t = max([len(p) for p in paths] + [length or 0, 1])
    out = np.zeros((len(paths), t, 3))
    for i, p in enumerate(paths):
        out[i, : len(p)] = p
        if len(p) < t:
            out[i, len(p) :, :2] = p[-1, :2] if len(p) else 0.0
    return out
