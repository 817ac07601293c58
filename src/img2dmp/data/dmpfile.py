"""The one DMP file of img2dmp: what ``img2dmp predict --out`` writes (``NAME_dmp.json``),
``img2dmp write --dmp`` executes, :func:`save_dmp_json` / :func:`load_dmp_json` and
``Prediction.save`` write and read. Format ``"img2dmp-dmp"``, version 2 (docs/ROBOT.md)::

    {
      "format": "img2dmp-dmp", "version": 2,
      "dmp_config": {...},           # DMPConfig.to_dict()
      "params": {"w": [[...]], "tau": 3.0, "g": [x, y], "y0": [x, y]},
                                     # ONE DMP: w [N, d], scalar tau (s), g [d], y0 [d]:
                                     # the one `write` executes (rank 1 of "hypotheses")
      "image_size": [H, W],          # the image whose pixels "params" is in
      -- optional, checked when present:
      "frame": "model" | "image",    # which image that is: the model's input (predict)
                                     # or the user's own image
      "hypotheses": [                # ranked, most probable first; [0]["params"] == "params"
        {"rank": 1, "probability": 0.8, "params": {...},
         "params_image": {...},      # the same DMP in the user's image (needs image_frame)
         "trajectory": {"t_s": [T], "xy_model_px": [T][2], "xy_image_px": [T][2],
                        "pen": [T]}}],  # pen only for d = 3; at least one xy
      "image_frame": {"image": "my.png" | null, "image_size": [Hu, Wu],
                      "model_size": [H, W], "image_to_model": [[a, b, c], [d, e, f]],
                      "model_to_image": [[...], [...]]},   # needs "frame": "model"
      "refinement": {"steps": 30}    # gradient steps on the ink (0: the network's DMP)
    }

Positions are pixels (x = column, y = row, the centre of pixel ``[i, j]`` at ``(j, i)``);
a field's name says its frame: ``params``, ``image_size`` and ``xy_model_px`` are in the
model's input (``frame`` "model"), ``params_image`` and ``xy_image_px`` in the user's
image, and ``image_to_model`` maps the second to the first (``[x_m, y_m] = A [x, y] +
b``). With ``d = 3`` the third channel is the pen (1 = down, 0 = up, threshold 0.5).

**Older files** are read and converted to this version in memory:

- *version 1* (``write --dmp`` files before this one: no ``format``, no ``version``):
  the same required fields; converted as they are.
- *the record of ``img2dmp predict`` before version 2* (``"image"``, ``"dmp"``,
  ``"vector"``, ``"trajectory": {"t", "y"}``, optional ``"hypotheses"`` with ``"dmp"``):
  ``dmp`` becomes ``params``, each hypothesis's ``dmp`` its ``params``, ``t``/``y`` become
  ``t_s``/``xy_model_px`` (and ``pen``), ``frame`` is "model". The record has neither DMP
  constants nor image size: the constants are the defaults (N and d from ``w``) with the
  scaling ("goal-start" or "none") whose rollout reproduces the stored trajectories
  (else it is refused), and the model's input size must be given (``image_size=``,
  ``img2dmp write --image-size H W``).

Reading is strict, and every error is one line naming the file, the field and the value:

- every number must be a JSON number: ``"tau": true`` or ``"tau": "2.0"`` is refused,
  as are NaN and Infinity, ragged lists and shapes other than ``w [N, d]``, scalar
  ``tau`` > 0, ``g [d]``, ``y0 [d]``;
- a field missing from ``params`` or ``dmp_config`` is refused, and so is an unknown
  one inside them or inside the optional fields' objects;
- the optional fields agree with each other: ranks 1..K, probabilities in [0, 1] and
  descending, ``hypotheses[0]`` is ``params``, ``params_image`` is ``params`` mapped by
  ``image_frame`` (:func:`img2dmp.dmp.affine.affine_dmp`), the two matrices are inverses;
- **unknown top-level keys are kept as notes** and ignored, so a file may carry
  ``"label"`` or ``"source"``;
- a file larger than ``MAX_FILE_BYTES`` (16 MiB), one that is not UTF-8 text, a DMP of
  more than ``MAX_KERNELS`` kernels or of other than 2 or 3 dimensions are refused
  before any work depends on them. Writers check the same, so what they write reads.
"""

from __future__ import annotations

import json
import math
import numbers
import os
from dataclasses import dataclass, field

import numpy as np

from .._files import atomic_write_text, check_readable, parse_json
from ..dmp import DMPConfig, DMPParams
from ..dmp._numpy_rollout import rollout_numpy
from ..dmp.affine import affine_dmp
from ..dmp.config import MAX_KERNELS
from ..dmp.params import config_of, show_value, strict_numbers
from .images import ImageFrame

FORMAT = "img2dmp-dmp"
VERSION = 2
MAX_FILE_BYTES = 16 << 20
#: Largest magnitude of a weight or a position (pixels) in a DMP file, and longest tau
#: (seconds, 11.6 days): far beyond any image's DMP, well inside float64's range.
MAX_MAGNITUDE = 1e9
MAX_TAU_S = 1e6
#: Samples over [0, tau] at which a DMP read from a file is rolled out to check it is
#: finite.
ROLLOUT_CHECK_SAMPLES = 101
#: Largest side of the frame a DMP is in (``image_size``, pixels): a 24-MP photo's is 6,000.
MAX_IMAGE_SIDE_PX = 100_000
#: Decimals kept of trajectory samples (seconds, pixels); DMP parameters are kept exact.
TRAJECTORY_DECIMALS = 6
#: The top-level fields this version defines; any other top-level key is a note.
REQUIRED = ("dmp_config", "params", "image_size")
OPTIONAL = ("format", "version", "frame", "hypotheses", "image_frame", "refinement")
FRAMES = ("model", "image")
_JSON_TYPES = {dict: "an object", list: "a list", str: "a string", bool: "a boolean"}
# An old predict record's trajectory must be reproduced this closely (pixels, relative
# to the path's size) by the DMP constants the conversion settles on.
_OLD_RECORD_TOLERANCE = 1e-5


def _bad(path, field: str, why: str) -> ValueError:
    return ValueError(f"{path}: field {field!r} {why}")


def _kind(v) -> str:
    return _JSON_TYPES.get(type(v), "a number" if v is not None else "null")


@dataclass(frozen=True)
class DMPFile:
    """A DMP file as read (any version), converted to version 2.

    Attributes
    ----------
    path : str
    config : DMPConfig
    image_size : (H, W)
        Of the frame ``params`` is in.
    hypotheses : list of DMPParams
        Ranked (NumPy float64, batch shape ``[]``); ``hypotheses[0]`` is :attr:`params`.
        A file without the field has the one DMP.
    probabilities : list of float or None
        One per hypothesis (None: the file does not give them).
    frame : str or None
        "model", "image" or None (not said).
    image_frame : ImageFrame or None
        The map between the user's image and the model's input.
    hypotheses_image : list of DMPParams or None
        The hypotheses in the user's image frame.
    document : dict
        The version-2 document (notes included).
    converted_from : str or None
        None for a version-2 file, else what it was ("version 1", "predict record").
    """

    path: str
    config: DMPConfig
    image_size: tuple[int, int]
    hypotheses: list
    probabilities: list | None = None
    frame: str | None = None
    image_frame: ImageFrame | None = None
    hypotheses_image: list | None = None
    document: dict = field(default_factory=dict, repr=False)
    converted_from: str | None = None

    def __repr__(self) -> str:
        k = len(self.hypotheses)
        return (
            f"DMPFile({self.path!r}: {k} DMP{'s' if k > 1 else ''}, N = "
            f"{self.config.n_kernels}, d = {self.config.n_dims}, image_size "
            f"{self.image_size}, frame {self.frame}"
            + (f", converted from {self.converted_from}" if self.converted_from else "")
            + ")"
        )

    @property
    def params(self) -> DMPParams:
        """The DMP ``img2dmp write`` executes: the top hypothesis."""
        return self.hypotheses[0]

    def hypothesis(self, rank: int) -> DMPParams:
        """The hypothesis of ``rank`` (1 = the top one), ``ValueError`` naming the range."""
        k = len(self.hypotheses)
        if isinstance(rank, bool) or not isinstance(rank, numbers.Integral) or not 1 <= rank <= k:
            have = f"{k} hypotheses" if k > 1 else "one DMP"
            raise ValueError(
                f"{self.path}: field 'hypotheses': the file has {have}; the hypothesis must "
                f"be a rank in 1..{k}, got {rank!r}"
            )
        return self.hypotheses[int(rank) - 1]


# --- reading --------------------------------------------------------------------------


def _read_document(path: str) -> dict:
    """The file's top-level JSON object; OSErrors (missing, a directory, no permission)
    pass through, naming the file."""
    check_readable(path, "DMP file")
    with open(path, "rb") as f:
        raw = f.read(MAX_FILE_BYTES + 1)
    if len(raw) > MAX_FILE_BYTES:
        raise ValueError(
            f"{path}: larger than {MAX_FILE_BYTES >> 20} MiB; a DMP file holds a few kB "
            "(is it the right file?)"
        )
    doc = parse_json(raw, path)
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a JSON object at the top level, got {_kind(doc)}")
    return doc


def _read_config(path: str, raw) -> DMPConfig:
    if not isinstance(raw, dict):
        raise _bad(
            path, "dmp_config", f"must be an object (DMPConfig.to_dict()), got {show_value(raw)}"
        )
    missing = [k for k in DMPConfig().to_dict() if k not in raw]
    if missing:  # a default in their place would change the movement without a word
        raise _bad(path, "dmp_config", f"is missing {', '.join(missing)}")
    for k, v in raw.items():  # DMPConfig would read "48" as 48 in places, True as 1
        number = isinstance(v, (int, float)) and not isinstance(v, bool)
        if k != "scaling" and not number and not (k == "beta_z" and v is None):
            raise _bad(path, "dmp_config", f"is invalid: {k} must be a number, got {show_value(v)}")
    try:
        config = DMPConfig.from_dict(raw)
    except (TypeError, ValueError) as e:
        raise _bad(path, "dmp_config", f"is invalid: {e}") from e
    _check_size_of(path, "dmp_config", config.n_kernels, config.n_dims)
    return config


def _check_size_of(path: str, where: str, n_kernels: int, n_dims: int) -> None:
    if n_kernels > MAX_KERNELS:  # (a DMPConfig refuses it too; an old record has none)
        raise _bad(
            path,
            where,
            f"is invalid: n_kernels is {n_kernels}; a DMP may have at most {MAX_KERNELS} kernels",
        )
    if n_dims not in (2, 3):
        raise _bad(
            path,
            where,
            f"is invalid: n_dims must be 2 (x, y) or 3 (x, y, pen) for a DMP to write, "
            f"got {n_dims}",
        )


def _read_params(path: str, where: str, raw, config: DMPConfig) -> DMPParams:
    try:
        params = DMPParams.from_dict(raw, config=config, batch_shape=())
    except ValueError as e:
        raise _bad(path, where, f"is invalid: {e}") from e
    _check_magnitudes(path, where, params, config)
    return params


def _check_magnitudes(path: str, where: str, params: DMPParams, config: DMPConfig) -> None:
    """Refuse numbers no DMP of an image has (beyond :data:`MAX_MAGNITUDE`, a ``tau``
    beyond :data:`MAX_TAU_S`) and a DMP whose movement is not finite: a weight of 1e308
    is a JSON number, but its rollout overflows, and the arm would try to follow it."""
    limits = {"w": MAX_MAGNITUDE, "tau": MAX_TAU_S, "g": MAX_MAGNITUDE, "y0": MAX_MAGNITUDE}
    for name, limit in limits.items():
        a = np.abs(np.asarray(getattr(params, name), dtype=np.float64))
        if a.size and a.max() > limit:
            at = [int(i) for i in np.unravel_index(int(a.argmax()), a.shape)] if a.ndim else ""
            value = float(np.asarray(getattr(params, name), dtype=np.float64).ravel()[a.argmax()])
            raise _bad(
                path,
                f"{where}.{name}",
                f"is invalid: {name}{at} is {value:.6g}, beyond the {limit:g} a DMP may hold",
            )
    tau = float(params.tau)
    t = np.linspace(0.0, tau, ROLLOUT_CHECK_SAMPLES)
    with np.errstate(all="ignore"):  # an overflow is what is being looked for
        y = rollout_numpy(params.to_numpy(), t, config)
    if not np.isfinite(y).all():
        raise _bad(path, where, "is invalid: its movement (the rollout) is not finite")


def _read_size(path: str, where: str, size) -> tuple[int, int]:
    if (
        not isinstance(size, list)
        or len(size) != 2
        or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)
    ):
        raise _bad(path, where, f"must be [H, W], two positive integers, got {show_value(size)}")
    if max(size) > MAX_IMAGE_SIDE_PX:  # 1e9 px made a digit 0.0 mm tall on the paper
        raise _bad(path, where, f"is {show_value(size)}: a side of more than "
                   f"{MAX_IMAGE_SIDE_PX:,} px is no image a DMP was read from")  # fmt: skip
    return size[0], size[1]


def _object(path: str, where: str, raw, allowed: tuple, required: tuple = ()) -> dict:
    """``raw`` as an object with only ``allowed`` keys and every ``required`` one."""
    if not isinstance(raw, dict):
        raise _bad(path, where, f"must be an object, got {show_value(raw)}")
    unknown = sorted(str(k) for k in raw if k not in allowed)
    if unknown:
        raise _bad(path, where, f"has unknown field(s) {unknown} (allowed: {', '.join(allowed)})")
    missing = [k for k in required if k not in raw]
    if missing:
        raise _bad(path, where, f"is missing {', '.join(missing)}")
    return raw


def _check_version(path: str, doc: dict) -> None:
    if doc.get("format") == "img2dmp-page":  # img2dmp.robot.pagefile.FORMAT
        raise ValueError(f"{path}: is a page document (format 'img2dmp-page'), not one DMP: "
                         f"img2dmp write {path} --page writes it")  # fmt: skip
    if doc.get("format") == "img2dmp-strokes":  # img2dmp.predict.STROKES_FORMAT
        raise ValueError(f"{path}: is a stroke model's prediction (format 'img2dmp-strokes'), "
                         "a DMP per stroke, not one DMP: img2dmp write --dmp writes it "
                         "(in Python img2dmp.robot.pagefile.strokes_page_document)")  # fmt: skip
    if doc.get("format") != FORMAT:
        raise _bad(path, "format", f"must be {FORMAT!r}, got {show_value(doc.get('format'))}")
    v = doc.get("version")
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise _bad(path, "version", f"must be a whole number >= 1, got {show_value(v)}")
    if v > VERSION:
        raise _bad(
            path,
            "version",
            f"is {v}: written by a newer img2dmp; this one reads versions up to {VERSION}",
        )


def check_dmp_document(doc: dict, path: str = "DMP document") -> DMPFile:
    """Check a version-2 document (a dict as :func:`json.loads` gives it; the format in
    the module docstring) and return it as a :class:`DMPFile`; ``ValueError`` naming
    ``path``, the field and the value otherwise."""
    if "format" in doc or "version" in doc:  # first: another format is said as such
        _check_version(path, doc)
    for key in REQUIRED:
        if key not in doc:
            raise _bad(path, key, "is missing")
    config = _read_config(path, doc["dmp_config"])
    params = _read_params(path, "params", doc["params"], config)
    size = _read_size(path, "image_size", doc["image_size"])
    frame = doc.get("frame")
    if "frame" in doc and frame not in FRAMES:
        raise _bad(path, "frame", f"must be one of {', '.join(FRAMES)}, got {show_value(frame)}")
    image_frame = None
    if "image_frame" in doc:
        image_frame = _read_image_frame(path, doc["image_frame"], frame, size)
    if "refinement" in doc:
        r = _object(path, "refinement", doc["refinement"], ("steps",), ("steps",))
        if isinstance(r["steps"], bool) or not isinstance(r["steps"], int) or r["steps"] < 0:
            raise _bad(path, "refinement.steps", f"must be a whole number >= 0, got {r['steps']!r}")
    hyps, probs, hyps_image = [params], None, None
    if "hypotheses" in doc:
        hyps, probs, hyps_image = _read_hypotheses(
            path, doc["hypotheses"], params, config, image_frame
        )
    return DMPFile(path, config, size, hyps, probs, frame, image_frame, hyps_image, doc)


def _read_image_frame(path: str, raw, frame, size) -> ImageFrame:
    keys = ("image", "image_size", "model_size", "image_to_model", "model_to_image")
    raw = _object(path, "image_frame", raw, keys, keys[1:])
    if frame != "model":
        raise _bad(
            path,
            "image_frame",
            f'needs "frame": "model" (params in the model\'s input), got frame {show_value(frame)}',
        )
    if raw["image"] is not None and not isinstance(raw["image"], str):
        raise _bad(
            path,
            "image_frame.image",
            f"must be a file name or null, got {show_value(raw['image'])}",
        )
    user = _read_size(path, "image_frame.image_size", raw["image_size"])
    model = _read_size(path, "image_frame.model_size", raw["model_size"])
    if model != size:
        raise _bad(
            path, "image_frame.model_size", f"is {list(model)}, but image_size is {list(size)}"
        )
    mats = {}
    for key in ("image_to_model", "model_to_image"):
        try:
            m = strict_numbers(f"field 'image_frame.{key}'", raw[key])
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
        if m.shape != (2, 3):
            raise _bad(
                path, f"image_frame.{key}", f"must be a 2 x 3 matrix, got shape {list(m.shape)}"
            )
        mats[key] = m
    try:
        image_frame = ImageFrame(mats["image_to_model"], user, model)
    except ValueError as e:
        raise _bad(path, "image_frame.image_to_model", f"is invalid: {e}") from None
    scale = 1.0 + float(np.abs(image_frame.model_to_image).max())
    if np.abs(image_frame.model_to_image - mats["model_to_image"]).max() > 1e-9 * scale:
        raise _bad(path, "image_frame.model_to_image", "is not the inverse of image_to_model")
    return image_frame


def _read_hypotheses(path: str, raw, top: DMPParams, config: DMPConfig, image_frame):
    if not isinstance(raw, list) or not raw:
        raise _bad(path, "hypotheses", f"must be a non-empty list, got {show_value(raw)}")
    keys = ("rank", "probability", "params", "params_image", "trajectory")
    hyps, probs, images = [], [], []
    for i, h in enumerate(raw):
        where = f"hypotheses[{i}]"
        h = _object(path, where, h, keys, ("rank", "probability", "params"))
        if h["rank"] != i + 1 or isinstance(h["rank"], bool):
            raise _bad(
                path,
                f"{where}.rank",
                f"must be {i + 1} (ranked from 1), got {show_value(h['rank'])}",
            )
        p = h["probability"]
        if not (isinstance(p, (int, float)) and not isinstance(p, bool) and 0.0 <= p <= 1.0):
            raise _bad(
                path, f"{where}.probability", f"must be a number in [0, 1], got {show_value(p)}"
            )
        if probs and p > probs[-1] + 1e-12:
            raise _bad(
                path,
                f"{where}.probability",
                f"is {p!r}, above rank {i}'s {probs[-1]!r}: hypotheses are ranked, most "
                "probable first",
            )
        params = _read_params(path, f"{where}.params", h["params"], config)
        if i == 0 and not np.array_equal(params.to_vector(), top.to_vector()):
            raise _bad(
                path,
                "hypotheses[0].params",
                "differs from 'params': the top hypothesis is the DMP written",
            )
        hyps.append(params)
        probs.append(float(p))
        if "params_image" in h:
            images.append(
                _read_params_image(path, where, h["params_image"], params, config, image_frame)
            )
        if "trajectory" in h:
            _read_trajectory(path, f"{where}.trajectory", h["trajectory"], config, image_frame)
    if sum(probs) > 1.0 + 1e-6:
        raise _bad(path, "hypotheses", f"has probabilities summing to {sum(probs)!r} > 1")
    if images and len(images) != len(hyps):
        raise _bad(path, "hypotheses", "give params_image for every hypothesis or for none")
    return hyps, probs, images or None


def _read_params_image(path, where, raw, params, config, image_frame) -> DMPParams:
    if image_frame is None:
        raise _bad(path, f"{where}.params_image", "needs 'image_frame' (the map it was made with)")
    got = _read_params(path, f"{where}.params_image", raw, config)
    want = affine_dmp(params, config, image_frame.model_to_image)
    a, b = got.to_vector(), want.to_vector()
    if np.abs(a - b).max() > 1e-9 * (1.0 + np.abs(b).max()):
        raise _bad(
            path,
            f"{where}.params_image",
            "is not params mapped by image_frame.model_to_image (edited one without the other?)",
        )
    return got


def _read_trajectory(path: str, where: str, raw, config: DMPConfig, image_frame) -> None:
    keys = ("t_s", "xy_model_px", "xy_image_px", "pen")
    raw = _object(path, where, raw, keys, ("t_s",))
    if "xy_model_px" not in raw and "xy_image_px" not in raw:
        raise _bad(path, where, "needs xy_model_px or xy_image_px (the positions)")
    if "xy_image_px" in raw and image_frame is None:
        raise _bad(path, f"{where}.xy_image_px", "needs 'image_frame' (the user's image)")
    if ("pen" in raw) != (config.n_dims == 3):
        raise _bad(
            path,
            f"{where}.pen",
            f"must be given exactly for d = 3 (x, y, pen), d is {config.n_dims}",
        )
    shapes = {}
    for key in raw:
        try:
            shapes[key] = strict_numbers(f"field '{where}.{key}'", raw[key]).shape
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
    n = shapes["t_s"][0] if len(shapes["t_s"]) == 1 else -1
    for key, shape in shapes.items():
        want = (n, 2) if key.startswith("xy") else (n,)
        if n < 1 or shape != want:
            raise _bad(
                path,
                f"{where}.{key}",
                f"has shape {list(shape)}, expected {list(want) if n >= 1 else '[T]'} "
                "(T samples of t_s)",
            )


# --- older files ----------------------------------------------------------------------


def _is_old_predict_record(doc: dict) -> bool:
    return "format" not in doc and "dmp_config" not in doc and "dmp" in doc


def _old_trajectory(path: str, where: str, raw, d: int) -> tuple[np.ndarray, np.ndarray]:
    raw = _object(path, where, raw, ("t", "y"), ("t", "y"))
    try:
        t = strict_numbers(f"field '{where}.t'", raw["t"])
        y = strict_numbers(f"field '{where}.y'", raw["y"])
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    if t.ndim != 1 or y.shape != (len(t), d) or len(t) < 1:
        raise _bad(
            path, where, f"must hold t [T] and y [T, {d}], got {list(t.shape)} and {list(y.shape)}"
        )
    if len(t) > 1 and not (np.diff(t) > 0).all():
        i = int(np.argmax(~(np.diff(t) > 0)))
        raise _bad(path, f"{where}.t", f"must increase strictly, but t[{i + 1}] = "
                   f"{float(t[i + 1])!r} follows t[{i}] = {float(t[i])!r}")  # fmt: skip
    return t, y


def _old_constants(path: str, tracks: list) -> DMPConfig:
    """The default constants with the scaling whose rollout reproduces every stored
    trajectory (``tracks``: (params, t, y))."""
    n, d = tracks[0][0].n_kernels, tracks[0][0].n_dims
    worst = {}
    for scaling in ("goal-start", "none"):
        config = DMPConfig(n_kernels=n, n_dims=d, scaling=scaling)
        err = 0.0
        for params, t, y in tracks:
            p = params.to_numpy().with_config(config)  # each candidate on purpose
            y_hat = rollout_numpy(p, np.asarray(t, dtype=np.float64))
            err = max(err, float(np.abs(y_hat - y).max()) / (1.0 + float(np.abs(y).max())))
        if err <= _OLD_RECORD_TOLERANCE:
            return config
        worst[scaling] = err
    raise _bad(
        path,
        "trajectory",
        "cannot be reproduced by the default DMP constants with either scaling (relative "
        f"errors {', '.join(f'{k}: {v:.2g}' for k, v in worst.items())}): this old predict "
        "record's model used other constants; predict the image again for a version-2 file",
    )


def _from_old_predict_record(path: str, doc: dict, image_size) -> dict:
    """A version-2 document from the record ``img2dmp predict`` wrote before version 2."""
    if image_size is None:
        raise _bad(
            path,
            "image_size",
            "is missing: a prediction record of 'img2dmp predict' from before version 2 "
            "does not store the model's input size; give it (img2dmp write --image-size H W, "
            "load_dmp_json(..., image_size=(H, W))) or predict the image again",
        )
    size = _read_size(path, "image_size", list(image_size))
    try:
        top = DMPParams.from_dict(doc["dmp"])
    except ValueError as e:
        raise _bad(path, "dmp", f"is invalid: {e}") from e
    if top.w.ndim != 2 or top.tau.ndim != 0:
        raise _bad(
            path,
            "dmp",
            f"must hold one DMP (w [N, d], scalar tau), got w of shape {list(top.w.shape)}",
        )
    _check_size_of(path, "dmp", top.n_kernels, top.n_dims)
    d = top.n_dims
    old_hyps = doc.get("hypotheses") or [
        {"rank": 1, "probability": 1.0, "dmp": doc["dmp"], "trajectory": doc.get("trajectory")}
    ]
    if not isinstance(old_hyps, list):
        raise _bad(path, "hypotheses", f"must be a list, got {show_value(old_hyps)}")
    tracks, entries = [], []
    for i, h in enumerate(old_hyps):
        where = f"hypotheses[{i}].trajectory" if "hypotheses" in doc else "trajectory"
        h = _object(
            path,
            f"hypotheses[{i}]",
            h,
            ("rank", "probability", "dmp", "trajectory"),
            ("dmp", "trajectory"),
        )
        try:
            p = DMPParams.from_dict(
                h["dmp"], config=DMPConfig(n_kernels=top.n_kernels, n_dims=d), batch_shape=()
            )
        except ValueError as e:
            raise _bad(path, f"hypotheses[{i}].dmp", f"is invalid: {e}") from e
        t, y = _old_trajectory(path, where, h["trajectory"], d)
        tracks.append((p, t, y))
        rank, prob = h.get("rank", i + 1), h.get("probability", 1.0)
        entry = {"rank": rank, "probability": prob, "params": p.to_dict()}
        entries.append({**entry, "trajectory": trajectory_entry(t, xy_model=y)})
    config = _old_constants(path, tracks)
    notes = {k: v for k, v in doc.items() if k not in ("dmp", "vector", "trajectory", "hypotheses")}
    return {**notes, "format": FORMAT, "version": VERSION, "frame": "model",
            "dmp_config": config.to_dict(), "params": top.to_dict(), "image_size": list(size),
            "hypotheses": entries}  # fmt: skip


def read_dmp_file(path, *, image_size=None) -> DMPFile:
    """Read a DMP file of any version (module docstring), converted to version 2.

    ``image_size`` (H, W) is needed only for the record of ``img2dmp predict`` from before
    version 2, which does not store it; a file that has it is refused with another.

    Raises
    ------
    FileNotFoundError, IsADirectoryError, PermissionError
        If the file cannot be opened (the exception names it).
    ValueError
        If it is not a valid DMP file; the message names the file, the field and the value.
    """
    path = os.fspath(path)
    doc = _read_document(path)
    converted = None
    if _is_old_predict_record(doc):
        doc, converted = _from_old_predict_record(path, doc, image_size), "predict record"
    elif "format" not in doc and "version" not in doc:
        converted = "version 1"
        doc = {"format": FORMAT, "version": VERSION, **doc}
    if image_size is not None and converted != "predict record":
        given = tuple(image_size) if isinstance(image_size, (list, tuple)) else image_size
        have = doc.get("image_size")
        if isinstance(have, list) and tuple(have) != given:
            raise _bad(
                path,
                "image_size",
                f"is {show_value(have)}; the image size given ({show_value(list(given))}) is "
                "for old predict records only, which do not store it",
            )
    f = check_dmp_document(doc, path)
    return DMPFile(**{**f.__dict__, "converted_from": converted})


def load_dmp_json(
    path, *, hypothesis: int = 1, image_size=None
) -> tuple[DMPParams, DMPConfig, tuple[int, int]]:
    """Read the DMP to execute from a DMP file of any version (:func:`read_dmp_file`).

    Parameters
    ----------
    hypothesis : int
        Rank of the hypothesis (1 = the top one, what ``img2dmp write`` executes by
        default; a file without hypotheses has rank 1 only).
    image_size : (H, W), optional
        Only for the record of ``img2dmp predict`` from before version 2 (module docstring).

    Returns
    -------
    params : DMPParams
        NumPy float64, no batch dimensions, in the frame of ``image_size``.
    config : DMPConfig
    image_size : tuple (H, W)
    """
    f = read_dmp_file(path, image_size=image_size)
    return f.hypothesis(hypothesis), f.config, f.image_size


# --- writing --------------------------------------------------------------------------


def box_around_px(xy, size: tuple[int, int]) -> list[int]:
    """Half-open integer pixel bounds ``[x0, y0, x1, y1]`` around the points ``[n, 2]``
    (the centre of pixel ``[i, j]`` at ``(j, i)``), inside an image of ``size`` (H, W)
    and at least one pixel each way (a dot): a page document's ``box_image_px``."""
    xy = np.asarray(xy, dtype=np.float64)
    h, w = size
    lo = np.floor(np.min(xy, axis=0) + 0.5).astype(int)
    hi = np.floor(np.max(xy, axis=0) + 0.5).astype(int) + 1
    x0, y0 = int(np.clip(lo[0], 0, w - 1)), int(np.clip(lo[1], 0, h - 1))
    x1, y1 = int(np.clip(hi[0], x0 + 1, w)), int(np.clip(hi[1], y0 + 1, h))
    return [x0, y0, x1, y1]


def trajectory_entry(times, xy_model=None, xy_image=None) -> dict:
    """The ``trajectory`` of a hypothesis: ``t_s [T]`` and positions ``[T, d]`` in the
    model's and/or the user's frame (a third column is the pen: ``pen [T]``), rounded to
    ``TRAJECTORY_DECIMALS`` decimals."""
    entry = {"t_s": np.round(np.asarray(times, dtype=np.float64), TRAJECTORY_DECIMALS).tolist()}
    pen = None
    for key, y in (("xy_model_px", xy_model), ("xy_image_px", xy_image)):
        if y is not None:
            y = np.asarray(y, dtype=np.float64)
            entry[key] = np.round(y[..., :2], TRAJECTORY_DECIMALS).tolist()
            pen = y[..., 2] if y.shape[-1] > 2 else pen
    if pen is not None:
        entry["pen"] = np.round(pen, TRAJECTORY_DECIMALS).tolist()
    return entry


def _layout(v, indent: int = 0) -> str:
    """JSON text: objects and lists of objects one member a line, lists of numbers on
    one line (a trajectory stays readable and about 12 bytes a number)."""
    pad = " " * (indent + 1)
    if isinstance(v, dict) and v:
        items = [f"{pad}{json.dumps(str(k))}: {_layout(x, indent + 1)}" for k, x in v.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * indent + "}"
    if isinstance(v, list) and any(isinstance(x, dict) for x in v):
        return (
            "[\n" + ",\n".join(pad + _layout(x, indent + 1) for x in v) + "\n" + " " * indent + "]"
        )
    return json.dumps(v, allow_nan=False, separators=(", ", ": "))


def dmp_json_text(doc: dict, path="DMP document") -> str:
    """The text of a checked document (:func:`check_dmp_document`); ``ValueError`` for a
    document that does not check, holds values that are not plain JSON or would be
    larger than ``MAX_FILE_BYTES``."""
    try:
        text = _layout(doc) + "\n"
        plain = json.loads(text)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: extra keys are not plain JSON values: {e}") from e
    check_dmp_document(plain, os.fspath(path))
    if len(text.encode("utf-8")) > MAX_FILE_BYTES:
        raise ValueError(
            f"{path}: the DMP file would be {len(text.encode()) >> 20} MiB, more than the "
            f"{MAX_FILE_BYTES >> 20} MiB a DMP file may have; sample fewer trajectory points"
        )
    return text


def write_dmp_document(path, doc: dict) -> None:
    """Write a version-2 document, checked as :func:`read_dmp_file` checks it before
    anything is written (a refused one leaves an existing file at ``path`` untouched),
    atomically."""
    path = os.fspath(path)
    atomic_write_text(path, dmp_json_text(doc, path))


def dmp_document(
    params: DMPParams, config: DMPConfig | None, image_size, path="DMP document", **extra
) -> dict:
    """The version-2 document of one DMP (``extra``: optional fields and notes; NumPy
    numbers and arrays among them are stored as JSON numbers and lists). ``config``
    None: the constants ``params`` carries; a different one is refused."""
    if not isinstance(params, DMPParams):
        raise TypeError(f"{path}: params must be a DMPParams, got {type(params).__name__}")
    if params.config is None and not isinstance(config, DMPConfig):
        raise TypeError(f"{path}: config must be a DMPConfig, got {type(config).__name__} "
                        "(these parameters carry none)")  # fmt: skip
    try:
        config = config_of(params, config)
    except (TypeError, ValueError) as e:
        raise type(e)(f"{path}: {e}") from None
    p = params.to_numpy()
    if p.batch_shape != ():
        raise ValueError(f"{path}: params must hold one DMP, got batch shape {p.batch_shape}")
    p.validate(config)
    size = list(image_size) if isinstance(image_size, (list, tuple)) else image_size
    if not (
        isinstance(size, list)
        and len(size) == 2
        and all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in size)
        and all(s > 0 for s in size)
    ):
        raise ValueError(f"{path}: image_size must be two positive integers, got {image_size!r}")
    if not all(math.isfinite(float(x)) for x in np.ravel(p.to_vector())):
        raise ValueError(f"{path}: params contain NaN or inf")
    doc = {"format": FORMAT, "version": VERSION, "dmp_config": config.to_dict(),
           "params": p.to_dict(), "image_size": [int(s) for s in size]}  # fmt: skip
    for k, v in extra.items():
        if k in doc:
            raise ValueError(f"{path}: extra key {k!r} would overwrite a format field")
        doc[k] = _plain(v)
    return doc


_PLAIN = (float, int, str, bool, type(None))


def _plain(v):
    """``v`` with NumPy numbers and arrays (in lists and dicts too) as Python ones."""
    if isinstance(v, (np.generic, np.ndarray)):
        return v.tolist()
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):  # a page's paths: many plain numbers, taken as they are
        return [x if type(x) in _PLAIN else _plain(x) for x in v]
    return v


def save_dmp_json(path, params: DMPParams, config: DMPConfig | None, image_size, **extra) -> None:
    """Write one DMP in the format of :func:`load_dmp_json` (version 2), atomically.

    ``config`` None stores the constants ``params`` carries (a prediction's, a fit's);
    one that differs from them is refused (``ValueError``), as the rollouts refuse it.

    ``extra`` keys (JSON-serialisable) are stored alongside: the optional fields of the
    format (e.g. ``frame="image"``), checked as the reader checks them, or notes (e.g.
    ``label=3``). The document is checked as :func:`load_dmp_json` checks it before
    anything is written, so a refused DMP leaves an existing file at ``path`` untouched
    and a written file can always be read back.
    """
    path = os.fspath(path)
    write_dmp_document(path, dmp_document(params, config, image_size, path, **extra))


__all__ = [
    "FORMAT",
    "MAX_FILE_BYTES",
    "MAX_KERNELS",
    "TRAJECTORY_DECIMALS",
    "VERSION",
    "DMPFile",
    "box_around_px",
    "check_dmp_document",
    "dmp_document",
    "dmp_json_text",
    "load_dmp_json",
    "read_dmp_file",
    "save_dmp_json",
    "trajectory_entry",
    "write_dmp_document",
]
