"""Trained networks shipped inside the package, named like ``--model digits-real``.

A shipped model is a folder ``img2dmp/models/NAME/`` of three files:

``model.safetensors``
    A checkpoint exactly as :mod:`img2dmp.checkpoint` writes it (safetensors weights,
    the JSON record in its header with its own digests), byte for byte the trained run's
    best checkpoint.
``model.json``
    The shipping record (format ``img2dmp-shipped-model``, version 1): the name, whether
    it is the default, a one-line summary, the weights file's size and SHA-256, the
    settings its card recommends (``{"refine": 30}``; a stroke model's also
    ``"count_views"``), the test-part figures it was
    measured at and where it came from (commands, revisions).
``CARD.md``
    The model card for people: data, commands, revisions, figures, recommended settings
    and what the model is not for.

A model may also carry ``familiar.safetensors`` (:mod:`img2dmp.familiar`: its training
drawings' encoder features and the line below which an image is unfamiliar), named with
its size and SHA-256 in ``model.json``'s ``"familiar"`` and checked like the weights
(:func:`verified_familiar`).

A name is a word of letters, digits, ``-`` and ``_`` (:func:`is_model_name`). Wherever a
run directory or checkpoint is taken, such a word that is not an existing file or folder
is looked up here (:func:`resolve`): a shipped name gives its weights file, after its
SHA-256 is checked against ``model.json`` (:func:`verified_weights`: a damaged file is
refused with one :class:`~img2dmp.errors.ShippedModelError` naming it); another word gives
one :class:`~img2dmp.errors.UnknownModelError` listing the shipped names. A path is always
a path: a folder ``digits-real`` in the working directory wins over the shipped model
when that word is given. The default, read when no model is given at all, is always the
shipped model itself (:func:`default_model`).

Standard library only: ``img2dmp models`` lists them without loading torch, and every
layer (the checkpoint reader among them) may use this module.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from .._files import file_digest
from ..errors import ShippedModelError, UnknownModelError, show

FORMAT = "img2dmp-shipped-model"
VERSION = 1
WEIGHTS_FILE = "model.safetensors"
RECORD_FILE = "model.json"
CARD_FILE = "CARD.md"
FAMILIAR_FILE = "familiar.safetensors"
#: What a model's name looks like (and a ``--model`` word looked up here).
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")
#: Settings a card may recommend, with their types and least values (``refine``:
#: refinement steps; ``refine_unfamiliar``: those of images the model finds unfamiliar,
#: :attr:`img2dmp.predict.Predictor.refine_unfamiliar`; ``count_views``: the views of an
#: image a stroke model reads its stroke count from,
#: :attr:`img2dmp.predict.Predictor.count_views`).
RECOMMENDED_KEYS = {"refine": (int, 0), "refine_unfamiliar": (int, 0), "count_views": (int, 1)}


@dataclass(frozen=True)
class ShippedModel:
    """One model shipped with img2dmp (its ``model.json``, read and checked).

    Attributes
    ----------
    name : str
    folder : Path
        ``img2dmp/models/NAME``.
    summary : str
        One line: what it reads and how it was trained.
    sha256 : str
        SHA-256 of ``model.safetensors`` as shipped.
    size_bytes : int
    default : bool
        The model used when none is given (exactly one shipped model is).
    recommended : dict
        Settings its card recommends, e.g. ``{"refine": 30}``.
    figures : dict
        Its measured test-part figures (``model.json``'s ``"figures"``).
    record : dict
        The whole ``model.json``.
    """

    name: str
    folder: Path
    summary: str
    sha256: str
    size_bytes: int
    default: bool
    recommended: dict = field(default_factory=dict)
    figures: dict = field(default_factory=dict)
    record: dict = field(default_factory=dict, repr=False)

    def __str__(self) -> str:  # as a command line and its messages name it
        return self.name

    @property
    def weights(self) -> Path:
        """The checkpoint file (not yet verified: :func:`verified_weights`)."""
        return self.folder / WEIGHTS_FILE

    @property
    def card(self) -> Path:
        return self.folder / CARD_FILE

    @property
    def familiar(self) -> Path | None:
        """Its familiarity file, if it carries one (not yet verified:
        :func:`verified_familiar`)."""
        return self.folder / FAMILIAR_FILE if "familiar" in self.record else None

    @property
    def reading(self) -> Reading:
        """The settings its card recommends reading its predictions with."""
        return Reading.from_recommended(self.recommended, "its card")

    @property
    def refine(self) -> int:
        """The refinement steps its card recommends (0 if it recommends none)."""
        return self.reading.refine

    @property
    def refine_unfamiliar(self) -> int | None:
        """The refinement steps its card recommends for images it finds unfamiliar (None:
        it recommends none, they get :attr:`refine`'s)."""
        return self.reading.refine_unfamiliar

    @property
    def count_views(self) -> int | None:
        """The views a stroke model's card recommends reading the stroke count from (None:
        it recommends none, :data:`img2dmp.nn.strokes.COUNT_VIEWS` is read)."""
        return self.reading.count_views


@dataclass(frozen=True)
class Reading:
    """The settings a model's predictions are read with when the caller does not say
    (``predict``, ``write``, ``evaluate``, ``serve``, :func:`img2dmp.predict.load_model`):
    a shipped model's card's ``recommended``, or the ``reading`` section of the training
    configuration in a run's checkpoint (:class:`img2dmp.training.config.ReadingConfig`).

    ``refine``: refinement steps (0: none); ``refine_unfamiliar``: those of images below
    the model's familiarity line (None: ``refine``'s); ``count_views``: the views a stroke
    model reads its count from (None: :data:`img2dmp.nn.strokes.COUNT_VIEWS`); ``by``:
    who recommends them, for notes (``"its card"``; empty: nobody).
    """

    refine: int = 0
    refine_unfamiliar: int | None = None
    count_views: int | None = None
    by: str = ""

    @classmethod
    def from_recommended(cls, recommended: dict, by: str) -> Reading:
        """From settings written as a card writes them (:data:`RECOMMENDED_KEYS`; checked
        where they are read)."""
        return cls(int(recommended.get("refine", 0)), recommended.get("refine_unfamiliar"),
                   recommended.get("count_views"), by)  # fmt: skip

    def recommended(self) -> dict:
        """The settings as a card writes them (``refine`` always, the others when set)."""
        out = {"refine": self.refine}
        for key in ("refine_unfamiliar", "count_views"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        return out

    def without_unfamiliar(self) -> Reading:
        """The same without ``refine_unfamiliar`` (for a model that carries no
        familiarity to tell unfamiliar images by)."""
        return Reading(self.refine, None, self.count_views, self.by)


def _bad_setting(recommended: dict):
    """The first key of ``recommended`` that is not a reading setting of its type and
    least value (:data:`RECOMMENDED_KEYS`), None if every one is."""
    for key, value in recommended.items():
        kind, least = RECOMMENDED_KEYS.get(key, (None, 0))
        if kind is None or not isinstance(value, kind) or isinstance(value, bool) or value < least:
            return key
    return None


def checkpoint_reading(record: dict, where: str = "checkpoint") -> Reading:
    """The reading settings a checkpoint's JSON ``record`` recommends: its training
    configuration's ``reading`` section (:class:`img2dmp.training.config.ReadingConfig`),
    nothing for a checkpoint trained before img2dmp recorded one. ``ValueError`` naming
    ``where`` and the setting for a value that is not a whole number in range."""
    train_config = record.get("train_config") or {}
    if not isinstance(train_config, dict):
        raise ValueError(f"{where} is {show(train_config)}, not a mapping")
    section = train_config.get("reading") or {}
    if not isinstance(section, dict):
        raise ValueError(f"{where}: train_config.reading is {show(section)}, not a mapping")
    recommended = {k: v for k, v in section.items() if v is not None}
    bad = _bad_setting(recommended)
    if bad is not None:
        raise ValueError(f"{where}: reading setting {bad!r} = {show(recommended[bad])}")
    return Reading.from_recommended(recommended, "its training configuration (reading)")


def models_root() -> Path:
    """The folder that holds the shipped models (``img2dmp/models``)."""
    return Path(str(resources.files(__name__)))


def is_model_name(text) -> bool:
    """Whether ``text`` is written like a model's name (a word: letters, digits, ``-``,
    ``_``; no path separator, no suffix) rather than like a path."""
    return isinstance(text, str) and NAME_PATTERN.fullmatch(text) is not None


def _field(record: dict, key: str, kind, where: Path):
    value = record.get(key)
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise ShippedModelError(
            f"shipped model record {where}: {key!r} must be a {kind.__name__}, got {show(value)}"
        )
    return value


def _read(folder: Path) -> ShippedModel:
    """The model of one folder, its ``model.json`` checked (not the weights' digest)."""
    where = folder / RECORD_FILE
    try:
        record = json.loads(where.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ShippedModelError(f"shipped model record {where} cannot be read: {e}") from None
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise ShippedModelError(f"{where} is not a shipped model record (format {FORMAT!r})")
    if record.get("version") != VERSION:
        raise ShippedModelError(
            f"{where}: shipped model record version {show(record.get('version'))} is not "
            f"supported (this img2dmp reads version {VERSION})"
        )
    name = _field(record, "name", str, where)
    if name != folder.name or not is_model_name(name):
        raise ShippedModelError(f"{where}: name {show(name)} is not its folder's {folder.name!r}")
    weights = _field(record, "weights", dict, where)
    sha256 = _field(weights, "sha256", str, where)
    size = _field(weights, "bytes", int, where)
    recommended = _field(record, "recommended", dict, where)
    if "familiar" in record:
        familiar = _field(record, "familiar", dict, where)
        if familiar.get("file") != FAMILIAR_FILE:
            raise ShippedModelError(f"{where}: familiar file {show(familiar.get('file'))} "
                                    f"is not {FAMILIAR_FILE!r}")  # fmt: skip
        _field(familiar, "sha256", str, where)
        _field(familiar, "bytes", int, where)
    bad = _bad_setting(recommended)
    if bad is not None:
        raise ShippedModelError(f"{where}: recommended setting {bad!r} = {show(recommended[bad])}")
    return ShippedModel(
        name=name,
        folder=folder,
        summary=_field(record, "summary", str, where),
        sha256=sha256,
        size_bytes=size,
        default=_field(record, "default", bool, where),
        recommended=dict(recommended),
        figures=dict(record.get("figures") or {}),
        record=record,
    )


def shipped_models(root: str | os.PathLike | None = None) -> list[ShippedModel]:
    """Every shipped model, by name (``root``: another folder of models, for tests)."""
    base = Path(root) if root is not None else models_root()
    folders = sorted(p for p in base.iterdir() if (p / RECORD_FILE).is_file())
    return [_read(p) for p in folders]


def shipped_model_names(root: str | os.PathLike | None = None) -> list[str]:
    """The names of the shipped models (``img2dmp models`` lists them)."""
    return [m.name for m in shipped_models(root)]


def find_shipped(name: str, root: str | os.PathLike | None = None) -> ShippedModel:
    """The shipped model ``name``; :class:`~img2dmp.errors.UnknownModelError` naming the
    shipped ones if there is none of that name."""
    models = shipped_models(root)
    for m in models:
        if m.name == name:
            return m
    names = ", ".join(m.name for m in models) or "none"
    raise UnknownModelError(
        f"no run directory, checkpoint or shipped model named {show(name)}; the models "
        f"shipped with img2dmp are: {names} (img2dmp models lists them)"
    )


def default_model(root: str | os.PathLike | None = None) -> ShippedModel:
    """The model used when none is given: the one shipped model marked default."""
    defaults = [m for m in shipped_models(root) if m.default]
    if len(defaults) != 1:
        names = ", ".join(m.name for m in defaults) or "none"
        raise ShippedModelError(
            f"img2dmp ships {len(defaults)} default models ({names}); exactly one must be: "
            "the installation is damaged"
        )
    return defaults[0]


def resolve(source, root: str | os.PathLike | None = None) -> ShippedModel | None:
    """The shipped model ``source`` names, or None when ``source`` is a path.

    ``source`` is a path if it is not written like a name (:func:`is_model_name`, as a
    string or a path of one word such as ``Path("digits-real")``), or if a file or
    folder of that name exists here; otherwise it must name a shipped model
    (:func:`find_shipped`: unknown words are refused, listing the shipped names).
    """
    if isinstance(source, ShippedModel):
        return source
    if isinstance(source, os.PathLike):
        source = os.fspath(source)
    if not is_model_name(source) or os.path.lexists(source):
        return None
    return find_shipped(source, root)


def verified_weights(model: ShippedModel) -> Path:
    """``model``'s weights file once its size and SHA-256 match ``model.json``; else one
    :class:`~img2dmp.errors.ShippedModelError` naming the file (reinstall img2dmp)."""
    return _verified(model, model.weights, model.size_bytes, model.sha256)


def verified_familiar(model: ShippedModel) -> Path | None:
    """``model``'s familiarity file (None if it carries none) once its size and SHA-256
    match ``model.json``; else one :class:`~img2dmp.errors.ShippedModelError` naming it."""
    if model.familiar is None:
        return None
    entry = model.record["familiar"]
    return _verified(model, model.familiar, entry["bytes"], entry["sha256"])


def _verified(model: ShippedModel, path: Path, size_bytes: int, sha256: str) -> Path:
    try:
        size = path.stat().st_size
        digest = file_digest(path)
    except OSError as e:
        raise ShippedModelError(
            f"shipped model {model.name}: {path} cannot be read ({e.strerror or e}); "
            "reinstall img2dmp"
        ) from None
    if size != size_bytes or digest != sha256:
        raise ShippedModelError(
            f"shipped model {model.name}: {path} is damaged: its SHA-256 {digest[:12]}... "
            f"({size:,} bytes) is not the recorded {sha256[:12]}... "
            f"({size_bytes:,} bytes); reinstall img2dmp"
        )
    return path


__all__ = [
    "CARD_FILE",
    "FAMILIAR_FILE",
    "FORMAT",
    "RECORD_FILE",
    "Reading",
    "ShippedModel",
    "WEIGHTS_FILE",
    "checkpoint_reading",
    "default_model",
    "find_shipped",
    "is_model_name",
    "models_root",
    "resolve",
    "shipped_model_names",
    "shipped_models",
    "verified_familiar",
    "verified_weights",
]
