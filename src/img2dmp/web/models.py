"""The trained networks a server answers with: loaded once, one lock each.

A model's id is its run directory's name, or the parent's name for a folder called
``run`` (``out/demo/run`` is ``demo``); a second model of the same name gets ``-2``.
:func:`prediction_answer` is the JSON body of ``POST /api/predict`` (docs/WEB.md): a
one-DMP model's K ranked hypotheses, or a stroke model's character (one hypothesis, the
whole path with the pen lifted between strokes, and each stroke's DMP:
:class:`~img2dmp.predict.StrokePrediction`).
"""

from __future__ import annotations

import base64
import json
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..data.dmpfile import TRAJECTORY_DECIMALS
from ..models import ShippedModel
from ..predict import Prediction, Predictor, StrokePrediction, load_model
from .strokes import grey_png


@dataclass
class LoadedModel:
    """One network the server answers with.

    Attributes
    ----------
    id : str
        What ``"model"`` in a request names.
    path : str
        The run directory or checkpoint, as given.
    predictor : Predictor
    lock : threading.Lock
        Held while the network runs: one prediction at a time per model.
    """

    id: str
    path: str
    predictor: Predictor
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @property
    def stroke_slots(self) -> int | None:
        """S, the strokes a stroke model can read in a character; None for a one-DMP
        model."""
        strokes = getattr(self.predictor, "strokes", None)
        return None if strokes is None else int(strokes.slots)

    def describe(self) -> dict:
        """The model's entry in ``GET /api/models``: ``kind`` ``"dmp"`` (one DMP per
        hypothesis) or ``"strokes"`` (a character as up to ``stroke_slots`` DMPs)."""
        slots = self.stroke_slots
        return {
            "id": self.id,
            "path": self.path,
            "kind": "dmp" if slots is None else "strokes",
            "stroke_slots": slots,
            "n_hypotheses": self.predictor.n_hypotheses,
            "image_size": list(self.predictor.image_size),
        }


def model_id(path: str | os.PathLike) -> str:
    """The id of a run directory or checkpoint: its name (without a file's suffix), or
    the parent's name for a folder called ``run``."""
    p = Path(os.path.abspath(path))
    if p.suffix and not p.is_dir():
        p = p.parent.parent if p.parent.name == "checkpoints" else p.with_suffix("")
    return p.parent.name if p.name == "run" and p.parent.name else p.name


def load_models(sources, refine: int | None = None,
                refine_unfamiliar: int | None = None) -> dict[str, LoadedModel]:  # fmt: skip
    """Every model of ``sources`` (shipped models' names, paths, or ``(id, Predictor)``
    pairs), in order, by id; those loaded by name or path refine their predictions with
    ``refine`` steps, those they find unfamiliar with ``refine_unfamiliar`` (``img2dmp
    serve --refine``, ``--refine-unfamiliar``; None: as the model recommends, a shipped
    model's card or a run's reading, :func:`img2dmp.predict.load_model`).

    Raises ``FileNotFoundError`` or ``ValueError`` (from :func:`img2dmp.predict.load_model`)
    naming a path that holds no model.
    """
    models: dict[str, LoadedModel] = {}
    for source in sources:
        if isinstance(source, tuple):
            name, predictor = source
            path = str(name)
        elif isinstance(source, ShippedModel):  # the default: by itself, never a folder here
            name = path = source.name
            predictor = load_model(source, refine=refine, refine_unfamiliar=refine_unfamiliar)
        else:
            name, path = model_id(source), os.fspath(source)
            predictor = load_model(source, refine=refine, refine_unfamiliar=refine_unfamiliar)
        unique, n = name, 1
        while unique in models:
            n += 1
            unique = f"{name}-{n}"
        models[unique] = LoadedModel(unique, path, predictor)
    return models


def _rounded(a: np.ndarray) -> list:
    return np.round(np.asarray(a, dtype=np.float64), TRAJECTORY_DECIMALS).tolist()


def png_data_url(ink: np.ndarray) -> str:
    """``data:image/png;base64,...`` of ``ink [H, W]`` (ink = 1) as dark ink on white."""
    grey = np.round(255.0 * (1.0 - np.clip(np.asarray(ink, dtype=np.float64), 0.0, 1.0)))
    return "data:image/png;base64," + base64.b64encode(grey_png(grey)).decode("ascii")


def hypothesis_entry(rank: int, probability: float, tau_s: float, times, path_model,
                     path_image) -> dict:  # fmt: skip
    """One entry of ``"hypotheses"`` in ``POST /api/predict``'s answer: ``times [T]``,
    paths ``[T, d]`` in the model and the image frame (``path_image`` None: null)."""
    d = path_model.shape[-1]
    return {
        "rank": int(rank),
        "probability": float(probability),
        "tau_s": float(tau_s),
        "t": _rounded(times),
        "model": _rounded(path_model[:, :2]),
        "image": None if path_image is None else _rounded(path_image[:, :2]),
        "pen": _rounded(path_model[:, 2]) if d == 3 else None,
    }


def _hypotheses(pred: Prediction) -> list[dict]:
    return [
        hypothesis_entry(
            k + 1,
            pred.probabilities[k],
            pred.params[k].tau,
            pred.times[k],
            pred.path_model[k],
            pred.path_image[k],
        )  # fmt: skip
        for k in range(pred.n_hypotheses)
    ]


def _stroke_hypotheses(pred: StrokePrediction, document: dict) -> list[dict]:
    """A stroke model's one "hypothesis": the character's whole path (pen 1 on the
    strokes, 0 on the travel between) and ``"strokes"``, each stroke's entry of the
    stroke document (``index``, ``presence``, ``t_start_s``, ``params``,
    ``params_image``) with its ``tau_s`` and ``rows``, its first and last sample in the
    path."""
    entry = hypothesis_entry(1, 1.0, pred.times[-1], pred.times, pred.path_model[0],
                             pred.path_image[0])  # fmt: skip
    rows = [pred.stroke_rows(j) for j in range(pred.n_strokes)]
    entry["strokes"] = [
        {**s, "tau_s": float(pred.strokes.tau[j]), "rows": [r.start, r.stop - 1]}
        for j, (s, r) in enumerate(zip(document["strokes"], rows, strict=True))
    ]
    return [entry]


def warm_up(model: LoadedModel) -> None:
    """One prediction of a drawn "1" and one page of two, so that the first request does
    not pay for the caches (numba's compiled rollout, the DMP response table, the page
    reading's first run)."""
    image = np.full((64, 64), 255, np.uint8)
    image[12:52, 29:35] = 0
    predict_with(model, image, 100, "warm-up")
    with model.lock:
        model.predictor.predict_page(np.tile(image, (1, 2)), name="warm-up page")


def predict_with(model: LoadedModel, image, n_points: int, name: str,
                 clean: bool = True) -> Prediction | StrokePrediction:  # fmt: skip
    """``model``'s prediction for ``image`` (array or PIL image), one at a time per model
    (a stroke model's: ``n_points`` samples per stroke); ``clean=False`` for strokes
    rendered on a blank canvas (no paper to separate the ink from).

    Raises ``ValueError`` for an image the library refuses (e.g. one without ink).
    """
    with model.lock:
        return model.predictor.predict(image, n_points=n_points, name=name, clean=clean)


def prediction_answer(model: LoadedModel, pred: Prediction | StrokePrediction,
                      elapsed_ms: float) -> bytes:  # fmt: skip
    """The JSON body of ``POST /api/predict`` for one prediction (docs/WEB.md); a stroke
    model's adds ``n_strokes`` and ``strokes_page``, the page document of its strokes
    that ``POST /api/write`` takes (:meth:`StrokePrediction.to_page_document`)."""
    document = pred.to_document()
    strokes = isinstance(pred, StrokePrediction)
    answer = {
        "model": model.id,
        "kind": "strokes" if strokes else "dmp",
        "elapsed_ms": round(float(elapsed_ms), 3),
        "model_size": list(pred.frame.model_size),
        "image_size": list(pred.frame.image_size),
        "input_image": png_data_url(pred.image),
        "hypotheses": _stroke_hypotheses(pred, document) if strokes else _hypotheses(pred),
        "fit": dict(pred.fit),
        "flags": list(pred.flags),
        "dmp": document,
        "csv": pred.trajectory_csv(),
    }
    if strokes:
        answer.update(n_strokes=pred.n_strokes, strokes_page=pred.to_page_document())
    return json.dumps(answer, allow_nan=False, separators=(",", ":")).encode("utf-8")


__all__ = [
    "LoadedModel",
    "hypothesis_entry",
    "load_models",
    "model_id",
    "png_data_url",
    "predict_with",
    "prediction_answer",
    "warm_up",
]
