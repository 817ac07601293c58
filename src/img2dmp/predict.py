"""From images to DMPs with a trained network (the inference side of Pahič et al.).

- :func:`load_model` - a trained network, ready to predict: the shipped default model
  (``load_model().predict("digit.png")``), a shipped one by name
  (``load_model("digits-real")``, :mod:`img2dmp.models`), a run directory or checkpoint
  (``load_model("runs/paper")``).
- :class:`Predictor` - a loaded model: :meth:`Predictor.load` (run directory or
  checkpoint), :meth:`~Predictor.predict` (one image: path, PIL image or array of any
  size and polarity, to a :class:`Prediction`), :meth:`~Predictor.predict_batch` (many
  images, read together, to one :class:`Prediction` each), :meth:`~Predictor.predict_images`
  (prepared ``[B, H, W]`` images to :class:`~img2dmp.dmp.DMPParams`),
  :meth:`~Predictor.predict_paths` (image files), :meth:`~Predictor.trajectories`
  (rollout at given or evenly spaced time stamps).
- :class:`Prediction` - the DMP(s) of one image, ranked, with their probabilities and
  trajectories in both frames (the model's input and the user's image), and
  :meth:`~Prediction.save`, which writes the one DMP file (:mod:`img2dmp.data.dmpfile`)
  that ``img2dmp write --dmp`` executes.
- :func:`prepare_image` - bring an arbitrary PNG/JPEG (any size, dark ink on light paper
  or light on dark) to the model's input the way the training images were made
  (defined in :mod:`img2dmp.data.images`, with :func:`prepare_image_framed`,
  :func:`ink_margin`, :func:`stroke_width` and :func:`typical_stroke_width`; still
  importable from here).
- :func:`write_prediction` - ``NAME_dmp.json`` + ``NAME_trajectory.csv`` (+ overlays) for
  one prediction.

**Frames.** The network reads the prepared image (the **model frame**: ``image_size``,
e.g. 40 x 40, the ink cropped, padded to a square with the training images' margin and
resized), so its DMPs and their paths are in those pixels. ``Prediction.frame`` (an
:class:`~img2dmp.data.images.ImageFrame`) is the affine map between the user's own image
(the **image frame**, its own pixels) and the model frame; ``params_image`` and
``path_image`` are the same DMPs and paths in the image frame (exact: see
:mod:`img2dmp.dmp.affine`). Both follow docs/CONTRACTS.md: x = column, y = row, the
centre of pixel ``[i, j]`` at ``(j, i)``.

**Backends.** A loaded model runs on one of two implementations of the same numbers
(``backend``, :data:`BACKENDS`): ``"numpy"`` (:mod:`img2dmp.nn._numpy_net` for the
network, :mod:`img2dmp.nn._refine_numpy` for refinement, :mod:`img2dmp.dmp._numpy_rollout`
for the rollout), which never imports torch (its import alone takes 1.5-3 s, longer than
the rest of a one-image prediction), and ``"torch"`` (:mod:`img2dmp.nn.inference`, the
batched path that evaluation and training's validation use, on any device).
``"auto"`` (the default) takes NumPy on the CPU. They agree to rounding: tests compare
them to 1e-5 of each parameter's spread over the training set (docs/ARCHITECTURE.md).
The two methods that serve evaluation (:meth:`~Predictor.hypothesis_trajectories`,
:meth:`~Predictor.trajectories_for_images`) roll out in torch at float32 time stamps, as
training's validation does, whatever the backend; :attr:`Predictor.model` is the torch
network, built from the same weights when first asked for.
"""

from __future__ import annotations

import numbers
import os
from dataclasses import replace
from pathlib import Path
from typing import Any, Generic, Literal, TypeVar, overload

import numpy as np

from ._files import check_stem
from ._lazy import is_tensor
from .checkpoint import (
    Checkpoint,
    CheckpointError,
    atomic_write_text,
    load_checkpoint,
    load_weights_into,
    read_checkpoint_meta,
    resolve_checkpoint,
)
from .data.dmpfile import (
    box_around_px,
    dmp_document,
    dmp_json_text,
    trajectory_entry,
    write_dmp_document,
)
from .data.images import (  # noqa: F401  (re-exported: their home was this module)
    DEFAULT_MARGIN,
    INK_THRESHOLD,
    ImageFrame,
    _decode,
    _match_stroke_width,
    ink_margin,
    ink_view,
    prepare_image,
    prepare_image_found,
    prepare_image_framed,
    stroke_width,
    typical_stroke_width,
)
from .data.store import DIGIT_NAMES
from .dmp import DMPConfig, DMPParams
from .dmp._numpy_rollout import rollout_numpy
from .dmp.affine import affine_dmp
from .dmp.params import config_of
from .familiar import run_familiar, shipped_familiar
from .models import Reading, ShippedModel, checkpoint_reading, default_model
from .models import resolve as resolve_shipped
from .nn._numpy_net import NumpyNetwork
from .nn._refine_numpy import (
    MAX_REFINE_STEPS,
    RefineOptions,
    refine_numpy,
    refine_strokes_numpy,
)
from .nn._stroke_layout import (
    COUNT_VIEWS,
    MAX_COUNT_VIEWS,
    STROKE_REFINE,
    StrokeLayout,
    character_paths,
    count_probabilities,
    count_views,
    ink_pieces,
    read_strokes,
    split_slots_numpy,
    stroke_params,
)
from .nn.architecture import ModelConfig
from .nn.normalise import ParamNormaliser

#: How a loaded model computes (module docstring, "Backends").
BACKENDS = ("auto", "numpy", "torch")

#: The most DMPs refined in one batch (a stroke model's characters: this many slots).
#: Each is refined on its own, so parts give the numbers of one batch; the work arrays
#: grow with the batch (about 1 MiB a DMP) and parts of 256 were the fastest (RESULTS 5.8).
REFINE_ROWS = 256
#: Instants over a DMP's duration at which refinement compares its path with the ink.
REFINE_POINTS = 100
#: Largest batch the network is run on at once.
MAX_BATCH_SIZE = 1 << 20
#: Most samples of one trajectory (``n_points``, ``img2dmp predict --points``): a record
#: holds them as JSON text, about 60 bytes a sample and hypothesis.
MAX_POINTS = 100_000
#: A prediction is flagged ``off_ink`` when less of its path than this lies on the ink,
#: ``unexplained_ink`` when less of the ink than this is written: both are below the 1st
#: percentile of the recommended model's refined predictions on MNIST validation images
#: (0.805 and 0.856; RESULTS 6.0), so a well-read digit is seldom flagged.
MIN_PATH_ON_INK = 0.8
MIN_INK_WRITTEN = 0.8
#: The pen width assumed when a model did not record its training images' (pixels).
DEFAULT_STROKE_WIDTH_PX = 2.4


#: At most this many images' encoder features are kept from the network's last pass for
#: their familiarity (:meth:`Predictor.familiarity`): a page's characters (at most
#: :data:`img2dmp.data.pages.MAX_CHARACTERS`, 5,000), not a whole evaluation's images.
KEEP_ROWS = 5000


def fit_score(image: np.ndarray, path: np.ndarray, stroke_width_px: float | None = None) -> dict:
    """How well a path ``[T, d]`` explains an image ``[H, W]`` (model frame, ink = 1):
    ``path_on_ink`` (:func:`img2dmp.metrics.on_ink_share`) and ``ink_written``
    (:func:`img2dmp.metrics.ink_written_share` within half the pen width and half a
    pixel of the path)."""
    from .metrics import ink_written_share, on_ink_share

    width = stroke_width_px or DEFAULT_STROKE_WIDTH_PX
    img, p = np.asarray(image)[None], np.asarray(path)[None]
    return {
        "path_on_ink": round(float(on_ink_share(img, p)[0]), 4),
        "ink_written": round(float(ink_written_share(img, p, radius_px=0.5 * width + 0.5)[0]), 4),
    }


#: How much wider than tall one mark must be before predict's count of characters cuts it
#: into touching digits (chosen on MNIST training digits: RESULTS 7.5).
TOUCHING_WIDTH = 1.1


def character_lines(mask) -> tuple[int, int]:
    """``(characters, lines)`` in an ink mask, the characters counted as
    :func:`count_characters` counts a stroke model's (``letters``) and the lines they
    stand in: characters whose heights overlap by half the smaller one share a line (a
    character's pieces side by side do; two rows of writing do not)."""
    from .data.pages import find_characters
    from .page import STROKE_PAGE_CUT, STROKE_PAGE_JOIN

    chars = find_characters(mask, cut=STROKE_PAGE_CUT, join_sides=STROKE_PAGE_JOIN).characters
    tallest = max((c.box[3] - c.box[1] for c in chars), default=0)
    spans = [(c.box[1], c.box[3]) for c in chars if c.box[3] - c.box[1] >= 0.5 * tallest]
    line = list(range(len(spans)))  # union-find over spans that overlap enough

    def root(i: int) -> int:
        while line[i] != i:
            i = line[i]
        return i

    for i, (a0, a1) in enumerate(spans):
        for j in range(i):
            b0, b1 = spans[j]
            if min(a1, b1) - max(a0, b0) >= 0.5 * min(a1 - a0, b1 - b0):
                line[root(i)] = root(j)
    return len(spans), len({root(i) for i in range(len(spans))})


def count_characters(mask, letters: bool = False) -> int:
    """Characters in an ink mask ``bool [H, W]`` at least half as tall as the tallest
    (:func:`img2dmp.data.pages.find_characters`; specks and fragments do not count).
    ``letters``: found as a stroke model's page finds them (no mark cut at its waists,
    pieces side by side joined: :data:`img2dmp.page.STROKE_PAGE_CUT`,
    :data:`~img2dmp.page.STROKE_PAGE_JOIN`), not as digits. Digits: as a page's, cut into
    touching digits at their waists, except that an image of one mark is one digit
    unless it is at least :data:`TOUCHING_WIDTH` times as wide as tall (the cuts part one
    MNIST 4 in seven)."""
    from .data.pages import find_characters

    def tall(chars) -> int:
        tallest = max((c.box[3] - c.box[1] for c in chars), default=0)
        return int(sum(c.box[3] - c.box[1] >= 0.5 * tallest for c in chars))

    if letters:
        from .page import STROKE_PAGE_CUT, STROKE_PAGE_JOIN

        return tall(find_characters(mask, cut=STROKE_PAGE_CUT,
                                    join_sides=STROKE_PAGE_JOIN).characters)  # fmt: skip
    whole = find_characters(mask, cut=False).characters
    if len(whole) == 1:  # one mark: one digit, unless wide enough to be several touching
        x0, y0, x1, y1 = whole[0].box
        if x1 - x0 < TOUCHING_WIDTH * (y1 - y0):
            return 1
    # Several marks: as many as the page's cuts find, and never fewer than the marks
    # (the cuts may take two digits side by side for one).
    return max(tall(whole), tall(find_characters(mask).characters)) if whole else 0


def fit_flags(fit: dict, n_characters: int = 1) -> list[str]:
    """What is wrong with a prediction, from its :func:`fit_score` and the characters its
    image holds (:func:`count_characters`): ``"off_ink"``, ``"unexplained_ink"``
    (thresholds above) and ``"several_characters"``."""
    flags = []
    if fit["path_on_ink"] < MIN_PATH_ON_INK:
        flags.append("off_ink")
    if fit["ink_written"] < MIN_INK_WRITTEN:
        flags.append("unexplained_ink")
    if n_characters >= 2:
        flags.append("several_characters")
    return flags


def _set_familiarity(pred, familiarity, line) -> None:
    """``pred.familiarity`` and ``pred.familiar_line`` (floats or None), and the flag
    ``"unfamiliar"`` added to ``pred.flags`` when the one is below the other."""
    pred.familiarity = None if familiarity is None else float(familiarity)
    pred.familiar_line = None if line is None else float(line)
    if pred.familiarity is not None and pred.familiar_line is not None:
        if pred.familiarity < pred.familiar_line:
            pred.flags.append("unfamiliar")


def _familiarity_entry(pred) -> dict:
    """A document's ``familiarity`` (the image's and the model's line), when the model
    carries one; nothing otherwise."""
    if pred.familiarity is None:
        return {}
    entry = {"value": round(pred.familiarity, 6)}
    if pred.familiar_line is not None:
        entry["line"] = round(pred.familiar_line, 6)
    return {"familiarity": entry}


def check_count(name: str, value, lo: int, hi: int) -> int:
    """``value`` as an int if it is a whole number in ``[lo, hi]``, else ``ValueError``
    naming ``name``, the value and the range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not lo <= value <= hi:
        raise ValueError(f"{name} must be a whole number in [{lo}, {hi}], got {value!r}")
    return int(value)


def _check_levels(x: np.ndarray) -> None:
    """Prepared images hold ink levels in [0, 1] (ink = 1): NaN, inf or 0-255 values are
    no prepared image (1e30 made NaN weights, 255 weights of 1e6)."""
    if not np.isfinite(x).all():
        raise ValueError("images contain NaN or inf")
    if x.size and (float(x.min()) < -1e-3 or float(x.max()) > 1.0 + 1e-3):
        raise ValueError(
            f"images must hold ink levels in [0, 1] (prepared images, ink = 1; "
            f"Predictor.prepare makes them), got values from {float(x.min()):g} to "
            f"{float(x.max()):g}"
        )


def _check_framing(record: dict, image_size) -> None:
    """A checkpoint record's framing of its training images (``ink_margin``,
    ``stroke_width_px``), as :func:`prepare_image` will take them; ``ValueError`` naming
    the field."""
    from .config import show
    from .data.images import _check_preparation

    margin, width = record.get("ink_margin", DEFAULT_MARGIN), record.get("stroke_width_px")
    for key, value in (("ink_margin", margin), ("stroke_width_px", width)):
        given = value is not None or key == "ink_margin"  # no pen width: none recorded
        if given and (isinstance(value, bool) or not isinstance(value, numbers.Real)):
            raise ValueError(f"field {key!r} must be a number, got {show(value)}")
    for key, framing in (
        ("ink_margin", (float(margin), None)),
        ("stroke_width_px", (DEFAULT_MARGIN, float(width) if width else None)),
    ):
        try:
            _check_preparation(image_size, *framing)
        except ValueError as e:
            raise ValueError(f"field {key!r}: {e}") from None


#: What a :class:`Predictor`'s :meth:`~Predictor.predict` gives, for type checkers: a
#: :class:`Prediction` (one DMP per image) or a stroke model's :class:`StrokePrediction`.
PredictionT = TypeVar("PredictionT")


class Predictor(Generic[PredictionT]):
    """A trained network with its output normalisation and DMP constants.

    Attributes
    ----------
    model : EncoderDecoder
        The torch network (built from the NumPy backend's weights when first asked for,
        which imports torch).
    network : NumpyNetwork or None
        The same network in NumPy (the ``"numpy"`` backend), None for ``"torch"``.
    normaliser : ParamNormaliser
    dmp_config : DMPConfig
    image_size : (H, W)
    meta : dict
        The checkpoint's JSON record.
    refine_options : RefineOptions or None
        If set, every prediction is refined on its image (:func:`img2dmp.nn.refine.refine`:
        a few gradient steps that pull the DMP onto the ink near the network's output);
        None (default): the network's output as it is.
    refine_unfamiliar : int or None
        The refinement steps of images the model finds unfamiliar (below the
        :attr:`familiar` line) instead of ``refine_options.steps``; None (default): the
        same steps for every image. Set both with :meth:`refine_with`;
        :meth:`refine_steps_for` gives an image's steps.
    shipped : ShippedModel or None
        The model shipped with img2dmp this is (:mod:`img2dmp.models`: its name, card
        and recommended settings), None for a run directory or checkpoint.
    reading : Reading
        The settings its predictions are best read with (:class:`~img2dmp.models.Reading`):
        a shipped model's card's, else its training configuration's ``reading``
        (without ``refine_unfamiliar`` when it carries no :attr:`familiar`).
        :func:`load_model` and the commands apply them where not told otherwise;
        :meth:`Predictor.load` applies only ``count_views``.
    strokes : StrokeLayout or None
        A stroke model's layout (:mod:`img2dmp.nn.strokes`: a character as up to S
        strokes, each its own DMP); None for one DMP per image. A stroke model's
        :meth:`predict` gives a :class:`StrokePrediction`.
    count_views : int
        How many views of each image a stroke model reads its stroke count from (the
        image and ``count_views - 1`` small affine copies,
        :func:`img2dmp.nn.strokes.count_views`; 1: the image alone): a shipped model's
        recommended ``count_views`` (:attr:`reading`), else
        :data:`~img2dmp.nn.strokes.COUNT_VIEWS`.
    familiar : Familiar or None
        The training drawings' encoder features and the line below which an image is
        unfamiliar (:mod:`img2dmp.familiar`): a shipped model's when it carries them
        (both shipped models do), a run's when ``img2dmp train`` wrote them for the
        checkpoint loaded (:func:`~img2dmp.familiar.run_familiar`), else None; set it
        with :func:`~img2dmp.familiar.fit_familiar`. Predictions then record their
        familiarity and flag ``"unfamiliar"`` below it.

    ``Predictor(model, ...)`` with a torch network computes with torch;
    :meth:`Predictor.load` chooses the backend (module docstring, "Backends").

    For type checkers a ``Predictor[Prediction]`` (``load_model()``,
    ``load_model("digits-real")``) or ``Predictor[StrokePrediction]``
    (``load_model("omniglot-strokes")``); a run directory's is ``Predictor[Any]``.
    """

    def __init__(
        self,
        model,
        normaliser: ParamNormaliser,
        dmp_config: DMPConfig,
        meta: dict,
        refine_options: RefineOptions | None = None,
        shipped: ShippedModel | None = None,
        *,
        network: NumpyNetwork | None = None,
        checkpoint: Checkpoint | None = None,
        strokes: StrokeLayout | None = None,
    ):
        if model is None and (network is None or checkpoint is None):
            raise ValueError("Predictor needs a torch model, or a NumpyNetwork and its checkpoint")
        self._model = model.eval() if model is not None else None
        self.network = network
        self._checkpoint = checkpoint  # the NumPy weights, for the torch network on demand
        self._source = None if checkpoint is None else checkpoint.path  # for repr
        self.normaliser = normaliser
        self.dmp_config = dmp_config
        self.meta = meta
        size = network.image_size if network is not None else model.image_size
        self.image_size = tuple(int(s) for s in size)
        self.refine_options = refine_options
        self.refine_unfamiliar: int | None = None
        self.shipped = shipped
        self.strokes = strokes
        self.reading: Reading = shipped.reading if shipped is not None else checkpoint_reading(meta)
        views = self.reading.count_views
        self.count_views = views if views is not None and strokes is not None else COUNT_VIEWS
        self.familiar = shipped_familiar(shipped) if shipped is not None else None
        self._seen = None  # (images, encoder features) of the network's last batch
        self._familiar_seen = None  # (those features, familiar, their familiarity)

    @property
    def backend(self) -> str:
        """``"numpy"`` or ``"torch"``: what :meth:`predict` and page reading compute with."""
        return "numpy" if self.network is not None else "torch"

    @property
    def model(self):
        """The torch network (``EncoderDecoder``, eval mode)."""
        if self._model is None:
            import torch

            from .nn.model import build_model

            ckpt = self._checkpoint
            state = {k: torch.from_numpy(np.array(v)) for k, v in ckpt.model_state.items()}
            model = build_model(self.network.config)
            load_weights_into(model, Checkpoint(ckpt.path, ckpt.meta, state))
            self._model = model.eval()
        return self._model

    @model.setter
    def model(self, model) -> None:  # a torch network of one's own: torch computes
        self._model, self.network, self._seen = model.eval(), None, None

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        name: str = "best",
        device: str = "cpu",
        backend: str = "auto",
    ) -> Predictor[Any]:
        """Load from a run directory (its ``checkpoints/<name>``), a checkpoint file or
        the name of a shipped model (``"digits-real"``, :mod:`img2dmp.models`; its file's
        SHA-256 checked). No refinement is set (:func:`load_model` applies the
        model's recommended :attr:`reading`); a stroke model's ``count_views`` is its
        reading's.

        ``device``: where the network runs (``"cpu"``, ``"cuda"``; inputs and outputs stay
        on the CPU, :func:`img2dmp.nn.device.place_model`). ``backend``: one of
        :data:`BACKENDS`; ``"auto"`` is NumPy on the CPU, torch elsewhere.

        Raises ``FileNotFoundError`` if nothing is there and :class:`CheckpointError`
        (a ``ValueError``) if the file is corrupt, truncated or of another architecture;
        ``ValueError`` for an unknown backend or NumPy on another device than the CPU.
        """
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        if backend == "numpy" and device != "cpu":
            raise ValueError(f"backend 'numpy' runs on the CPU; device {device!r} needs "
                             "backend 'torch'")  # fmt: skip
        numpy = backend == "numpy" or (backend == "auto" and device == "cpu")
        ckpt = load_checkpoint(path, name, framework="numpy" if numpy else "pt")
        try:
            mcfg = ModelConfig.from_dict(ckpt.meta["model"])
            normaliser = ParamNormaliser.from_dict(ckpt.meta["normaliser"])
            dmp_config = DMPConfig.from_dict(ckpt.meta["dmp_config"])
            strokes = ckpt.meta.get("strokes")
            strokes = StrokeLayout.from_dict(strokes) if strokes is not None else None
            checkpoint_reading(ckpt.meta, "train_config")  # its reading settings, checked
            _check_framing(ckpt.meta, mcfg.image_size)
        except KeyError as e:
            raise CheckpointError(
                f"checkpoint {ckpt.path}: invalid record (field {e.args[0]!r} is missing)"
            ) from e
        except (TypeError, ValueError) as e:
            raise CheckpointError(f"checkpoint {ckpt.path}: invalid record ({e})") from e
        need = dmp_config.n_params if strokes is None else strokes.n_outputs
        if mcfg.n_outputs != need:
            raise CheckpointError(
                f"checkpoint {ckpt.path}: model has {mcfg.n_outputs} outputs but the DMP "
                f"config needs {need}"
                + ("" if strokes is None else f" ({strokes.slots} stroke slots)")
            )
        shipped = resolve_shipped(path)
        if numpy:
            try:
                network = NumpyNetwork(mcfg, ckpt.model_state)
            except ValueError as e:
                raise CheckpointError(f"checkpoint {ckpt.path} was saved from another "
                                      f"architecture: {e}") from e  # fmt: skip
            predictor = cls(None, normaliser, dmp_config, ckpt.meta, shipped=shipped,
                            network=network, checkpoint=ckpt, strokes=strokes)  # fmt: skip
        else:
            from .nn.device import place_model
            from .nn.model import build_model

            model = build_model(mcfg)
            load_weights_into(model, ckpt)
            predictor = cls(place_model(model, device), normaliser, dmp_config, ckpt.meta,
                            shipped=shipped, strokes=strokes)  # fmt: skip
            predictor._source = ckpt.path
        if shipped is None:  # a run's own, drawn by img2dmp train for these weights
            predictor.familiar = run_familiar(ckpt.path)
            if predictor.familiar is None:
                predictor.reading = predictor.reading.without_unfamiliar()
        return predictor

    def refine_with(self, steps: int, unfamiliar: int | None = None) -> None:
        """Refine every prediction with ``steps`` gradient steps on the ink (0: off), with
        the default settings of this kind of model (a stroke model's
        :data:`~img2dmp.nn.strokes.STROKE_REFINE`); an image the model finds unfamiliar
        (below its :attr:`familiar` line) with ``unfamiliar`` steps instead (None: with
        ``steps`` too). ``ValueError`` for steps outside ``[0, MAX_REFINE_STEPS]`` and for
        ``unfamiliar`` on a model without a :attr:`familiar`."""
        steps = check_count("refine", steps, 0, MAX_REFINE_STEPS)
        if unfamiliar is not None:
            unfamiliar = check_count("refine_unfamiliar (--refine-unfamiliar)", unfamiliar, 0,
                                     MAX_REFINE_STEPS)  # fmt: skip
            if self.familiar is None:
                raise ValueError(
                    f"refine_unfamiliar (--refine-unfamiliar) {unfamiliar}: "
                    f"{self._label()} carries no familiarity to tell unfamiliar images by "
                    "(img2dmp train writes one into its run; for a run trained before: "
                    "img2dmp.familiar.write_run_familiar(RUN, DATA))"
                )
        extra = STROKE_REFINE if self.strokes is not None else {}
        self.refine_unfamiliar = None if unfamiliar == steps else unfamiliar
        refining = steps or self.refine_unfamiliar
        self.refine_options = RefineOptions(steps=steps, **extra) if refining else None

    @property
    def refine_steps(self) -> int:
        """The refinement steps of an image the model knows (0: the network's output as it
        is; :attr:`refine_unfamiliar` for the others); :attr:`refine_options` is None
        then."""
        return 0 if self.refine_options is None else int(self.refine_options.steps)

    def refine_steps_for(self, images, batch_size: int = 4096, familiarity=None) -> np.ndarray:
        """The refinement steps of each prepared image ``[B, H, W]``: ``[B]`` ints, those
        of :attr:`refine_options` (0 without refinement), :attr:`refine_unfamiliar` for
        an image below the :attr:`familiar` line (the one the ``"unfamiliar"`` flag
        uses); ``familiarity [B]``: the images' own, when already computed."""
        o = self.refine_options
        if not hasattr(images, "__len__"):
            raise ValueError(f"images must be prepared images [B, H, W], got {images!r:.60}")
        steps = np.full(len(images), 0 if o is None else int(o.steps), dtype=np.int64)
        adaptive = o is not None and self.refine_unfamiliar is not None
        if adaptive and self.familiar is not None and len(images):
            if familiarity is None:
                familiarity = self.familiarity(images, batch_size)
            steps[np.asarray(familiarity) < self.familiar.line] = self.refine_unfamiliar
        return steps

    def _label(self) -> str:
        """``model NAME`` for a shipped model, else ``this model`` (for messages)."""
        return f"model {self.shipped.name}" if self.shipped is not None else "this model"

    def count_with(self, views: int) -> None:
        """Read a stroke model's stroke counts from ``views`` views of each image (the
        image and ``views - 1`` small affine copies; 1: the image alone). ``ValueError``
        for a one-DMP model or ``views`` outside ``[1, MAX_COUNT_VIEWS]``."""
        views = check_count("count_views (--count-views)", views, 1, MAX_COUNT_VIEWS)
        if self.strokes is None:
            raise ValueError(f"count_views (--count-views) {views}: {self._label()} predicts "
                             "one DMP per image, it reads no stroke count")  # fmt: skip
        self.count_views = views

    @property
    def margin(self) -> float:
        """Framing of the training images, used by :func:`prepare_image`."""
        return float(self.meta.get("ink_margin", DEFAULT_MARGIN))

    @property
    def class_names(self) -> tuple[str, ...] | None:
        """The names of the classes the model learnt, as its training data named them
        (None: digits 0-9, or a checkpoint trained before runs recorded them)."""
        names = (self.meta.get("dataset") or {}).get("class_names")
        return tuple(str(n) for n in names) if isinstance(names, list) and names else None

    @property
    def reads_letters(self) -> bool:
        """Whether the model reads characters other than digits (a stroke model, or one
        trained on other classes): a mark is then not cut at its waists into two
        characters, and pieces side by side are joined (:func:`count_characters`,
        :func:`img2dmp.page.read_page`), as letters such as n, m and W need."""
        names = self.class_names
        return self.strokes is not None or (
            names is not None and not set(names) <= set(DIGIT_NAMES)
        )

    @property
    def stroke_width(self) -> float | None:
        """Typical pen width of the training images in pixels (None: not recorded)."""
        w = self.meta.get("stroke_width_px")
        return float(w) if w else None

    def __repr__(self) -> str:
        name = self.shipped.name if self.shipped is not None else self._source or "a network"
        k = self.n_hypotheses
        kind = f"{k} hypothes{'i' if k == 1 else 'e'}s"
        if self.strokes is not None:
            kind = f"stroke model of {self.strokes.slots} slots"
        steps = f"refine {self.refine_steps}"
        if self.refine_unfamiliar is not None:
            steps += f" ({self.refine_unfamiliar} unfamiliar)"
        c = self.dmp_config
        return (
            f"Predictor({name}: {kind}, input {self.image_size[0]} x {self.image_size[1]}, "
            f"{steps}, {self.backend} backend, DMPs N = {c.n_kernels}, d = {c.n_dims}, "
            f"scaling {c.scaling!r})"
        )

    def __reduce__(self):
        raise TypeError(
            "a Predictor is not pickled or copied (it holds a network, compiled kernels and "
            "caches): load one in each process, e.g. img2dmp.load_model(...) in a process "
            "pool's initializer (docs/API.md); its Predictions pickle"
        )

    @property
    def n_hypotheses(self) -> int:
        """K, the DMPs the network proposes per image (1: the paper's network)."""
        if self.network is not None:
            return self.network.n_hypotheses
        return int(getattr(self.model, "n_hypotheses", 1))

    def _check_images(self, images) -> np.ndarray:
        """Prepared images as float32 ``[B, H, W]``, or ``ValueError`` saying what is wrong."""
        if isinstance(images, tuple) and any(isinstance(v, ImageFrame) for v in images):
            raise ValueError("images must be prepared images [B, H, W]; prepare() returns "
                             "(image, frame): give its image, prepare(path)[0][None]")  # fmt: skip
        if is_tensor(images):
            images = images.detach().cpu().float().numpy()
        try:
            x = np.asarray(images, dtype=np.float32)
        except (TypeError, ValueError) as e:
            raise ValueError(f"images must be prepared images [B, H, W] of numbers ({e})") from None
        if x.ndim == 2:
            x = x[None]
        if x.ndim != 3 or tuple(x.shape[1:]) != self.image_size:
            raise ValueError(
                f"images must have shape [B, {self.image_size[0]}, {self.image_size[1]}], "
                f"got {tuple(x.shape)} (use prepare_image for other sizes)"
            )
        _check_levels(x)
        return x

    def _raw_outputs(self, images, batch_size: int):
        """Checked images ``x [B, H, W]`` and the network's outputs for them (NumPy)."""
        check_count("batch_size", batch_size, 1, MAX_BATCH_SIZE)
        x = self._check_images(images)
        if self.network is not None and self.familiar is not None and 0 < len(x) <= KEEP_ROWS:
            # the encoder's features kept for the familiarity of the same images (a copy of
            # them: the caller may change its array)
            parts = [self.network.with_features(x[lo : lo + batch_size])
                     for lo in range(0, len(x), batch_size)]  # fmt: skip
            out = np.concatenate([o for o, _ in parts])
            self._seen = (x.copy(), np.concatenate([f for _, f in parts]))
        elif self.network is not None:
            parts = [self.network(x[lo : lo + batch_size]) for lo in range(0, len(x), batch_size)]
            out = np.concatenate(parts) if parts else self.network(x)  # [B, K (P + 1) | P]
        else:
            import torch

            from .nn.inference import network_outputs

            out = network_outputs(self.model, torch.from_numpy(x), batch_size).numpy()
        return x, out

    def _outputs(self, images, batch_size: int):
        """Checked images ``x [B, H, W]``, the hypotheses ``z [B, K, P]`` (normalised,
        float32) and their scores ``[B, K]``, NumPy arrays from either backend."""
        if self.strokes is not None:
            raise ValueError(
                f"this is a stroke model ({self.strokes.slots} stroke slots): its "
                "predictions are strokes (predict, predict_strokes), not one DMP per image"
            )
        x, out = self._raw_outputs(images, batch_size)
        k = self.n_hypotheses
        if k == 1:
            return x, out[:, None, :], np.zeros((len(out), 1), out.dtype)
        p = out.shape[-1] // k - 1
        return x, out[:, : k * p].reshape(-1, k, p), out[:, k * p :]

    def _refined(self, z: np.ndarray, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """``z [N, P]`` refined on images ``x [N, H, W]``, each with its ``steps [N]``
        (:meth:`refine_steps_for`; unchanged with 0), compared with the ink at 100
        instants over each DMP's own duration; the result in ``z``'s dtype. Each DMP is
        refined on its own, so rows of equal steps go together, at most
        :data:`REFINE_ROWS` at once (the parts give the numbers of one batch, in bounded
        memory)."""
        o = self.refine_options
        if o is None or len(z) == 0 or not steps.any():
            return z
        out = z.copy()
        for n in np.unique(steps[steps > 0]):
            check_count("refine steps (--refine)", int(n), 0, MAX_REFINE_STEPS)
            rows = np.flatnonzero(steps == n)
            parts = [rows[a : a + REFINE_ROWS] for a in range(0, len(rows), REFINE_ROWS)]
            o_n = replace(o, steps=int(n))
            out[rows] = np.concatenate([self._refined_part(z[r], x[r], o_n) for r in parts])
        return out

    def _refined_part(self, z: np.ndarray, x: np.ndarray, o: RefineOptions) -> np.ndarray:
        """At most :data:`REFINE_ROWS` DMPs ``z`` refined on ``x`` with options ``o``."""
        z64 = z.astype(np.float64)
        tau = self.normaliser.denormalise_numpy(z64)[:, self.normaliser.tau_index]
        t = tau[:, None] * np.linspace(0.0, 1.0, REFINE_POINTS)  # [N, T]
        if self.network is not None:
            refined = refine_numpy(z64, x.astype(np.float64), t, self.normaliser,
                                   self.dmp_config, o)  # fmt: skip
        else:
            import torch

            from .nn.refine import refine

            as_t = torch.from_numpy
            refined = refine(as_t(z64), as_t(x), as_t(t), self.normaliser, self.dmp_config, o)
            refined = refined.numpy()
        return refined.astype(z.dtype)

    def _refined_all(self, z: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Every hypothesis ``z [B, K, P]`` refined on its image (see :meth:`_refined`)."""
        b, k, p = z.shape
        steps = np.repeat(self.refine_steps_for(x), k)
        return self._refined(z.reshape(b * k, p), np.repeat(x, k, axis=0), steps).reshape(b, k, p)

    def _top_refined(self, images, batch_size: int) -> np.ndarray:
        """The top hypothesis ``[B, P]`` (normalised) of every image, refined if asked."""
        x, z, logits = self._outputs(images, batch_size)
        top = z[np.arange(len(z)), logits.argmax(axis=1)]  # [B, P]
        return self._refined(top, x, self.refine_steps_for(x, batch_size))

    def predict_normalised(self, images, batch_size: int = 4096):
        """Network output ``[B, P]`` (a torch tensor, normalised units; the top hypothesis
        of a network with several) for prepared images ``[B, H, W]``, refined if asked."""
        import torch

        return torch.from_numpy(self._top_refined(images, batch_size))

    def predict_hypotheses(
        self, images, batch_size: int = 4096, *, refine_top_only: bool = False
    ) -> tuple[DMPParams, np.ndarray]:
        """All K hypotheses for prepared images, ranked by probability (highest first).

        With refinement, every hypothesis is refined on its image, or only the top one
        with ``refine_top_only`` (the one a page's robot writes; a quarter of the work for
        four hypotheses; the others as the network gave them).

        Returns
        -------
        params : DMPParams
            NumPy float64, batch shape ``[B, K]``; ``params[b, 0]`` is the top hypothesis.
        probs : ndarray [B, K]
            Their probabilities (softmax of the scores), descending along K.
        """
        x, z, logits = self._outputs(images, batch_size)
        if refine_top_only and self.refine_options is not None:
            rows, top = np.arange(len(z)), logits.argmax(axis=1)  # [B]
            z = z.copy()
            z[rows, top] = self._refined(z[rows, top], x, self.refine_steps_for(x, batch_size))
        else:
            z = self._refined_all(z, x)  # [B, K, P]
        probs = _softmax(logits.astype(np.float64))  # [B, K]
        order = np.argsort(-probs, axis=1, kind="stable")  # [B, K], highest first
        z = np.take_along_axis(z, order[..., None], axis=1)
        v = self.normaliser.denormalise_numpy(z.astype(np.float64))
        n, d = self.dmp_config.n_kernels, self.dmp_config.n_dims
        params = DMPParams.from_vector(v, n, d, config=self.dmp_config)
        return params, np.take_along_axis(probs, order, axis=1)

    def hypothesis_trajectories(self, images, times, batch_size: int = 4096):
        """Every hypothesis rolled out at time stamps ``[B, T]``, in the network's order:
        ``y [B, K, T, d]`` and ``probs [B, K]`` (NumPy arrays), see
        :func:`img2dmp.nn.hypothesis_trajectories` (the rollout in torch, float32 stamps,
        as training's validation)."""
        if self.strokes is not None:
            return self._stroke_hypotheses(images, times, batch_size)
        import torch

        from .nn.inference import rollout_outputs

        t = torch.as_tensor(np.asarray(times), dtype=torch.float32)
        x, z, logits = self._outputs(images, batch_size)
        z = torch.from_numpy(self._refined_all(z, x))  # unchanged without refinement
        y = rollout_outputs(z, t, self.normaliser, self.dmp_config, batch_size)
        return y.numpy(), _softmax(logits).astype(np.float32)

    def predict_strokes(self, images, batch_size: int = 4096, return_counts: bool = False):
        """A stroke model's strokes of prepared images ``[B, H, W]``: per image the top
        hypothesis' strokes in writing order, (normalised vectors ``[c, P]``, presence
        probabilities ``[c]``) (:func:`img2dmp.nn.strokes.read_strokes`), refined on the
        image if asked (:func:`img2dmp.nn.strokes.refine_strokes` on the torch backend,
        :func:`img2dmp.nn._refine_numpy.refine_strokes_numpy` on NumPy's).

        With ``return_counts`` also the probabilities ``[B, S]`` of 1 to S strokes that
        the count was read from (that hypothesis', averaged over :attr:`count_views`
        views; the count read is the most probable one of at least the image's pieces of
        ink): ``(strokes, count_probabilities)``."""
        if self.strokes is None:
            raise ValueError("predict_strokes needs a stroke model; this one predicts one DMP")
        x, out = self._raw_outputs(images, batch_size)
        steps = self.refine_steps_for(x, batch_size)  # before the views: x's features kept
        counts = self._count_probabilities(x, out, batch_size)  # [B, K, S]
        strokes = list(read_strokes(out, self.strokes, self.n_hypotheses, count_probs=counts,
                                    min_counts=ink_pieces(x)))  # fmt: skip
        o = self.refine_options
        if o is not None and steps.any():
            if self.network is not None:
                refine = refine_strokes_numpy
            else:
                from .nn.strokes import refine_strokes as refine
            n = REFINE_ROWS // self.strokes.slots  # characters: at most REFINE_ROWS strokes
            for k in np.unique(steps[steps > 0]):  # each character is refined on its own
                check_count("refine steps (--refine)", int(k), 0, MAX_REFINE_STEPS)
                rows, o_k = np.flatnonzero(steps == k), replace(o, steps=int(k))
                for part in (rows[a : a + n] for a in range(0, len(rows), n)):
                    done = refine([strokes[i] for i in part], x[part], self.normaliser,
                                  self.strokes, o_k)  # fmt: skip
                    for i, s in zip(part, done, strict=True):
                        strokes[i] = s
        if not return_counts:
            return strokes
        top = split_slots_numpy(out, self.strokes, self.n_hypotheses)[4].argmax(1)  # [B]
        return strokes, counts[np.arange(len(counts)), top]

    def encoder_features(self, images, batch_size: int = 4096) -> np.ndarray:
        """The encoder's features ``[B, F]`` of prepared images ``[B, H, W]`` (what the
        decoder reads; float32), a new array: the caller's to change."""
        features = self._features(images, batch_size)
        kept = self._seen is not None and features is self._seen[1]
        return features.copy() if kept else features

    def _features(self, images, batch_size: int) -> np.ndarray:
        """:meth:`encoder_features`, or the very array kept from the network's last pass
        over the same images (not to be changed: :meth:`familiarity` reads it)."""
        x = np.asarray(images, dtype=np.float32)
        if x.ndim != 3 or x.shape[1:] != self.image_size:
            raise ValueError(f"images must be [B, {self.image_size[0]}, {self.image_size[1]}] "
                             f"prepared images, got shape {x.shape}")  # fmt: skip
        _check_levels(x)
        seen = self._seen
        if seen is not None and seen[0].shape == x.shape and np.array_equal(seen[0], x):
            return seen[1]  # the network read these images last: their features are kept
        if self.network is not None:
            return self.network.features(x)
        import torch

        m, out = self.model, []
        device = next(m.parameters()).device
        with torch.no_grad():
            for a in range(0, len(x), batch_size):
                t = torch.as_tensor(x[a : a + batch_size], device=device)
                out.append(m.encoder(m.input_filter(t)).float().cpu().numpy())
        return np.concatenate(out) if out else np.zeros((0, 0), np.float32)

    def familiarity(self, images, batch_size: int = 4096) -> np.ndarray | None:
        """How familiar prepared images ``[B, H, W]`` are to the model ``[B]``
        (:meth:`Familiar.familiarity <img2dmp.familiar.Familiar.familiarity>`), None when
        the model carries no :attr:`familiar`."""
        if self.familiar is None:
            return None
        features = self._features(images, batch_size)
        known = self._familiar_seen  # the last answer, for the very features kept last
        if known is not None and known[0] is features and known[1] is self.familiar:
            return known[2].copy()
        out = self.familiar.familiarity(features)
        if self._seen is not None and features is self._seen[1]:
            self._familiar_seen = (features, self.familiar, out.copy())
        return out

    def stroke_count_probabilities(self, images, batch_size: int = 4096) -> np.ndarray:
        """A stroke model's probabilities ``[B, K, S]`` of 1 to S strokes per hypothesis
        for prepared images ``[B, H, W]``, averaged over :attr:`count_views` views of each
        (what :meth:`predict_strokes` reads the count from, before the pieces of ink)."""
        if self.strokes is None:
            raise ValueError("stroke counts need a stroke model; this one predicts one DMP")
        x, out = self._raw_outputs(images, batch_size)
        return self._count_probabilities(x, out, batch_size)

    def _count_probabilities(self, x: np.ndarray, out: np.ndarray, batch_size: int):
        """The stroke count's probabilities ``[B, K, S]`` of images ``x`` whose network
        outputs are ``out``, averaged over ``count_views`` views of each image
        (:func:`img2dmp.nn.strokes.count_views`)."""
        views = check_count("count_views (--count-views)", self.count_views, 1, MAX_COUNT_VIEWS)
        logits = [split_slots_numpy(out, self.strokes, self.n_hypotheses)[3]]  # [B, K, S]
        for view in count_views(x, views):
            view_out = self._raw_outputs(view, batch_size)[1]
            logits.append(split_slots_numpy(view_out, self.strokes, self.n_hypotheses)[3])
        return count_probabilities(np.stack(logits))  # [V, B, K, S] -> [B, K, S]

    def stroke_paths(self, images, batch_size: int = 4096, n_per_stroke: int = 40) -> list:
        """Each image's character as one path ``[T_i, 3]`` (x, y, pen; model frame): its
        strokes (:meth:`predict_strokes`) each at ``n_per_stroke`` instants with straight
        pen-up travel between (:func:`img2dmp.nn.strokes.character_paths`)."""
        n_per_stroke = check_count("n_per_stroke", n_per_stroke, 2, MAX_POINTS)
        strokes = self.predict_strokes(images, batch_size)
        return character_paths(strokes, self.normaliser, self.strokes, n_per_stroke)

    def _stroke_hypotheses(self, images, times, batch_size: int):
        """:meth:`hypothesis_trajectories` of a stroke model: each character's path
        brought to the ``T`` of ``times`` by its instants' index (the strokes' own
        timing; pen-up travel straight), as ``[B, 1, T, 3]`` with probability 1."""
        t_len = np.asarray(times).shape[-1]
        paths = self.stroke_paths(images, batch_size)
        y = np.stack([index_resampled(p, t_len) for p in paths]) if paths else None
        if y is None:
            return np.zeros((0, 1, t_len, 3), np.float32), np.zeros((0, 1), np.float32)
        return y[:, None].astype(np.float32), np.ones((len(y), 1), np.float32)

    def predict_images(self, images, batch_size: int = 4096) -> DMPParams:
        """DMPs for prepared images.

        Parameters
        ----------
        images : array float32 [B, H, W] (or [H, W])
            In [0, 1], ink = 1, at the model's ``image_size``.

        Returns
        -------
        DMPParams
            NumPy float64, batch shape ``[B]``.
        """
        z = self._top_refined(images, batch_size)
        v = self.normaliser.denormalise_numpy(z.astype(np.float64))
        n, d = self.dmp_config.n_kernels, self.dmp_config.n_dims
        return DMPParams.from_vector(v, n, d, config=self.dmp_config)

    def predict_paths(
        self, paths, match_stroke_width: bool = True
    ) -> list[tuple[DMPParams, np.ndarray]]:
        """One DMP (batch shape ``[]``) and the prepared image for every image file.

        With ``match_stroke_width`` (and a model that recorded it) the strokes are brought
        to the training images' pen width, see :func:`prepare_image`.
        """
        images = self.prepare_paths(paths, match_stroke_width)
        params = self.predict_images(images)
        return [(params[i], images[i]) for i in range(len(images))]

    def prepare_paths(self, paths, match_stroke_width: bool = True) -> np.ndarray:
        """Image files as the model's input ``[B, H, W]`` (:func:`prepare_image` with the
        training images' framing and, with ``match_stroke_width``, their pen width)."""
        if isinstance(paths, (str, bytes, os.PathLike)) or not len(paths := list(paths)):
            raise ValueError(f"paths must be a non-empty list of image paths, got {paths!r}")
        width = self.stroke_width if match_stroke_width else None
        return np.stack(
            [
                prepare_image(p, self.image_size, margin=self.margin, stroke_width_px=width)
                for p in paths
            ]
        )

    def prepare(
        self, image, match_stroke_width: bool = True, name: str | None = None
    ) -> tuple[np.ndarray, ImageFrame]:
        """One image (a path, a PIL image or an array ``[H, W]``, ``[H, W, 3]`` or
        ``[H, W, 4]`` of any size, either polarity) as the model's input ``[H, W]``, and
        the :class:`ImageFrame` between it and the image (:func:`prepare_image_framed`
        with the training images' framing and, with ``match_stroke_width``, pen width)."""
        width = self.stroke_width if match_stroke_width else None
        return prepare_image_framed(
            image, self.image_size, margin=self.margin, stroke_width_px=width, name=name
        )

    def predict(
        self,
        image,
        *,
        n_points: int = 100,
        match_stroke_width: bool = True,
        name: str | None = None,
        clean: bool = True,
    ) -> PredictionT:
        """The DMP(s) that write the digit in one image: the one call from Python.

        Parameters
        ----------
        image : path, PIL image or array
            A PNG/JPEG file, a ``PIL.Image.Image``, a NumPy array (grey ``[H, W]`` or
            ``[H, W, 1]``, RGB ``[H, W, 3]``, RGBA ``[H, W, 4]``; values in [0, 1], or
            [0, 255] when any is above 1) or a torch tensor (the same, or channels first
            ``[C, H, W]``), any size, dark ink on light paper or light on dark; brought to
            the model's input as the training images were made (:meth:`prepare`).
            Several images: :meth:`predict_batch`.
        n_points : int
            Samples of each trajectory, evenly spaced over its own ``[0, tau]``.
        match_stroke_width : bool
            Bring the strokes to the training images' pen width (default).
        name : str, optional
            Names an array or PIL image in error messages.
        clean : bool
            Separate the ink from its paper (lighting, ruled lines, specks; default). False
            for a clean image, e.g. strokes rendered on a blank canvas as the browser's
            drawings are: the same input for such an image, about 30 ms sooner.

        Returns
        -------
        Prediction or StrokePrediction
            All hypotheses, ranked, in both frames; :meth:`Prediction.save` writes them.
            A stroke model's: its strokes, each a DMP, and the character's path.
        """
        n_points = check_count("n_points (--points)", n_points, 2, MAX_POINTS)
        found = self._found(image, match_stroke_width, name, clean)
        return self._predictions([image], [found], n_points)[0]

    def predict_batch(
        self,
        images,
        *,
        n_points: int = 100,
        match_stroke_width: bool = True,
        clean: bool = True,
        chunk: int = 256,
    ) -> list[PredictionT]:
        """:meth:`predict` for many images at once: one :class:`Prediction` (a stroke
        model's :class:`StrokePrediction`) per image, in order.

        The images are prepared one by one, then read ``chunk`` at a time: one network
        pass and one refinement over the whole part instead of one per image. The
        numbers are those of :meth:`predict` to float32 rounding, as every batch's (a
        few 1e-6 of the weights; refinement can carry it further on a few images:
        docs/API.md), not bit for bit.

        Parameters
        ----------
        images : sequence or array
            A list (or any iterable) of what :meth:`predict` takes (paths, PIL images,
            arrays, tensors), or one array or tensor whose first axis runs over images
            (``[B, H, W]`` grey, ``[B, H, W, 3 | 4]``).
        n_points, match_stroke_width, clean
            As for :meth:`predict`.
        chunk : int
            Images read at once (bounds the memory of a long batch).

        Raises
        ------
        ValueError
            Naming the image at fault (its file, or ``images[i]``); nothing is returned
            then.
        """
        n_points = check_count("n_points (--points)", n_points, 2, MAX_POINTS)
        chunk = check_count("chunk", chunk, 1, MAX_BATCH_SIZE)
        items = _batch_items(images)
        out: list = []
        for lo in range(0, len(items), chunk):
            part = items[lo : lo + chunk]
            found = [
                self._found(im, match_stroke_width, _batch_name(lo + i, im), clean)
                for i, im in enumerate(part)
            ]
            out.extend(self._predictions(part, found, n_points))
        return out

    def _found(self, image, match_stroke_width: bool, name: str | None, clean: bool):
        """``(prepared, frame, mask)`` of one image (:func:`prepare_image_found` with the
        training images' framing and, with ``match_stroke_width``, pen width)."""
        width = self.stroke_width if match_stroke_width else None
        return prepare_image_found(
            image, self.image_size, margin=self.margin, stroke_width_px=width, name=name,
            clean=clean,
        )  # fmt: skip

    def _predictions(self, images: list, found: list, n_points: int) -> list:
        """The predictions of ``images`` (as the user gave them), each prepared as
        ``found`` holds it (:meth:`_found`), read in one batch."""
        prepared = np.stack([f[0] for f in found])  # [B, H, W]
        sources = [str(im) if isinstance(im, (str, os.PathLike)) else None for im in images]
        if self.strokes is not None:
            strokes, counts = self.predict_strokes(prepared, return_counts=True)
            familiarity = self.familiarity(prepared)
            steps = self.refine_steps_for(prepared, familiarity=familiarity)
            out = []
            for i, (image, (_, frame, mask)) in enumerate(zip(images, found, strict=True)):
                n_found, lines = self._characters_and_lines(mask)
                out.append(StrokePrediction(
                    strokes[i], self.normaliser, self.strokes, frame, prepared[i],
                    source=sources[i], refine_steps=int(steps[i]), user_image=image,
                    stroke_width_px=self.stroke_width,
                    n_characters=n_found, n_lines=lines,
                    n_per_stroke=n_points, count_views=self.count_views,
                    count_probabilities=counts[i],
                    familiarity=None if familiarity is None else familiarity[i],
                    familiar_line=None if self.familiar is None else self.familiar.line,
                ))  # fmt: skip
            return out
        params, probs = self.predict_hypotheses(prepared)  # [B, K], ranked
        times, path = self.trajectories(params, n_points=n_points)  # [B, K, T], [B, K, T, d]
        familiarity = self.familiarity(prepared)
        steps = self.refine_steps_for(prepared, familiarity=familiarity)
        return [
            Prediction(
                params=params[i],
                probabilities=probs[i],
                times=times[i],
                path_model=path[i],
                frame=frame,
                dmp_config=self.dmp_config,
                image=prepared[i],
                source=sources[i],
                refine_steps=int(steps[i]),
                user_image=image,
                stroke_width_px=self.stroke_width,
                n_characters=count_characters(mask, letters=self.reads_letters),
                familiarity=None if familiarity is None else familiarity[i],
                familiar_line=None if self.familiar is None else self.familiar.line,
            )
            for i, (image, (_, frame, mask)) in enumerate(zip(images, found, strict=True))
        ]

    def _characters_and_lines(self, mask) -> tuple[int, int]:
        """``(characters, lines)`` of a stroke model's image: the lines are looked for
        only where several characters are found (a second reading of the mask)."""
        found = count_characters(mask, letters=self.reads_letters)
        if found < 2 or not self.reads_letters:
            return found, 1
        return found, character_lines(mask)[1]

    def predict_page(
        self, image, *, n_points: int = 100, match_stroke_width: bool = True, name=None
    ):
        """Every handwritten character of a photo or scan of a page, each a ranked set of
        DMPs where it stands (:func:`img2dmp.page.read_page`): a
        :class:`~img2dmp.page.PagePrediction` in reading order, with fit scores and flags;
        ``.save(dir, stem)`` writes the page document and its picture. A stroke model
        reads each character as its strokes (:class:`StrokePrediction`), and the page
        document lists every stroke as an entry (docs/PAGE.md)."""
        from .page import read_page

        return read_page(self, image, n_points=n_points,
                         match_stroke_width=match_stroke_width, name=name)  # fmt: skip

    def trajectories(self, params: DMPParams, times=None, n_points: int = 100):
        """Roll DMPs out (exact solution, eqs. 3-7): the fast rollout's interpolant in
        NumPy (:func:`img2dmp.dmp._numpy_rollout.rollout_numpy`), on either backend.

        Parameters
        ----------
        params : DMPParams
            Batch shape ``[*batch]``.
        times : array [*batch, T] or [T], optional
            Seconds from the start; default ``n_points`` evenly spaced over ``[0, tau]``.
        n_points : int
            In ``[2, MAX_POINTS]`` (``ValueError`` naming the value otherwise).

        Returns
        -------
        times : ndarray [*batch, T]
        y : ndarray [*batch, T, d]
        """
        if not isinstance(params, DMPParams):
            raise ValueError(f"params must be a DMPParams, got {type(params).__name__}")
        p = params.to_numpy()
        if times is None:
            n_points = check_count("n_points (--points)", n_points, 2, MAX_POINTS)
            t = np.asarray(p.tau, dtype=np.float64)[..., None] * np.linspace(0.0, 1.0, n_points)
        else:
            t = np.asarray(times, dtype=np.float64)
            if t.size > MAX_POINTS * max(1, int(np.prod(p.batch_shape))):
                raise ValueError(
                    f"times holds {t.size:,} stamps, more than {MAX_POINTS:,} per DMP "
                    f"({int(np.prod(p.batch_shape)) or 1} here)"
                )
        y = rollout_numpy(p, t, self.dmp_config)  # either backend: the same to 1e-12 px
        return np.broadcast_to(t, y.shape[:-1]).copy(), y

    def trajectories_for_images(self, images, times, batch_size: int = 4096) -> np.ndarray:
        """The network's DMP trajectories ``[B, T, d]`` at given time stamps ``[B, T]``
        (seconds, each row shifted to start at 0; :func:`img2dmp.nn.dmp_trajectories`,
        training's validation: the rollout in torch at float32 stamps), the top
        hypothesis, refined on its image if asked."""
        import torch

        from .nn.inference import rollout_outputs

        t = torch.as_tensor(np.asarray(times), dtype=torch.float32)  # [B, T], like training
        z = torch.from_numpy(self._top_refined(images, batch_size))  # [B, P]
        y = rollout_outputs(z[:, None], t, self.normaliser, self.dmp_config, batch_size)
        return y[:, 0].numpy()


def _batch_items(images) -> list:
    """The images of :meth:`Predictor.predict_batch`'s ``images``, one list entry each."""
    from PIL import Image

    if isinstance(images, (str, bytes, os.PathLike, Image.Image)):
        raise ValueError(
            f"images must be several images (a list, or an array [B, H, W]), got one "
            f"{type(images).__name__}: predict takes one image"
        )
    if isinstance(images, np.ndarray) or is_tensor(images):
        shape = tuple(images.shape)
        if len(shape) not in (3, 4) or (len(shape) == 3 and shape[-1] in (3, 4)):
            raise ValueError(
                f"an array of images must be [B, H, W] or [B, H, W, C], got shape {shape}"
                + (" (one RGB image? predict takes one image, or give [image])"
                   if len(shape) == 3 else "")
            )  # fmt: skip
        return list(images)
    try:
        return list(images)
    except TypeError:
        raise ValueError(
            f"images must be a list of images or an array [B, H, W], got {type(images).__name__}"
        ) from None


def _batch_name(i: int, image) -> str | None:
    """How image ``i`` of a batch is named in messages: a file by its path."""
    return None if isinstance(image, (str, os.PathLike)) else f"images[{i}]"


def index_resampled(path: np.ndarray, n: int) -> np.ndarray:
    """A path ``[T, 3]`` at ``n`` instants evenly spaced by index (x, y linear, the pen
    of the nearer instant)."""
    u = np.linspace(0.0, len(path) - 1.0, n)
    i0 = np.minimum(np.floor(u).astype(int), len(path) - 1)
    i1 = np.minimum(i0 + 1, len(path) - 1)
    f = (u - i0)[:, None]
    xy = (1 - f) * path[i0, :2] + f * path[i1, :2]
    pen = np.where(f[:, 0] < 0.5, path[i0, 2], path[i1, 2])
    return np.column_stack([xy, pen])


def _softmax(logits: np.ndarray) -> np.ndarray:
    """Softmax along the last axis, shifted by the largest score (no overflow)."""
    e = np.exp(logits - logits.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


class Prediction:
    """The DMP(s) one image shows, as :meth:`Predictor.predict` gives them.

    K hypotheses (1 for the paper's network), ranked by probability; index 0 is the top
    one, the DMP ``img2dmp write`` executes. Positions are pixels (x = column, y = row)
    in the frame the name says: ``*_model`` in the model's input (``frame.model_size``),
    ``*_image`` in the user's own image (``frame.image_size``).

    Attributes
    ----------
    params : DMPParams
        Batch shape ``[K]``, NumPy float64, model frame.
    params_image : DMPParams
        The same DMPs in the image frame (:func:`img2dmp.dmp.affine.affine_dmp`: the
        rollout of ``params_image[k]`` is ``path_image[k]``, exactly).
    probabilities : ndarray [K]
        Descending, summing to 1.
    times : ndarray [K, T]
        Seconds, evenly spaced over each DMP's own duration.
    path_model, path_image : ndarray [K, T, d]
        The rollouts in the model and the image frame (d = 3: the third column is the
        pen, 1 = down, the same in both).
    frame : ImageFrame
        The affine map between the two frames.
    dmp_config : DMPConfig
    image : ndarray float32 [H, W]
        The model's input (the prepared image), ink = 1.
    source : str or None
        The image file, or None for an array or PIL image.
    refine_steps : int
        Gradient steps on the ink each DMP got (0: the network's output).
    user_image : path, PIL image, array or None
        What was predicted from, as given (for pictures on it: :func:`write_prediction`).
    fit : dict
        How well the top hypothesis explains the image (:func:`fit_score`):
        ``path_on_ink`` and ``ink_written``, shares in [0, 1].
    flags : list of str
        What looks wrong (:func:`fit_flags`): ``"off_ink"``, ``"unexplained_ink"``,
        ``"several_characters"``; empty for an image read as one character.
    n_characters : int
        The characters found in the image (1 for a page's character).
    familiarity, familiar_line : float or None
        How familiar the image is to the model (:meth:`Predictor.familiarity`) and the
        line below which it is flagged ``"unfamiliar"`` (:mod:`img2dmp.familiar`); None
        when the model carries no familiarity.
    """

    familiarity: float | None
    familiar_line: float | None

    def __init__(
        self,
        params: DMPParams,
        probabilities,
        times,
        path_model,
        frame: ImageFrame,
        dmp_config: DMPConfig,
        image: np.ndarray,
        source: str | None = None,
        refine_steps: int = 0,
        user_image=None,
        stroke_width_px: float | None = None,
        n_characters: int = 1,
        familiarity: float | None = None,
        familiar_line: float | None = None,
    ):
        self.params = params.to_numpy().with_config(config_of(params, dmp_config))
        if len(self.params.batch_shape) != 1:
            raise ValueError(f"params must have batch shape [K], got {self.params.batch_shape}")
        self.probabilities = np.asarray(probabilities, dtype=np.float64)
        self.times = np.asarray(times, dtype=np.float64)
        self.path_model = np.asarray(path_model, dtype=np.float64)
        self.frame, self.dmp_config, self.image = frame, dmp_config, image
        self.source, self.refine_steps = source, int(refine_steps)
        self.params_image = affine_dmp(self.params, dmp_config, frame.model_to_image)
        self.path_image = frame.to_image(self.path_model)
        self.user_image = user_image
        self.fit = fit_score(image, self.path_model[0], stroke_width_px)
        self.flags = fit_flags(self.fit, n_characters)
        _set_familiarity(self, familiarity, familiar_line)

    @property
    def n_hypotheses(self) -> int:
        return int(self.params.batch_shape[0])

    @property
    def dmp(self) -> DMPParams:
        """The top hypothesis (model frame, batch shape ``[]``): what a robot writes."""
        return self.params[0]

    @property
    def dmp_image(self) -> DMPParams:
        """The top hypothesis in the user's image frame."""
        return self.params_image[0]

    def to_document(self) -> dict:
        """The version-2 DMP file's content (:mod:`img2dmp.data.dmpfile`)."""
        hyps = [
            {
                "rank": k + 1,
                "probability": float(self.probabilities[k]),
                "params": self.params[k].to_dict(),
                "params_image": self.params_image[k].to_dict(),
                "trajectory": trajectory_entry(
                    self.times[k], xy_model=self.path_model[k], xy_image=self.path_image[k]
                ),
            }
            for k in range(self.n_hypotheses)
        ]
        return dmp_document(
            self.dmp,
            self.dmp_config,
            self.frame.model_size,
            frame="model",
            hypotheses=hyps,
            image_frame={"image": self.source, **self.frame.to_dict()},
            refinement={"steps": self.refine_steps},
            fit=self.fit,
            **_familiarity_entry(self),
            flags=self.flags,
        )

    def to_json(self, name: str | os.PathLike = "DMP document") -> str:
        """The DMP file's text, checked as the reader checks it (errors start with
        ``name``, e.g. the file it is for)."""
        return dmp_json_text(self.to_document(), name)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the one DMP file (format ``img2dmp-dmp`` version 2, docs/ROBOT.md) that
        ``img2dmp write --dmp`` and :func:`img2dmp.robot.load_dmp_json` read; atomically,
        checked before anything is written. Returns ``path``."""
        write_dmp_document(path, self.to_document())
        return Path(path)

    def trajectory_csv(self) -> str:
        """``rank,probability,t_s,x_model_px,y_model_px,x_image_px,y_image_px[,pen]``:
        one block of rows per hypothesis, ranked (:func:`trajectory_csv`)."""
        return trajectory_csv(self.probabilities, self.times, self.path_model, self.path_image)

    def __repr__(self) -> str:
        top = self.dmp
        return (
            f"Prediction({self.n_hypotheses} hypothes{'i' if self.n_hypotheses == 1 else 'e'}s, "
            f"top p = {self.probabilities[0]:.3f}, tau = {float(top.tau):.3f} s, "
            f"source {self.source or 'in memory'}, {self.frame!r})"
        )


#: How long the pen-up travel between two strokes takes in a stroke model's character
#: path (s): the model predicts each stroke's duration, not the lifts'.
LIFT_S = 0.2
#: ... drawn as this many points of the path.
LIFT_POINTS = 4
STROKES_FORMAT = "img2dmp-strokes"


class StrokePrediction:
    """The strokes one image shows, as a stroke model's :meth:`Predictor.predict` gives
    them: c strokes in writing order, each its own DMP, and the character's path.

    Attributes
    ----------
    strokes, strokes_image : DMPParams
        Batch shape ``[c]``, NumPy float64, in the model's and the user's image frame
        (:func:`img2dmp.dmp.affine.affine_dmp`); 2-D DMPs of ``dmp_config``.
    presence : ndarray [c]
        How sure the network is of each stroke.
    times : ndarray [T]
        The character path's instants (s): each stroke over its own tau, ``LIFT_S``
        of straight pen-up travel between strokes.
    path_model, path_image : ndarray [1, T, 3]
        The character's path (x, y, pen: 1 on the strokes, 0 on the travel), one
        "hypothesis" as :class:`Prediction` has K; ``probabilities`` is ``[1.0]``.
    frame, image, source, refine_steps, user_image, fit, flags
        As :class:`Prediction`.
    count_views : int
        The views of the image its stroke count was read from
        (:attr:`Predictor.count_views`).
    count_probabilities : ndarray [S] or None
        The probabilities of 1 to S strokes the count was read from (the network's,
        averaged over the views; :meth:`Predictor.predict_strokes`), when given.
    count_probability : float or None
        Of those, the probability of the count read (``n_strokes``): how sure the
        network is of it (RESULTS 8.8 measures how often such counts are right).
    familiarity, familiar_line : float or None
        How familiar the image is to the model (:meth:`Predictor.familiarity`) and the
        line below which it is flagged ``"unfamiliar"`` (:mod:`img2dmp.familiar`); None
        when the model carries no familiarity.
    """

    familiarity: float | None
    familiar_line: float | None

    def __init__(self, strokes, normaliser, layout, frame, image, *, source=None,
                 refine_steps=0, user_image=None, stroke_width_px=None, n_characters=1, n_lines=1,
                 n_per_stroke: int = 100, count_views: int = COUNT_VIEWS,
                 count_probabilities=None, familiarity=None, familiar_line=None):  # fmt: skip
        vectors, presence = strokes
        self.count_views = int(count_views)
        self.count_probabilities = (
            None if count_probabilities is None
            else np.asarray(count_probabilities, dtype=np.float64).reshape(-1)
        )  # fmt: skip
        self.dmp_config, self.frame, self.image = layout.config, frame, image
        self.presence = np.asarray(presence, dtype=np.float64)
        self.strokes = stroke_params(vectors, normaliser).with_config(self.dmp_config)
        self.strokes_image = affine_dmp(self.strokes, self.dmp_config, frame.model_to_image)
        (path,) = character_paths([strokes], normaliser, layout, n_per_stroke, LIFT_POINTS)
        self.times = _character_times(np.asarray(self.strokes.tau), n_per_stroke, LIFT_POINTS)
        self.n_per_stroke = int(n_per_stroke)
        self.path_model = path[None]
        self.path_image = frame.to_image(self.path_model)
        self.probabilities = np.ones(1)
        self.source, self.refine_steps, self.user_image = source, int(refine_steps), user_image
        self.fit = fit_score(image, path, stroke_width_px)
        # A character of c strokes may stand in up to c pieces: more is several
        # characters, and so are lines of writing (two or more, two pieces a line or more:
        # 4 of Omniglot's 2,720 drawings are found so, RESULTS 8.22).
        several = n_characters > self.n_strokes or (n_lines >= 2 and n_characters >= 2 * n_lines)
        self.flags = fit_flags(self.fit, n_characters if several else 1)
        _set_familiarity(self, familiarity, familiar_line)

    n_hypotheses = 1

    @property
    def n_strokes(self) -> int:
        return int(self.strokes.batch_shape[0])

    @property
    def count_probability(self) -> float | None:
        p = self.count_probabilities
        if p is None or not 1 <= self.n_strokes <= len(p):
            return None
        return float(p[self.n_strokes - 1])

    @property
    def dmp(self) -> DMPParams:
        raise ValueError(
            f"a stroke model's prediction is {self.n_strokes} DMPs, one per stroke "
            "(StrokePrediction.strokes), not one DMP"
        )

    def to_document(self) -> dict:
        """The stroke document (format ``img2dmp-strokes``, version 1, docs/ROBOT.md)."""
        starts = _stroke_starts(np.asarray(self.strokes.tau))
        strokes = [
            {"index": j + 1, "presence": round(float(self.presence[j]), 6),
             "t_start_s": round(float(starts[j]), 6), "params": self.strokes[j].to_dict(),
             "params_image": self.strokes_image[j].to_dict()}
            for j in range(self.n_strokes)
        ]  # fmt: skip
        trajectory = trajectory_entry(self.times, xy_model=self.path_model[0],
                                      xy_image=self.path_image[0])  # fmt: skip
        return {
            "format": STROKES_FORMAT, "version": 1, "dmp_config": self.dmp_config.to_dict(),
            "image_size": list(self.frame.model_size), "frame": "model", "strokes": strokes,
            "hypotheses": [{"rank": 1, "probability": 1.0, "trajectory": trajectory}],
            "image_frame": {"image": self.source, **self.frame.to_dict()},
            "refinement": {"steps": self.refine_steps}, "count": self._count_entry(),
            "fit": self.fit, **_familiarity_entry(self), "flags": self.flags,
        }  # fmt: skip

    def _count_entry(self) -> dict:
        """The stroke document's ``count``: the views, and when known the probability of
        the count read and of every count 1 .. S."""
        entry: dict = {"views": self.count_views}
        if self.count_probability is not None:
            entry["probability"] = round(self.count_probability, 6)
            entry["probabilities"] = [round(float(p), 6) for p in self.count_probabilities]
        return entry

    def stroke_rows(self, j: int) -> slice:
        """The rows of stroke ``j`` (0-based) in :attr:`path_model` and :attr:`times`."""
        first = j * (self.n_per_stroke + LIFT_POINTS)
        return slice(first, first + self.n_per_stroke)

    def to_page_document(self) -> dict:
        """The strokes as a page document (format ``img2dmp-page`` version 1,
        docs/PAGE.md) in the model's frame: one entry of ``characters`` per stroke, all
        on line 0 in writing order, each its own 2-D DMP (``"frame": "image"``, the
        model's ``image_size``). What ``img2dmp write`` has the arm write
        (:func:`img2dmp.robot.plan_page`): each stroke pen down, the pen lifted and
        carried to the next one's start."""
        h, w = self.frame.model_size
        entries = [{"index": j, "line": 0, **e} for j, e in enumerate(self.stroke_entries())]
        return {"format": "img2dmp-page", "version": 1, "image": None,
                "image_size_px": [int(w), int(h)], "frame": "model", "source": self.source,
                "lines": [{"index": 0, "characters": list(range(self.n_strokes))}],
                "characters": entries}  # fmt: skip

    def stroke_entries(self, in_image: bool = False) -> list[dict]:
        """One page-document entry per stroke, in writing order, without ``index`` and
        ``line``: its box and path (pen down), times from its start, its 2-D DMP
        (``"frame": "image"``) and ``"stroke"`` (1-based), in the model's frame or
        (``in_image``) the user's image."""
        size = self.frame.image_size if in_image else self.frame.model_size
        path, params = (self.path_image, self.strokes_image) if in_image else (
            self.path_model, self.strokes)  # fmt: skip
        entries = []
        for j in range(self.n_strokes):
            rows = self.stroke_rows(j)
            xy, t = path[0, rows, :2], self.times[rows]
            entries.append({
                "box_image_px": box_around_px(xy, size),
                "path_image_px": np.round(xy, 3).tolist(), "pen": [1] * len(xy),
                "times_s": np.round(t - t[0], 6).tolist(),
                "confidence": round(float(self.presence[j]), 6), "fit": dict(self.fit),
                "flags": [], "dmp": dmp_document(params[j], self.dmp_config, size, frame="image"),
                "stroke": j + 1,
            })  # fmt: skip
        return entries

    def to_json(self, name: str | os.PathLike = "stroke document") -> str:
        """The document's text; ``ValueError`` naming ``name`` for a value JSON cannot
        hold (NaN, infinity)."""
        import json

        try:
            return json.dumps(self.to_document(), indent=1, allow_nan=False) + "\n"
        except ValueError as e:
            raise ValueError(f"{name}: {e}") from None

    def save(self, path: str | os.PathLike) -> Path:
        """Write :meth:`to_json` atomically. Returns ``path``."""
        atomic_write_text(path, self.to_json(path))
        return Path(path)

    def trajectory_csv(self) -> str:
        """The character's path as :meth:`Prediction.trajectory_csv` writes one."""
        return trajectory_csv(self.probabilities, self.times[None], self.path_model,
                              self.path_image)  # fmt: skip

    def __repr__(self) -> str:
        return f"StrokePrediction({self.n_strokes} strokes, fit={self.fit}, flags={self.flags})"


def _stroke_starts(tau: np.ndarray) -> np.ndarray:
    """When each stroke begins (s): after the ones before it and a lift after each."""
    return np.concatenate([[0.0], np.cumsum(tau + LIFT_S)[:-1]])


def _character_times(tau: np.ndarray, n_per_stroke: int, n_travel: int) -> np.ndarray:
    """The instants of :func:`img2dmp.nn.strokes.character_paths`' path (s)."""
    starts, parts = _stroke_starts(tau), []
    for j, (t0, d) in enumerate(zip(starts, tau, strict=True)):
        parts.append(t0 + np.linspace(0.0, d, n_per_stroke))
        if j + 1 < len(tau):
            parts.append(t0 + d + np.linspace(0.0, LIFT_S, n_travel + 2)[1:-1])
    return np.concatenate(parts)


def trajectory_csv(probabilities, times, path_model, path_image) -> str:
    """The trajectory CSV of ``img2dmp predict``:
    ``rank,probability,t_s,x_model_px,y_model_px,x_image_px,y_image_px[,pen]``, one
    block of rows per hypothesis (``probabilities [K]``, ``times [K, T]``, paths
    ``[K, T, d]`` in the model and the image frame; d = 3: the pen)."""
    d = path_model.shape[-1]
    extra = ["pen"] if d == 3 else [f"channel_{k}" for k in range(2, d)]
    cols = ["rank", "probability", "t_s", "x_model_px", "y_model_px", "x_image_px",
            "y_image_px", *extra]  # fmt: skip
    lines = [",".join(cols)]
    for k in range(len(probabilities)):
        head = [str(k + 1), f"{probabilities[k]:.6g}"]
        m, u = path_model[k], path_image[k]
        for i, t in enumerate(times[k]):
            row = [t, m[i, 0], m[i, 1], u[i, 0], u[i, 1], *m[i, 2:]]
            lines.append(",".join(head + [f"{v:.6g}" for v in row]))
    return "\n".join(lines) + "\n"


def reading_for(source, checkpoint: str = "best") -> Reading:
    """The settings the model ``source`` recommends reading its predictions with
    (:attr:`Predictor.reading`, without loading the network): a shipped model's card's,
    else those of the training configuration in the checkpoint (``checkpoint``: which
    one of a run directory), without ``refine_unfamiliar`` when the run carries no
    familiarity for those weights (:func:`img2dmp.familiar.run_familiar`).
    ``FileNotFoundError`` / ``ValueError`` as :func:`img2dmp.checkpoint.read_checkpoint_meta`."""
    shipped = resolve_shipped(source)
    if shipped is not None:
        return shipped.reading
    path = resolve_checkpoint(source, checkpoint)
    reading = checkpoint_reading(read_checkpoint_meta(path), f"checkpoint {path}")
    if reading.refine_unfamiliar is not None and run_familiar(path) is None:
        return reading.without_unfamiliar()
    return reading


# For type checkers: what predict gives, by the shipped model's name (tests/test_api_batch.py
# checks these against the models).
@overload
def load_model(
    path: Literal["digits-real"] | None = None,
    *,
    refine: int | None = None,
    checkpoint: str = "best",
    device: str = "cpu",
    backend: str = "auto",
    refine_unfamiliar: int | None = None,
) -> Predictor[Prediction]: ...
@overload
def load_model(
    path: Literal["omniglot-strokes"],
    *,
    refine: int | None = None,
    checkpoint: str = "best",
    device: str = "cpu",
    backend: str = "auto",
    refine_unfamiliar: int | None = None,
) -> Predictor[StrokePrediction]: ...
@overload
def load_model(
    path: str | os.PathLike | None = None,
    *,
    refine: int | None = None,
    checkpoint: str = "best",
    device: str = "cpu",
    backend: str = "auto",
    refine_unfamiliar: int | None = None,
) -> Predictor[Any]: ...
def load_model(
    path: str | os.PathLike | None = None,
    *,
    refine: int | None = None,
    checkpoint: str = "best",
    device: str = "cpu",
    backend: str = "auto",
    refine_unfamiliar: int | None = None,
) -> Predictor[Any]:
    """A trained network, ready to predict: ``load_model().predict(image)``.

    Parameters
    ----------
    path : str, path-like or None
        The name of a model shipped with img2dmp (``"digits-real"``; ``img2dmp models``
        lists them), a run directory (its ``checkpoints/<checkpoint>``) or a checkpoint
        file. None: the default shipped model (:func:`img2dmp.models.default_model`).
    refine : int or None
        Gradient steps that pull every predicted DMP onto the ink of its image
        (``img2dmp predict --refine``; 0: the network's output as it is). None: what the
        model recommends (:attr:`Predictor.reading`: a shipped model's card, 30 for
        ``digits-real``; a run's training configuration's ``reading``, 0 where it says
        nothing).
    refine_unfamiliar : int or None
        The steps of images the model finds unfamiliar (below its familiarity line,
        :attr:`Predictor.refine_unfamiliar`; ``--refine-unfamiliar``). None: what the
        model recommends when ``refine`` is None too (60 for ``digits-real``, 150 for
        ``omniglot-strokes``), else ``refine``'s.
    checkpoint : str
        Which checkpoint of a run directory ("best" or "last").
    device : str
        Where the network runs ("cpu", "cuda"; :meth:`Predictor.load`).
    backend : {"auto", "numpy", "torch"}
        What computes (module docstring, "Backends"): "auto" is NumPy, without torch, on
        the CPU.

    Raises ``FileNotFoundError`` if nothing is there (an
    :class:`~img2dmp.errors.UnknownModelError`, listing the shipped models, for an
    unknown name), :class:`CheckpointError` (a ``ValueError``) for a corrupt or foreign
    file, :class:`~img2dmp.errors.ShippedModelError` for a shipped file that does not
    match its recorded SHA-256, and ``ValueError`` for a bad ``refine`` or
    ``refine_unfamiliar`` (or the latter for a model without a familiarity).
    """
    if refine is not None:  # before the model is read
        check_count("refine", refine, 0, MAX_REFINE_STEPS)
    if refine_unfamiliar is not None:
        check_count("refine_unfamiliar", refine_unfamiliar, 0, MAX_REFINE_STEPS)
    source = default_model() if path is None else path  # never a folder of its name here
    predictor = Predictor.load(source, checkpoint, device, backend)
    if refine is None:
        refine = predictor.reading.refine
        if refine_unfamiliar is None:
            refine_unfamiliar = predictor.reading.refine_unfamiliar
    predictor.refine_with(int(refine), refine_unfamiliar)
    return predictor


def _overlay(path: Path, image: np.ndarray, paths: np.ndarray, probs, title: str) -> None:
    """A picture of ``paths [K, T, d]`` (ranked) over ``image``; imported here so that
    matplotlib starts only when an overlay is asked for."""
    from .data.plotting import hypotheses_figure, overlay_figure

    if len(paths) > 1:
        hypotheses_figure(path, image, paths, probs, title=title)
    else:
        overlay_figure(path, image[None], None, paths[:1], titles=[title], cell_inches=3.0,
                       labels=("demonstration", "prediction"))  # fmt: skip


def write_prediction(
    out_dir: str | os.PathLike,
    stem: str,
    prediction: Prediction,
    overlay: bool = False,
    text: str | None = None,
) -> list[Path]:
    """Write ``<stem>_dmp.json`` (:meth:`Prediction.save`; ``text``: its text as
    :meth:`Prediction.to_json` gave it, if already made), ``<stem>_trajectory.csv``
    (:meth:`Prediction.trajectory_csv`) and, with ``overlay``, ``<stem>_overlay.png``
    (the model's input with the paths in the model frame) and
    ``<stem>_overlay_image.png`` (the user's own image with the paths in the image frame;
    several hypotheses ranked, the top one bold). Atomic writes."""
    check_stem(stem)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = [out / f"{stem}_dmp.json", out / f"{stem}_trajectory.csv"]
    text = prediction.to_json(written[0]) if text is None else text  # checked first
    atomic_write_text(written[0], text)
    atomic_write_text(written[1], prediction.trajectory_csv())
    if overlay:
        p = prediction.probabilities
        written.append(out / f"{stem}_overlay.png")
        _overlay(written[-1], prediction.image, prediction.path_model, p, f"{stem} (model frame)")
        if prediction.user_image is not None:
            view, scale = ink_view(prediction.user_image, name=stem)
            xy = prediction.path_image.copy()
            xy[..., :2] = (xy[..., :2] + 0.5) * scale - 0.5
            written.append(out / f"{stem}_overlay_image.png")
            _overlay(written[-1], view, xy, p, f"{stem} (your image)")
    return written


__all__ = [
    "DEFAULT_MARGIN",
    "INK_THRESHOLD",
    "MAX_BATCH_SIZE",
    "MAX_POINTS",
    "MAX_REFINE_STEPS",
    "BACKENDS",
    "ImageFrame",
    "Prediction",
    "Predictor",
    "StrokePrediction",
    "check_count",
    "count_characters",
    "fit_flags",
    "fit_score",
    "ink_margin",
    "load_model",
    "prepare_image",
    "prepare_image_framed",
    "reading_for",
    "stroke_width",
    "trajectory_csv",
    "typical_stroke_width",
    "write_prediction",
]
