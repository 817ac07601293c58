"""Write a trained network with its output normalisation as ONNX, for a robot computer
that runs it with onnxruntime, without torch (docs/EXPORT.md).

The graph (ONNX opset 18) takes prepared images "images" float32 [B, H, W] in the model's
frame (ink = 1, framed as the training images; img2dmp.predict.prepare_image) and gives
"dmp" float64 [B, K, P], the DMP parameter vectors in physical units (N weights of each
dimension, tau in seconds, goal and start in pixels of the input frame), and
"probability" float64 [B, K], the K hypotheses ranked, most probable first (K = 1 for the
paper's network). OUT.json beside it, and the graph's metadata, describe the layout, the
DMP constants, the image size and framing, and the check.

Before anything is written the graph runs in onnxruntime on a batch of synthetic digits at
the model's size (or on --data's images) and is compared with torch; the largest
difference, of the DMP parameters in units of their spread over the training set
(img2dmp.export.normalised_difference), is printed and must stay below 1e-4. OUT.onnx
and OUT.json, if there, are replaced only with --force. Needs the export extra:
pip install -e '/path/to/img2dmp[export]'.

  img2dmp export --model runs/paper --onnx paper.onnx
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import _args

HELP = "the network with its output normalisation as ONNX, checked with onnxruntime"
#: Default and largest number of check images (img2dmp.export.CHECK_IMAGES; literals: this
#: module must not import torch).
CHECK_IMAGES = 64
MAX_CHECK_IMAGES = 100_000


def add_arguments(p: argparse.ArgumentParser) -> None:
    _args.add_model(p, required=True)
    p.add_argument(
        "--onnx", required=True, metavar="OUT.onnx", help="the ONNX file (OUT.json beside it)"
    )
    _args.add_data(
        p,
        help="check on this data set's images (.safetensors, the model's image size) "
        "instead of synthetic digits",
    )
    p.add_argument(
        "--check",
        metavar="N",
        type=_args.int_at_least(3, MAX_CHECK_IMAGES),
        default=CHECK_IMAGES,
        help="images the check compares onnxruntime and torch on",
    )
    _args.add_force(p, "OUT.onnx and OUT.json")


def outputs(args: argparse.Namespace) -> list[Path]:
    """The two files written: the graph and its description."""
    onnx = Path(args.onnx)
    if onnx.suffix != ".onnx":
        raise ValueError(f"--onnx must name a file ending in .onnx, got {args.onnx!r}")
    return [onnx, onnx.with_suffix(".json")]


def run(args: argparse.Namespace) -> int:
    files = outputs(args)
    inputs = [("data set", args.data), *_args.model_inputs(args.model)]
    _args.check_outputs([(f, None) for f in files], args.force, inputs)
    if args.data is not None:
        _args.check_inputs([args.data], "data set")
    from ..export import export_onnx, require_export_packages

    require_export_packages()  # before anything slow: one line saying how to install
    images = _data_images(args.data, args.check) if args.data is not None else None
    report = export_onnx(args.model, files[0], images=images, n_check=args.check)
    print(
        f"written: {report.onnx_path} (ONNX opset {report.opset}) and "
        f"{report.description_path}; onnxruntime vs torch on {report.n_checked} images: "
        f"max difference {report.max_difference:.2e} (DMP parameters in units of their "
        "spread over the training set)"
    )
    return 0


def _data_images(path: str, n: int):
    """The first ``n`` images of a data set (its test split if it has one)."""
    from ..data.store import load_dataset

    data = load_dataset(path)
    if (data.split == 2).any():
        data = data.select_split("test")
    return data.images[:n]
