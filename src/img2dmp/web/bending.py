"""``POST /api/bend``: one hypothesis of a DMP document bent, as ``img2dmp write --goal
... --tempo ...`` bends it (:func:`img2dmp.dmp.bend_dmp`, the one implementation).

The answer holds the bent DMP as a document of its own (one hypothesis, rank 1, in the
frames of the one given), which ``POST /api/write`` takes as it is, its trajectory as
``POST /api/predict`` gives a hypothesis's, and its trajectory CSV. The request carries
the document: the server keeps nothing, and the browser bends the prediction it holds,
never a bent one again (a goal dragged twice is the prediction with the last goal).
"""

from __future__ import annotations

import json

import numpy as np
import torch

from ..data.dmpfile import check_dmp_document, dmp_document, trajectory_entry
from ..dmp import affine_dmp, bend_dmp, rollout
from ..predict import trajectory_csv
from .errors import WebError
from .jobs import read_document
from .models import hypothesis_entry

#: The request's fields that bend, as keywords of :func:`img2dmp.dmp.bend_dmp`.
BEND_FIELDS = ("goal", "start", "shift", "scale", "rotate_deg", "tempo")


def bend_answer(doc, hypothesis: int, options: dict, n_points: int) -> bytes:
    """The JSON body of ``POST /api/bend`` (docs/WEB.md).

    ``options``: the given fields of :data:`BEND_FIELDS` (positions in pixels of the
    document's ``params`` frame). 422 naming the field or value for a document that does
    not check (or is a stroke model's character), a hypothesis it does not have, or a
    bend the DMP cannot take.
    """
    f = read_document(doc, hypothesis, "bending is for one-DMP models")
    config, source = f.config, f.document
    try:
        bent = bend_dmp(f.hypothesis(hypothesis), config, **options)
    except ValueError as e:
        raise WebError(422, str(e)) from None
    t = float(bent.tau) * np.linspace(0.0, 1.0, n_points)  # [T], seconds
    y = rollout(bent.to_torch(), torch.as_tensor(t), config).numpy()  # [T, d], model frame
    frame = f.image_frame
    y_image = None if frame is None else frame.to_image(y)  # [T, d]
    p = 1.0 if f.probabilities is None else f.probabilities[hypothesis - 1]
    note = {"hypothesis": hypothesis, **{k: options[k] for k in BEND_FIELDS if k in options}}
    extra = {k: source[k] for k in ("frame", "image_frame", "refinement") if k in source}
    if f.probabilities is not None:
        entry = {"rank": 1, "probability": p, "params": bent.to_dict()}
        if frame is not None:
            entry["params_image"] = affine_dmp(bent, config, frame.model_to_image).to_dict()
        if f.frame == "model":
            entry["trajectory"] = trajectory_entry(t, xy_model=y, xy_image=y_image)
        extra["hypotheses"] = [entry]
    document = dmp_document(bent, config, f.image_size, "dmp", bent=note, **extra)
    try:  # as POST /api/write and img2dmp write --dmp will read it
        check_dmp_document(json.loads(json.dumps(document)), "the bent DMP")
    except ValueError as e:
        raise WebError(422, str(e)) from None
    answer = {
        "dmp": document,
        "hypothesis": hypothesis_entry(1, p, bent.tau, t, y, y_image),
        "csv": None if y_image is None else trajectory_csv([p], t[None], y[None], y_image[None]),
        "bent": note,
    }
    return json.dumps(answer, allow_nan=False, separators=(",", ":")).encode("utf-8")


__all__ = ["BEND_FIELDS", "bend_answer"]
