"""What a type checker (mypy, pyright) sees of the documented API in a user's code.

img2dmp ships ``py.typed``, so a user's mypy reads its annotations: the top-level names
must be visible as what they are (not ``Any`` through the lazy ``__getattr__``),
``load_model``'s overloads must say what each shipped model's ``predict`` gives, and the
fields users call array methods on (``fit.error_px.mean()``) must not be ``object``.
These check the annotations themselves (mypy is not a dependency): a stub
``img2dmp/__init__.pyi`` names the lazily loaded top-level names (type checkers read it
instead of ``__init__.py``, whose imports are strings).
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import types
import typing
from pathlib import Path

import img2dmp
import img2dmp.predict as predict_module
from img2dmp.dmp.fit import FitResult
from img2dmp.dmp.params import DMPParams
from img2dmp.interop import PeerExport
from img2dmp.models import default_model, shipped_models

STUB = Path(img2dmp.__file__).with_suffix(".pyi")  # what type checkers read for img2dmp


def test_every_top_level_name_is_named_for_type_checkers_from_its_module():
    assert STUB.is_file(), f"{STUB} is missing: type checkers would see img2dmp.X as Any"
    tree = ast.parse(STUB.read_text())
    seen = {}
    for imp in tree.body:
        if isinstance(imp, ast.ImportFrom):
            assert imp.level == 1, ast.dump(imp)
            for alias in imp.names:
                # "import X as X": an explicit re-export (mypy --strict needs it)
                assert alias.asname == alias.name, alias.name
                seen[alias.name] = "img2dmp." + imp.module
    lazy = img2dmp._LAZY
    assert set(seen) == set(lazy)
    for name in lazy:
        # the very object the lazy lookup gives (a package may re-export a submodule's)
        assert getattr(importlib.import_module(seen[name]), name) is getattr(img2dmp, name)
    stub_all = next(
        ast.literal_eval(n.value) for n in tree.body
        if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "__all__"
    )  # fmt: skip
    assert stub_all == img2dmp.__all__


def test_load_models_overloads_say_what_each_shipped_models_predict_gives():
    overloads = typing.get_overloads(predict_module.load_model)
    assert overloads, "load_model has no overloads"
    by_name, without_path = {}, []  # a shipped name -> what predict gives (the first match)
    for fn in overloads:
        hints = typing.get_type_hints(fn, vars(predict_module))
        (gives,) = typing.get_args(hints["return"])  # Predictor[gives]
        path = hints["path"]
        union = typing.get_origin(path) in (typing.Union, types.UnionType)
        for arg in typing.get_args(path) if union else (path,):
            if typing.get_origin(arg) is typing.Literal:
                for name in typing.get_args(arg):
                    by_name.setdefault(name, gives)
            elif arg is type(None):
                without_path.append(gives)
    for shipped in shipped_models():
        model = img2dmp.load_model(shipped.name, refine=0)
        expected = predict_module.StrokePrediction if model.strokes else predict_module.Prediction
        assert by_name.get(shipped.name) is expected, shipped.name
    assert without_path[0] is by_name[default_model().name]  # load_model(): the default


def test_fields_users_call_array_methods_on_are_not_typed_object():
    for cls, names in (
        (DMPParams, ("w", "tau", "g", "y0")),
        (FitResult, ("error_px", "max_error_px")),
        (PeerExport, ("dmp",)),
    ):
        hints = typing.get_type_hints(cls)
        for name in names:
            assert hints[name] is typing.Any, f"{cls.__name__}.{name}: {hints[name]}"
    assert {f.name for f in dataclasses.fields(DMPParams)} >= {"w", "tau", "g", "y0"}
    for cls in (predict_module.Prediction, predict_module.StrokePrediction):
        assert "familiarity" in typing.get_type_hints(cls), cls.__name__
