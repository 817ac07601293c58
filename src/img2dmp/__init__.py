"""img2dmp: from a raw image of handwriting to the movement that wrote it.

Implements and extends Pahič, Gams, Ude, Morimoto, "Deep Encoder-Decoder Networks for
Mapping Raw Images to Dynamic Movement Primitives", ICRA 2018.

The one call from Python::

    import img2dmp

    pred = img2dmp.load_model("runs/paper").predict("my_digit.png")  # or PIL / NumPy
    pred.dmp, pred.path_image, pred.probabilities
    pred.save("my_digit_dmp.json")        # what `img2dmp write --dmp` executes

Exported here (each loaded on first use, so that ``import img2dmp`` and
``img2dmp --help`` load neither torch nor NumPy):

- :func:`load_model` - a trained network (run directory or checkpoint) as a
  :class:`Predictor`; :meth:`Predictor.predict` gives a :class:`Prediction` (the ranked
  DMPs with their probabilities, trajectories in the model's and the image's frame,
  ``save``)
- :class:`ImageFrame` - the affine map between the user's image and the model's input;
  :func:`prepare_image` - an image as the model's input
- :class:`DMPConfig`, :class:`DMPParams`, :func:`fit_dmp`, :func:`rollout` - the DMP of
  the paper (:mod:`img2dmp.dmp`); :func:`affine_dmp` - the same DMP in another frame;
  :func:`bend_dmp` - a new goal or start, scaled, rotated, another tempo
- :func:`load_dmp_json`, :func:`save_dmp_json`, :func:`read_dmp_file` - the one DMP file

Everything else is imported from its module (``img2dmp.training``, ``img2dmp.robot``,
``img2dmp.data``, ...). Static type checkers see the exact types of every name, here
(``__init__.pyi`` names them for them) and there.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

# A facade: names of the layers below, resolved by module __getattr__ on first access
# (the modules themselves import nothing from here).
_LAZY = {
    "load_model": "img2dmp.predict",
    "Prediction": "img2dmp.predict",
    "Predictor": "img2dmp.predict",
    "ImageFrame": "img2dmp.data.images",
    "prepare_image": "img2dmp.data.images",
    "DMPConfig": "img2dmp.dmp",
    "DMPParams": "img2dmp.dmp",
    "fit_dmp": "img2dmp.dmp",
    "rollout": "img2dmp.dmp",
    "affine_dmp": "img2dmp.dmp.affine",
    "bend_dmp": "img2dmp.dmp.bend",
    "load_dmp_json": "img2dmp.data.dmpfile",
    "save_dmp_json": "img2dmp.data.dmpfile",
    "read_dmp_file": "img2dmp.data.dmpfile",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'img2dmp' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later accesses skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
