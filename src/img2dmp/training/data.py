"""Feeding a training run: its training and validation examples, and their augmentation.

:class:`TrainingData` holds the validation split and hands out each epoch's training
split, from a stored data set (the same samples every epoch) or from the on-the-fly
generator (fresh samples every epoch, drawn from ``(seed, epoch)`` so that a resumed run
sees the same ones). It also fits what the model keeps of its data: the output
normalisation, cost (9)'s parameter weighting, and how the images frame their ink.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
import torch

from .._files import file_digest
from ..config import ConfigError
from ..data.images import ink_margin, typical_stroke_width
from ..data.store import SPLITS, DigitData, digits_named, load_dataset
from ..dmp import DMPConfig
from ..nn import ParamNormaliser
from ..nn.costs import ParameterWeighting
from .config import TrainConfig

#: Validation images measured for the ink framing and pen width the model records.
_FRAMING_SAMPLES = 500


def generate_arrays(options: dict, n: int, seed: int, epoch: int = 0) -> DigitData:
    """``n`` fresh synthetic samples for one epoch from the on-the-fly generator
    (:class:`img2dmp.data.torch_data.SyntheticDigitStream`, seeded by ``(seed, epoch)``).

    ``options`` are :class:`~img2dmp.data.synthetic.SyntheticConfig` fields plus an
    optional ``dmp_config`` mapping.
    """
    from torch.utils.data import DataLoader

    from ..data.synthetic import SyntheticConfig
    from ..data.torch_data import SyntheticDigitStream

    opts = dict(options)
    dmp = DMPConfig.from_dict(opts.pop("dmp_config", {}) or {})
    config = SyntheticConfig.from_dict(opts)
    stream = SyntheticDigitStream(config, samples_per_epoch=int(n), seed=int(seed), dmp_config=dmp)
    stream.set_epoch(int(epoch))
    b = next(iter(DataLoader(stream, batch_size=int(n))))  # one batch = the whole epoch
    return DigitData(
        images=b["image"][:, 0].numpy(),  # [n, H, W]
        trajectories=b["trajectory"].numpy(),  # [n, T, d]
        times=b["times"].numpy(),  # [n, T]
        labels=b["label"].numpy(),
        params=b["params"].numpy(),  # [n, P]
        fit_error_px=b["fit_error_px"].numpy(),
        split=np.zeros(int(n), np.uint8),
        meta={"dmp_config": dmp.to_dict(), "source": {"kind": "synthetic"}, "seed": int(seed)},
    )


@dataclass
class Split:
    """Examples as the training step takes them (float32 tensors)."""

    images: torch.Tensor  # [M, H, W]
    times: torch.Tensor  # [M, T]
    trajectories: torch.Tensor  # [M, T, d]
    # [M, P], normalised DMP vector (cost 9's target); a stroke model's: the target
    # distribution of the stroke count [M, S] (count_targets)
    z_target: torch.Tensor

    def __len__(self) -> int:
        return int(self.images.shape[0])

    @classmethod
    def of(cls, a: DigitData, idx: np.ndarray, norm: ParamNormaliser | None, counts=None) -> Split:
        """Rows ``idx`` of ``a``; without a normaliser (a stroke model, whose targets are
        the paths' strokes) ``z_target`` is ``counts`` (the rows' stroke-count targets
        ``[M, S]``), or empty, ``[M, 0]``."""
        if norm is None:
            z_target = torch.zeros(len(idx), 0) if counts is None else counts
        else:
            params = torch.as_tensor(a.params[idx], dtype=torch.float64)
            z_target = norm.normalise(params).to(torch.float32)
        return cls(
            images=torch.as_tensor(a.images[idx], dtype=torch.float32),
            times=torch.as_tensor(a.times[idx], dtype=torch.float32),
            trajectories=torch.as_tensor(a.trajectories[idx], dtype=torch.float32),
            z_target=z_target,
        )


def stroke_normaliser(a: DigitData, idx: np.ndarray, layout) -> ParamNormaliser:
    """The output normalisation of a stroke model: of DMPs fitted to the strokes of the
    rows ``idx`` of ``a`` (their pen runs), as the cost reads them."""
    from ..nn.strokes import fit_stroke_normaliser, stroke_targets

    pts, present, duration, _ = stroke_targets(
        torch.as_tensor(a.trajectories[idx], dtype=torch.float64),
        torch.as_tensor(a.times[idx], dtype=torch.float64),
        layout,
    )
    if int(present.sum()) < 2:
        raise ValueError(f"need at least 2 training strokes, got {int(present.sum())}")
    return fit_stroke_normaliser(pts[present].numpy(), duration[present].numpy(), layout)


def count_targets(
    a: DigitData, idx: np.ndarray, train_idx: np.ndarray, slots: int, class_weight: float
) -> torch.Tensor:
    """The stroke count's target distributions ``[M, S]`` of the rows ``idx`` (count 1 to
    S; a drawing of more strokes counts as S): each row's own count, mixed with weight
    ``class_weight`` with the distribution of its class's counts among the training rows
    ``train_idx`` (a class with no training row: its own count alone).

    Drawers disagree on how many strokes a character has (two strokes meeting end to end
    look like one): the class's distribution teaches the count most drawers would give,
    where one drawing's own count is noise the image may not show.
    """
    counts = np.array([min(len(a.stroke_spans(int(i))), slots) for i in idx]) - 1
    own = np.eye(slots)[counts]  # [M, S]
    if class_weight == 0:
        return torch.as_tensor(own, dtype=torch.float32)
    labels = np.asarray(a.labels)
    train_counts = np.array([min(len(a.stroke_spans(int(i))), slots) for i in train_idx]) - 1
    hist = {}
    for c in np.unique(labels[train_idx]):
        hist[int(c)] = np.bincount(train_counts[labels[train_idx] == c], minlength=slots)
    mixed = own.copy()
    for r, i in enumerate(idx):
        h = hist.get(int(labels[i]))
        if h is not None:
            mixed[r] = (1 - class_weight) * own[r] + class_weight * h / h.sum()
    return torch.as_tensor(mixed, dtype=torch.float32)


def slots_note(a: DigitData, idx: np.ndarray, slots: int) -> str | None:
    """A one-line note when some of the rows ``idx`` have more strokes than a stroke
    model's ``slots`` (None when none has): how many, the most strokes, what it means and
    what to do. Such a row trains on its first ``slots`` strokes and its count is taught
    as ``slots`` (:func:`count_targets`), so no prediction of it can have its count right.
    Beyond ``MAX_SLOTS`` no model holds them: the note names those drawings."""
    from ..nn.strokes import MAX_SLOTS

    counts = np.array([len(a.stroke_spans(int(i))) for i in idx], dtype=np.int64)
    over = counts > slots
    if not over.any():
        return None
    most = int(counts.max())
    if most <= MAX_SLOTS:
        remedy = f"--set strokes.slots={most} holds them all (at most {MAX_SLOTS})"
    else:
        keep = "" if slots == MAX_SLOTS else f" (--set strokes.slots={MAX_SLOTS})"
        remedy = (
            f"strokes.slots is at most {MAX_SLOTS}, so no stroke model holds "
            f"{_drawings(a, idx[counts > MAX_SLOTS])}, which have more: leave them out of the "
            f"data set or train without their classes (--classes), or learn their first "
            f"{MAX_SLOTS} strokes{keep}"
        )
    return (
        f"note: {int(over.sum())} of {len(counts)} training drawings ({100 * over.mean():.1f} %) "
        f"have more than strokes.slots = {slots} strokes (up to {most}); the model learns "
        f"their first {slots} and cannot read their count right; {remedy}"
    )


def one_dmp_note(a: DigitData, idx: np.ndarray) -> str | None:
    """A one-line note when a model of one DMP per drawing (``strokes.slots`` 0) is to
    learn rows ``idx`` of which some have several strokes (None when none has): a stroke
    model, one DMP per stroke, is the configuration made for them."""
    counts = np.array([len(a.stroke_spans(int(i))) for i in idx], dtype=np.int64)
    several = counts > 1
    if not several.any():
        return None
    return (
        f"note: {int(several.sum())} of {len(counts)} training drawings "
        f"({100 * several.mean():.1f} %) have several strokes (up to {int(counts.max())}), "
        "which this configuration learns as one DMP per drawing with a pen channel "
        "(strokes.slots = 0); a stroke model learns one DMP per stroke: --config omniglot "
        "(docs/TRAINING.md, Stroke models)"
    )


#: Most drawings a note names by their files.
_NAMED = 3


def _drawings(a: DigitData, rows: np.ndarray) -> str:
    """``"the 6 drawings of the class grid (grid/000.csv, grid/001.csv, ...)"``: the rows'
    classes and their files (an imported data set's ``rows.trajectory``; else the rows)."""
    files = (a.meta.get("rows") or {}).get("trajectory") if isinstance(a.meta, dict) else None
    names = (
        list(dict.fromkeys(files[int(r)] for r in rows))  # augmented copies: one file
        if files is not None and len(files) == len(a)
        else [f"row {int(r)}" for r in rows]
    )
    shown = ", ".join(names[:_NAMED]) + (", ..." if len(names) > _NAMED else "")
    classes = sorted({a.label_names[int(a.labels[r])] for r in rows})
    which = "class" if len(classes) == 1 else "classes"
    return f"the {len(names)} drawing(s) of the {which} {', '.join(classes)} ({shown})"


def _split_indices(a: DigitData, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation rows of a stored data set (labels filtered: ``data.digits``
    are digits, or in a data set with class names the classes named after them;
    ``data.classes`` are class names). With ``data.train_on_validation`` the training
    rows include the validation rows."""
    d = cfg.data
    wanted = a.labels_selected(d.digits, d.classes)
    keep = np.ones(len(a.labels), dtype=bool) if wanted is None else np.isin(a.labels, wanted)
    train_idx = np.flatnonzero(keep & (a.split == 0))
    val_idx = np.flatnonzero(keep & (a.split == 1))
    if d.train_on_validation:
        if len(val_idx) == 0:
            raise ConfigError(
                f"data set {d.path} has no validation split to train on (data.train_on_validation)"
            )
        train_idx = np.union1d(train_idx, val_idx)
    elif len(val_idx) == 0:  # no validation split: hold out a share of the training split
        perm = np.random.default_rng(cfg.seed).permutation(train_idx)
        n_val = max(1, int(round(d.val_fraction * len(perm))))
        val_idx, train_idx = np.sort(perm[:n_val]), np.sort(perm[n_val:])
    if len(train_idx) < 2:
        raise _too_few(a.split[keep], cfg, len(train_idx))
    return train_idx, val_idx


def _too_few(split: np.ndarray, cfg: TrainConfig, n_train: int) -> ValueError:
    """The error of too few rows to train on: how many each split of the rows kept
    (``split``) holds, how many of the training split validation took, what to do."""
    d = cfg.data
    counts = ", ".join(f"{name} {int((split == i).sum())}" for name, i in SPLITS.items())
    held = int((split == 0).sum()) - n_train if not d.train_on_validation else 0
    took = (
        f"; with no validation split, {held} of the training split "
        f"{'is' if held == 1 else 'are'} held out to validate on: data.val_fraction = "
        f"{d.val_fraction:g}, at least 1"
        if held > 0
        else ""
    )
    remedy = "import more samples"
    if held > 0:
        remedy += (
            ", or import them with a validation split (--val-fraction) and train on it too "
            "(--set data.train_on_validation=true --set optim.patience=0)"
        )
    elif not d.train_on_validation:
        remedy += (
            ", or train on the validation split too (--set data.train_on_validation=true "
            "--set optim.patience=0)"
        )
    return ValueError(
        f"data set {d.path}"
        + (f" with labels {d.digits}" if d.digits is not None else "")
        + (f" of the classes {d.classes}" if d.classes is not None else "")
        + f" has {n_train} sample(s) to train on ({counts}{took}); need at least 2: {remedy}"
    )


class TrainingData:
    """Training and validation splits of a run, from a file or the generator.

    Attributes
    ----------
    dmp_config : DMPConfig
    image_size : [H, W]
    normaliser : ParamNormaliser
        Given (resume, fine-tuning) or fitted on the training samples.
    fit_arrays : (params [M, P], times [M, T])
        The training samples the normaliser and the parameter weighting are fitted on
        (generator mode: epoch 0's).
    val : Split
    dataset_sha256 : str or None
        Of the data-set file (stored mode).
    class_names : tuple of str or None
        The data set's class names (None: the digits 0-9, as the generator's).
    rows : (train_idx, val_idx) or None
        The data-set file's rows trained and validated on (stored mode; None for the
        generator).
    ink_margin, stroke_width_px : float
        How the images frame their ink and how wide the pen is, for preparing other
        images alike (:func:`img2dmp.data.images.prepare_image`).
    """

    def __init__(self, cfg: TrainConfig, normaliser: ParamNormaliser | None = None):
        self.cfg = cfg
        self.dataset_sha256 = None
        self.class_names: tuple[str, ...] | None = None
        self.rows: tuple[np.ndarray, np.ndarray] | None = None
        self._train: Split | None = None
        self._first: DigitData | None = None
        self._pool: tuple[int, Split] | None = None  # (epoch drawn for, samples)
        if cfg.data.path is not None:
            self._from_file(cfg, normaliser)
        elif cfg.strokes.slots:
            raise ConfigError(
                "a stroke model trains on a data set of paths with their strokes: set "
                "data.path (--data; the generator draws one-stroke digits)"
            )
        else:
            self._from_generator(cfg, normaliser)
        self.unlabelled = self._unlabelled(cfg)
        sample = self.val.images[:_FRAMING_SAMPLES].numpy()
        self.ink_margin = ink_margin(sample)
        self.stroke_width_px = typical_stroke_width(sample)

    def _from_file(self, cfg: TrainConfig, normaliser: ParamNormaliser | None) -> None:
        a = load_dataset(cfg.data.path)
        self.dmp_config = a.dmp_config
        self.image_size = list(a.images.shape[1:])
        self.dataset_sha256 = file_digest(cfg.data.path)
        self.class_names = a.class_names
        train_idx, val_idx = _split_indices(a, cfg)
        self.rows = (train_idx, val_idx)
        self.fit_arrays = (a.params[train_idx], a.times[train_idx])
        layout = cfg.strokes.layout()
        if layout is not None:  # the model's DMPs are the strokes'
            if note := slots_note(a, train_idx, layout.slots):
                print(note, file=sys.stderr)
            self.dmp_config = layout.config
            self.normaliser = normaliser or stroke_normaliser(a, train_idx, layout)
        else:
            if note := one_dmp_note(a, train_idx):
                print(note, file=sys.stderr)
            for rows in (train_idx, val_idx):  # every row a DMP (tau > 0), named if not
                a.dmp_params(rows)
            self.normaliser = normaliser or ParamNormaliser.fit(
                a.params[train_idx], self.dmp_config, cfg.cost.parameter_units
            )
        targets = self.normaliser if layout is None else None
        counts = (None, None)
        if layout is not None:
            w = cfg.strokes.count_class_weight
            counts = [count_targets(a, i, train_idx, layout.slots, w) for i in (train_idx, val_idx)]
        self._train = Split.of(a, train_idx, targets, counts[0])
        self.val = Split.of(a, val_idx, targets, counts[1])

    def _from_generator(self, cfg: TrainConfig, normaliser: ParamNormaliser | None) -> None:
        gen = dict(cfg.data.generator)
        if cfg.data.classes is not None:  # the generator's classes are the digits
            try:
                gen.setdefault("digits", list(digits_named(cfg.data.classes, "data.classes")))
            except ValueError as e:
                raise ConfigError(str(e)) from None
        if cfg.data.digits is not None:
            gen.setdefault("digits", list(cfg.data.digits))
        self._generator = gen
        # Validation: a fixed set from a stream no training epoch draws from.
        val = generate_arrays(gen, cfg.data.val_samples, seed=cfg.seed + 1_000_003)
        self.dmp_config = val.dmp_config
        self.image_size = list(val.images.shape[1:])
        first = self._generated(0)
        self.normaliser = normaliser or ParamNormaliser.fit(
            first.params, self.dmp_config, cfg.cost.parameter_units
        )
        self.fit_arrays = (first.params, first.times)
        self.val = Split.of(val, np.arange(len(val.labels)), self.normaliser)
        self._first = first

    def _unlabelled(self, cfg: TrainConfig) -> torch.Tensor | None:
        """Images without a path for the ink terms (``data.unlabelled_mnist``), [U, H, W]."""
        d = cfg.data
        if d.unlabelled_mnist is None:
            return None
        from ..data.mnist import unlabelled_images

        images = unlabelled_images(d.unlabelled_mnist, d.unlabelled_count, seed=cfg.seed)
        if list(images.shape[1:]) != self.image_size:
            raise ValueError(
                f"data.unlabelled_mnist: MNIST images are {list(images.shape[1:])} pixels, the "
                f"training images {self.image_size}"
            )
        return torch.as_tensor(images, dtype=torch.float32)

    def unlabelled_batch(self, rng: np.random.Generator) -> torch.Tensor | None:
        """A random batch of the unlabelled images (None without them)."""
        if self.unlabelled is None:
            return None
        n = min(self.cfg.data.unlabelled_per_batch, len(self.unlabelled))
        return self.unlabelled[torch.as_tensor(rng.choice(len(self.unlabelled), n, replace=False))]

    def _generated(self, epoch: int) -> DigitData:
        n = self.cfg.data.samples_per_epoch
        return generate_arrays(self._generator, n, seed=self.cfg.seed, epoch=epoch)

    @property
    def samples_per_epoch(self) -> int:
        """How many training samples an epoch goes through."""
        if self.rows is not None:
            return len(self.rows[0])
        return int(self.cfg.data.samples_per_epoch)

    def train_for_epoch(self, epoch: int) -> Split:
        """The training split of ``epoch`` (stored mode: always the same).

        Generator mode: the samples drawn for the last refresh epoch at or before
        ``epoch`` (``data.refresh_epochs``), so that a resumed run sees the same ones.
        """
        if self._train is not None:
            return self._train
        every = int(self.cfg.data.refresh_epochs)
        drawn_at = 0 if every == 0 else epoch - epoch % every
        if self._pool is not None and self._pool[0] == drawn_at:
            return self._pool[1]
        a = self._first if drawn_at == 0 and self._first is not None else self._generated(drawn_at)
        self._first = None
        split = Split.of(a, np.arange(len(a.labels)), self.normaliser)
        self._pool = (drawn_at, split) if every != 1 else None
        return split

    def parameter_weighting(self, stored: dict | None, resumed: bool) -> ParameterWeighting | None:
        """Weights of cost (9): a resumed run's stored ones (a checkpoint without the record
        was trained unweighted), else fitted on :attr:`fit_arrays` if the configuration
        asks for them and the cost has a parameter term."""
        c = self.cfg.cost
        if stored is not None:
            return ParameterWeighting.from_dict(stored)
        if resumed or c.parameter_weighting == "none" or c.name == "trajectory":
            return None
        params, times = self.fit_arrays
        return ParameterWeighting.fit(
            params,
            times,
            self.normaliser,
            self.dmp_config,
            c.parameter_weight_floor,
            kind=c.parameter_weighting,
        )


class Augmenter:
    """Random affine transforms of a training batch (``data.augment``), image and path
    together; refits the cost-(9) targets to the moved paths when the cost uses them."""

    def __init__(self, ranges, normaliser: ParamNormaliser, dmp_config: DMPConfig, refit: bool):
        self.ranges = ranges
        self.normaliser = normaliser
        self.dmp_config = dmp_config
        self.refit = refit

    @classmethod
    def from_config(cls, cfg: TrainConfig, data: TrainingData) -> Augmenter | None:
        ranges = cfg.data.augment_ranges()
        if ranges is None:
            return None
        return cls(ranges, data.normaliser, data.dmp_config, cfg.cost.name != "trajectory")

    def __call__(self, rng, images, times, trajectories, z_target):
        """``(images, trajectories, z_target)`` moved by one fresh transform per sample."""
        from ..data.affine import sample_affine, warp_images, warp_points
        from ..dmp import fit_dmp

        m = torch.as_tensor(sample_affine(rng, len(images), images.shape[-2:], self.ranges))
        images = warp_images(images, m)
        trajectories = warp_points(trajectories, m.to(trajectories.dtype))
        if self.refit:
            fit = fit_dmp(times, trajectories, self.dmp_config)
            z_target = self.normaliser.normalise(fit.params.to_vector()).to(torch.float32)
        return images, trajectories, z_target


__all__ = ["Augmenter", "Split", "TrainingData", "generate_arrays"]
