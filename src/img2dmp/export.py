"""A trained network as ONNX, for a robot computer without torch (``img2dmp export``).

:func:`export_onnx` writes the network **with its output normalisation** as one ONNX graph
(opset :data:`OPSET`), so that what comes out are DMP parameters in physical units, and
checks the graph with onnxruntime against torch before anything is written.

The graph::

    input   images       float32 [B, H, W]   prepared images in the model's frame
    output  dmp          float64 [B, K, P]   DMP parameter vectors, physical units, ranked
    output  probability  float64 [B, K]      each hypothesis' probability, descending

- ``images``: what :meth:`img2dmp.predict.Predictor.prepare_paths` gives (values in
  [0, 1], ink = 1, background = 0; the ink's box padded to a square with the training
  images' margin and resized to H x W, strokes brought to their pen width). ``B`` is free.
- ``dmp[b, k]``: hypothesis k of image b as the flat vector of eq. (8)
  (:class:`img2dmp.dmp.DMPParams`): ``w[0, 0] .. w[N-1, 0], w[0, 1] .. w[N-1, 1], ...,
  tau, g[0] .. g[d-1], y0[0] .. y0[d-1]``, P = N d + 1 + 2 d (55 for N = 25, d = 2).
  Positions g and y0 are pixels of the model's input frame (x = column, y = row, the
  centre of pixel [i, j] at (x = j, y = i)), tau is seconds, the weights are those of the
  forcing term with the DMP constants of ``dmp_config``. K = ``model.hypotheses`` (1 for
  the paper's network), ranked by probability: ``dmp[:, 0]`` is the hypothesis that
  ``img2dmp predict`` reports first and ``img2dmp write`` writes.
- ``probability``: softmax of the network's scores, in the same order (1 for K = 1).

**Stroke models** (:mod:`img2dmp.nn.strokes`: a character as up to S strokes, one
hypothesis) export as :class:`StrokeOnnxGraph`::

    input   images    float32 [B, H, W]
    output  strokes   float64 [B, S, P]   each slot's 2-D DMP vector, physical units
    output  presence  float64 [B, S]      the probability that the slot holds a stroke
    output  order     float64 [B, S]      the slot's order key (lower: written earlier)
    output  count     float64 [B, S]      the probabilities of 1 .. S strokes

read as :data:`STROKE_READING` says (the description's ``strokes.reading``).

The normalisation (:class:`img2dmp.nn.ParamNormaliser`: ``z * scale + centre``,
``tau = exp(.)``, forcing amplitudes back to weights) runs in float64 inside the graph,
as :class:`~img2dmp.predict.Predictor` runs it, so weights that grow like
``1 / (g - y0)`` keep their precision. Refinement (``--refine``) is not part of the graph.

**Description.** The graph's metadata (``metadata_props`` key ``"img2dmp"``) and a JSON
file beside it (``OUT.json``) hold the same description (:func:`describe`): format and
version, opset, input and outputs with their shapes, the vector's layout, the DMP
constants, the image size, the framing of the input (margin, pen width), the checkpoint
it came from (its record and weights digests) and the check.

**Check.** Before writing, the graph runs in onnxruntime on a batch of images (synthetic
digits drawn at the model's image size with the generator's noise, a blank and an
all-noise image, or a data set's images) and is compared with torch's
:meth:`~img2dmp.predict.Predictor.predict_hypotheses` on the same images. The DMP
parameters are compared in the network's output units (:func:`normalised_difference`:
each parameter minus its median over the training set, divided by its spread there,
log tau for tau, the forcing amplitudes for a network that outputs those), which weighs
each parameter by how much it varies between movements, whatever its physical unit; the
probabilities as they are. The largest difference must stay below :data:`TOLERANCE`,
else nothing is written. A float32 network gives a few 1e-8: a few roundings of float32.

Needs the ``export`` extra (onnx, onnxruntime, onnxscript): ``pip install
'img2dmp[export]'``; without it :class:`MissingExportPackages` says so in one line.
"""

from __future__ import annotations

import contextlib
import copy
import importlib
import json
import logging
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from . import __version__
from ._files import atomic_write_bytes, atomic_write_text
from .errors import Img2dmpError
from .nn.model import ImpulseFilter, split_hypotheses
from .nn.normalise import _MIN_SPAN as MIN_SPAN
from .predict import Predictor

#: The ONNX (default domain) opset the graph is written in.
OPSET = 18
FORMAT = "img2dmp-onnx"
VERSION = 1
INPUT = "images"
OUTPUTS = ("dmp", "probability")
#: A stroke model's graph's outputs (:class:`StrokeOnnxGraph`).
STROKE_OUTPUTS = ("strokes", "presence", "order", "count")
#: Largest difference between onnxruntime and torch that an export accepts (see the
#: module docstring); a float32 network gives a few 1e-8.
TOLERANCE = 1e-4
#: The packages of the ``export`` extra, and how to install them.
EXPORT_PACKAGES = ("onnx", "onnxruntime", "onnxscript")
INSTALL_HINT = "pip install -e '/path/to/img2dmp[export]'"
#: Images the check runs on by default.
CHECK_IMAGES = 64
#: Images per network call in the check.
MAX_CHECK_BATCH = 4096
SUFFIX = ".onnx"


class MissingExportPackages(Img2dmpError, ImportError):
    """An optional package of the ``export`` extra is not installed."""


class ExportCheckFailed(Img2dmpError):
    """The exported graph does not compute what torch computes."""


@dataclass
class ExportReport:
    """What :func:`export_onnx` wrote and measured."""

    onnx_path: Path
    description_path: Path
    opset: int
    max_difference: float
    n_checked: int
    description: dict = field(repr=False)


def require_export_packages() -> None:
    """Raise :class:`MissingExportPackages` (one line: what is missing, how to install it)
    unless onnx, onnxruntime and onnxscript can be imported."""
    missing = []
    for name in EXPORT_PACKAGES:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise MissingExportPackages(
            f"ONNX export needs the optional packages {', '.join(EXPORT_PACKAGES)} "
            f"(missing: {', '.join(missing)}); install them with: {INSTALL_HINT}"
        )


class DenseImpulseFilter(nn.Module):
    """:class:`~img2dmp.nn.model.ImpulseFilter` computed on every pixel, as ONNX can.

    The same values: a pixel at exactly 0 or 1 with ink around it takes the mean of the
    middle two of its 8 neighbours (edges replicated), every other pixel keeps its value.
    The original gathers only the pixels that can change (a data-dependent shape); this
    one takes the median everywhere and selects, which a static graph can express.
    """

    _NEIGHBOURS = ImpulseFilter._NEIGHBOURS

    def forward(self, images: torch.Tensor) -> torch.Tensor:  # [B, H, W] -> [B, H, W]
        x = images[:, None]
        hit = ((x <= 0) | (x >= 1)) & (nn.functional.max_pool2d(x.abs(), 3, 1, 1) > 0)
        padded = nn.functional.pad(x, (1, 1, 1, 1), mode="replicate")[:, 0]
        h, w = images.shape[-2:]
        around = [padded[:, di : di + h, dj : dj + w] for di, dj in self._NEIGHBOURS]
        ordered = torch.stack(around, -1).sort(-1).values  # [B, H, W, 8]
        return torch.where(hit[:, 0], ordered[..., 3:5].mean(-1), images)


class OnnxGraph(nn.Module):
    """What is exported: images -> network -> output normalisation -> ranked DMPs.

    ``forward(images [B, H, W] float32) -> (dmp [B, K, P] float64, probability [B, K]
    float64)``, the computation of :meth:`Predictor.predict_hypotheses` without
    refinement (see the module docstring).
    """

    def __init__(self, predictor: Predictor):
        super().__init__()
        model = copy.deepcopy(predictor.model).eval()
        if isinstance(model.input_filter, ImpulseFilter):
            model.input_filter = DenseImpulseFilter()
        self.model = model
        self.hypotheses = predictor.n_hypotheses
        norm = predictor.normaliser
        self.n_kernels, self.n_dims, self.units = norm.n_kernels, norm.n_dims, norm.units
        self.register_buffer("centre", torch.as_tensor(norm.centre, dtype=torch.float64))
        self.register_buffer("scale", torch.as_tensor(norm.scale, dtype=torch.float64))

    def denormalise(self, z: torch.Tensor) -> torch.Tensor:
        """:meth:`ParamNormaliser.denormalise_vector` in float64, with the sign of
        ``g - y0`` taken by a comparison (ONNX has no ``copysign``; the two differ only
        for a span of exactly -0.0, which the floor makes +-1e-9 either way)."""
        n, d = self.n_kernels, self.n_dims
        u = z.double() * self.scale + self.centre
        ti = n * d
        w = u[..., :ti]
        if self.units == "amplitudes":
            g, y0 = u[..., ti + 1 : ti + 1 + d], u[..., ti + 1 + d :]
            span = torch.repeat_interleave(g - y0, n, dim=-1)  # [..., N d], as w
            floor = span.abs().clamp_min(MIN_SPAN)
            w = w / torch.where(span < 0, -floor, floor)
        return torch.cat([w, torch.exp(u[..., ti : ti + 1]), u[..., ti + 1 :]], dim=-1)

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z, logits = split_hypotheses(self.model(images), self.hypotheses)  # [B, K, P], [B, K]
        v = self.denormalise(z)
        probs = torch.softmax(logits.double(), dim=1)
        probs, order = torch.topk(probs, self.hypotheses, dim=1)  # descending
        return torch.gather(v, 1, order[..., None].expand_as(v)), probs


class StrokeOnnxGraph(OnnxGraph):
    """A stroke model's graph: ``forward(images [B, H, W] float32) -> (strokes [B, S, P],
    presence [B, S], order [B, S], count [B, S])``, all float64: each slot's DMP in
    physical units, the probability that it holds a stroke, its order key, and the
    probabilities of 1 .. S strokes (module docstring; the reading is
    :func:`img2dmp.nn.strokes.read_strokes`)."""

    def __init__(self, predictor: Predictor):
        if predictor.n_hypotheses != 1:
            raise ValueError(
                f"only stroke models of one hypothesis export, this one has "
                f"{predictor.n_hypotheses}"
            )
        super().__init__(predictor)
        self.layout = predictor.strokes

    def forward(self, images: torch.Tensor):
        lay = self.layout
        out = self.model(images).double()
        s, p, width = lay.slots, lay.n_params, lay.slot_width
        z = out[:, : s * width].reshape(-1, s, width)
        return (self.denormalise(z[..., :p]), torch.sigmoid(z[..., p]), z[..., p + 1],
                torch.softmax(out[:, s * width :], dim=-1))  # fmt: skip


def vector_layout(n_kernels: int, n_dims: int) -> dict:
    """Where each field lies in the flat DMP vector: ``{"w": [start, stop], ...}`` (stop
    excluded) and how the weights are ordered."""
    n, d = n_kernels, n_dims
    return {
        "w": [0, n * d],
        "w_order": "w[k, i] (kernel k, dimension i) at index i * N + k",
        "tau": [n * d, n * d + 1],
        "g": [n * d + 1, n * d + 1 + d],
        "y0": [n * d + 1 + d, n * d + 1 + 2 * d],
        "length": n * d + 1 + 2 * d,
    }


def describe(predictor: Predictor, source: str | None = None) -> dict:
    """The description stored in the graph's metadata and in the JSON file beside it."""
    cfg = predictor.dmp_config
    h, w = predictor.image_size
    k, p = predictor.n_hypotheses, cfg.n_params
    meta = predictor.meta
    outputs = [
        {"name": OUTPUTS[0], "dtype": "float64", "shape": ["B", k, p]},
        {"name": OUTPUTS[1], "dtype": "float64", "shape": ["B", k]},
    ]
    if predictor.strokes is not None:
        outputs = _stroke_outputs(predictor.strokes)
    info = {
        "format": FORMAT,
        "version": VERSION,
        "opset": OPSET,
        "input": {"name": INPUT, "dtype": "float32", "shape": ["B", h, w]},
        "outputs": outputs,
        "vector_layout": vector_layout(cfg.n_kernels, cfg.n_dims),
        "hypotheses": k,
        "ranked": "hypotheses sorted by probability, highest first",
        "dmp_config": cfg.to_dict(),
        "image_size": [h, w],
        "framing": {
            "values": "float32 in [0, 1], ink = 1, background = 0",
            "ink_margin": predictor.margin,
            "stroke_width_px": predictor.stroke_width,
            "how": "img2dmp.predict.prepare_image(path, image_size, margin=ink_margin, "
            "stroke_width_px=stroke_width_px)",
        },
        "units": {
            "positions": "pixels of the model's input frame: x = column, y = row (down), "
            "pixel [i, j] centred at (x = j, y = i)",
            "tau": "seconds",
        },
        "source": {
            "checkpoint": source,
            "record_sha256": meta.get("record_sha256"),
            "weights_sha256": meta.get("weights_sha256"),
        },
        "img2dmp_version": __version__,
        "torch_version": torch.__version__,
    }
    if predictor.strokes is not None:
        info["strokes"] = {**predictor.strokes.to_dict(), "reading": STROKE_READING,
                           "count_views": int(predictor.count_views)}  # fmt: skip
    return info


#: How a stroke model's outputs are read as a character's strokes (the description's
#: ``strokes.reading``; :func:`img2dmp.nn.strokes.read_strokes`).
STROKE_READING = (
    "c = 1 + argmax(count[b]) strokes; with matching 'best' the c slots of highest "
    "presence, written in increasing order key; with 'order' slots 0 .. c-1 in that "
    "order; each slot's strokes[b, s] is one 2-D DMP vector laid out as vector_layout says. "
    "img2dmp itself averages count over count_views views of the image (the field beside "
    "this: the image and count_views - 1 small affine copies, img2dmp.nn.strokes."
    "count_views; 1 = the graph's count of the image alone) and reads no fewer strokes "
    "than the image "
    "has 8-connected pieces of ink (img2dmp.nn.strokes.ink_pieces)"
)


def _stroke_outputs(layout) -> list[dict]:
    s, p = layout.slots, layout.n_params
    shapes = {"strokes": ["B", s, p], "presence": ["B", s], "order": ["B", s], "count": ["B", s]}
    return [{"name": n, "dtype": "float64", "shape": shapes[n]} for n in STROKE_OUTPUTS]


def to_onnx(predictor: Predictor):
    """The :class:`OnnxGraph` of ``predictor`` as an ``onnx.ModelProto`` (batch size free)."""
    strokes = predictor.strokes is not None
    graph = (StrokeOnnxGraph if strokes else OnnxGraph)(predictor).eval()
    example = torch.zeros(3, *predictor.image_size)  # 3: a batch of 1 would be fixed
    with _quiet_exporter():
        program = torch.onnx.export(
            graph,
            (example,),
            dynamo=True,
            opset_version=OPSET,
            input_names=[INPUT],
            output_names=list(STROKE_OUTPUTS if strokes else OUTPUTS),
            dynamic_shapes={"images": {0: torch.export.Dim("batch")}},
            verbose=False,
        )
    return program.model_proto


@contextlib.contextmanager
def _quiet_exporter():
    """The exporter's notes (torchvision's operators skipped, deprecations inside torch)
    kept off the user's terminal; its errors still raise."""
    logger = logging.getLogger("torch.onnx")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            warnings.simplefilter("ignore", DeprecationWarning)
            yield
    finally:
        logger.setLevel(level)


def default_check_images(predictor: Predictor, n: int = CHECK_IMAGES, seed: int = 0) -> np.ndarray:
    """Images to check an export on, ``[n, H, W]`` float32: synthetic digits drawn at the
    model's image size (blur, salt-and-pepper noise, affine), the last two replaced by a
    blank image and one of salt-and-pepper noise everywhere."""
    from .data.synthetic import SyntheticConfig, generate

    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 3 <= n <= MAX_CHECK_BATCH:
        raise ValueError(
            f"n_check must be an integer from 3 to {MAX_CHECK_BATCH:,} (images the export is "
            f"checked on), got {n!r}"
        )
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    rng = np.random.default_rng(seed)
    config = SyntheticConfig(image_size=tuple(predictor.image_size))
    images = generate(np.arange(n - 2) % 10, config, rng).images.astype(np.float32)
    blank = np.zeros((1, *predictor.image_size), np.float32)
    noise = rng.choice(np.array([0.0, 0.5, 1.0], np.float32), size=blank.shape)
    return np.concatenate([images, blank, noise])


def max_difference(onnx_bytes: bytes, predictor: Predictor, images: np.ndarray) -> float:
    """The largest difference between the graph ``onnx_bytes`` run by onnxruntime and
    :meth:`Predictor.predict_hypotheses` (without refinement) on ``images [B, H, W]``: of
    the DMP parameters in the network's output units (:func:`normalised_difference`), of
    the probabilities as they are."""
    import onnxruntime as ort

    images = np.ascontiguousarray(images, dtype=np.float32)
    if images.ndim != 3 or tuple(images.shape[1:]) != predictor.image_size or not len(images):
        h, w = predictor.image_size
        raise ValueError(f"check images must have shape [B >= 1, {h}, {w}], got {images.shape}")
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(onnx_bytes, options, providers=["CPUExecutionProvider"])
    if predictor.strokes is not None:
        return _stroke_difference(session.run(list(STROKE_OUTPUTS), {INPUT: images}),
                                  predictor, images)  # fmt: skip
    dmp, prob = session.run(list(OUTPUTS), {INPUT: images})
    plain = Predictor(predictor.model, predictor.normaliser, predictor.dmp_config, predictor.meta)
    params, probs = plain.predict_hypotheses(images)
    ref = np.asarray(params.to_vector())  # [B, K, P]
    for name, a, b in (("dmp", dmp, ref), ("probability", prob, probs)):
        if a.shape != b.shape:
            raise ExportCheckFailed(f"onnxruntime gave {name} of shape {a.shape}, torch {b.shape}")
    if not np.isfinite(dmp).all() or not (dmp[..., predictor.normaliser.tau_index] > 0).all():
        raise ExportCheckFailed("onnxruntime gave DMP parameters that are not finite or tau <= 0")
    return max(normalised_difference(predictor.normaliser, dmp, ref), _abs_max(prob - probs))


def _stroke_difference(got, predictor: Predictor, images: np.ndarray) -> float:
    """:func:`max_difference` of a stroke model's graph: its outputs ``got`` against
    the network's outputs read in NumPy (:func:`img2dmp.nn.strokes.split_slots_numpy`),
    the strokes in the network's output units, the probabilities and keys as they are."""
    from .nn._stroke_layout import split_slots_numpy

    _, out = predictor._raw_outputs(images, MAX_CHECK_BATCH)
    z, presence, order, count, _ = split_slots_numpy(out, predictor.strokes, 1)
    c = np.exp(count[:, 0] - count[:, 0].max(-1, keepdims=True))
    ref = (predictor.normaliser.denormalise_numpy(z[:, 0]), 1 / (1 + np.exp(-presence[:, 0])),
           order[:, 0], c / c.sum(-1, keepdims=True))  # fmt: skip
    for name, a, b in zip(STROKE_OUTPUTS, got, ref, strict=True):
        if a.shape != b.shape:
            raise ExportCheckFailed(f"onnxruntime gave {name} of shape {a.shape}, torch {b.shape}")
    strokes = got[0]
    if (
        not np.isfinite(strokes).all()
        or not (strokes[..., predictor.normaliser.tau_index] > 0).all()
    ):
        raise ExportCheckFailed("onnxruntime gave strokes that are not finite or tau <= 0")
    diffs = [normalised_difference(predictor.normaliser, strokes, ref[0])]
    return max(diffs + [_abs_max(a - b) for a, b in zip(got[1:], ref[1:], strict=True)])


def normalised_difference(normaliser, a: np.ndarray, b: np.ndarray) -> float:
    """``max |normalise(a) - normalise(b)|`` of DMP vectors ``[..., P]`` (tau > 0): their
    difference in the network's output units, each parameter in units of its spread over
    the training set (:class:`img2dmp.nn.ParamNormaliser`; log tau, and the forcing
    amplitudes where the network outputs those)."""
    za = normaliser.normalise(torch.as_tensor(a, dtype=torch.float64))
    zb = normaliser.normalise(torch.as_tensor(b, dtype=torch.float64))
    return _abs_max((za - zb).numpy())


def _abs_max(d: np.ndarray) -> float:
    return float(np.abs(d).max()) if d.size else 0.0


def description_path(onnx_path: str | os.PathLike) -> Path:
    """The JSON description written beside ``OUT.onnx``: ``OUT.json``."""
    return Path(onnx_path).with_suffix(".json")


def export_onnx(
    model: str | os.PathLike | Predictor,
    onnx_path: str | os.PathLike,
    *,
    images: np.ndarray | None = None,
    n_check: int = CHECK_IMAGES,
    seed: int = 0,
) -> ExportReport:
    """Write ``model`` (a run directory, a checkpoint or a :class:`Predictor`) as ONNX to
    ``onnx_path`` (``.onnx``) and its description to ``OUT.json``, after checking the
    graph with onnxruntime against torch on ``images`` (default
    :func:`default_check_images` of ``n_check`` images drawn with ``seed``).

    Raises
    ------
    MissingExportPackages
        onnx, onnxruntime or onnxscript is not installed (nothing is read or written).
    ExportCheckFailed
        onnxruntime and torch differ by more than :data:`TOLERANCE` (nothing is written).
    """
    onnx_path = Path(onnx_path)
    if onnx_path.suffix != SUFFIX:
        raise ValueError(f"the ONNX file must end in {SUFFIX}, got {str(onnx_path)!r}")
    require_export_packages()
    source = None if isinstance(model, Predictor) else str(model)
    predictor = model if isinstance(model, Predictor) else Predictor.load(model)
    proto = to_onnx(predictor)
    check = default_check_images(predictor, n_check, seed) if images is None else images
    diff = max_difference(proto.SerializeToString(), predictor, check)
    if not diff <= TOLERANCE:
        raise ExportCheckFailed(
            f"the exported graph differs from torch by {diff:.3g} on {len(check)} images "
            f"(at most {TOLERANCE:g} is accepted); nothing was written"
        )
    info = describe(predictor, source)
    info["check"] = {
        "images": int(len(check)),
        "max_difference": diff,
        "tolerance": TOLERANCE,
        "measure": "onnxruntime vs torch: DMP parameters in the network's output units (each "
        "over its spread in the training set), probabilities as they are",
    }
    text = json.dumps(info, indent=1)
    entry = proto.metadata_props.add()
    entry.key, entry.value = "img2dmp", text
    proto.doc_string = "img2dmp: image -> DMP parameters (see the metadata key 'img2dmp')"
    atomic_write_bytes(onnx_path, proto.SerializeToString())
    atomic_write_text(description_path(onnx_path), text + "\n")
    return ExportReport(onnx_path, description_path(onnx_path), OPSET, diff, len(check), info)


__all__ = [
    "CHECK_IMAGES",
    "EXPORT_PACKAGES",
    "INSTALL_HINT",
    "OPSET",
    "TOLERANCE",
    "DenseImpulseFilter",
    "ExportCheckFailed",
    "ExportReport",
    "MissingExportPackages",
    "OnnxGraph",
    "default_check_images",
    "describe",
    "description_path",
    "normalised_difference",
    "export_onnx",
    "max_difference",
    "require_export_packages",
    "to_onnx",
    "vector_layout",
]
