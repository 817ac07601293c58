"""The names of ``img2dmp`` for type checkers (mypy, pyright, IDEs): what ``__init__.py``
loads on first use (its ``_LAZY``), imported from their modules. Kept equal to it by
tests/test_api_types.py."""

from .data.dmpfile import load_dmp_json as load_dmp_json
from .data.dmpfile import read_dmp_file as read_dmp_file
from .data.dmpfile import save_dmp_json as save_dmp_json
from .data.images import ImageFrame as ImageFrame
from .data.images import prepare_image as prepare_image
from .dmp import DMPConfig as DMPConfig
from .dmp import DMPParams as DMPParams
from .dmp import fit_dmp as fit_dmp
from .dmp import rollout as rollout
from .dmp.affine import affine_dmp as affine_dmp
from .dmp.bend import bend_dmp as bend_dmp
from .predict import Prediction as Prediction
from .predict import Predictor as Predictor
from .predict import load_model as load_model

__version__: str
__all__ = [
    "__version__",
    "load_model",
    "Prediction",
    "Predictor",
    "ImageFrame",
    "prepare_image",
    "DMPConfig",
    "DMPParams",
    "fit_dmp",
    "rollout",
    "affine_dmp",
    "bend_dmp",
    "load_dmp_json",
    "save_dmp_json",
    "read_dmp_file",
]
