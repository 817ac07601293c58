"""Write a digit with a simulated KUKA LBR iiwa (pybullet): joint-torque control, IK in the
plane and an admittance loop holding the pen's contact force.

Input is either images and a trained model (``IMAGE ... --model CKPT``) or one DMP file
(``--dmp params.json``; format in docs/ROBOT.md). For each input it writes
``NAME_paper.png`` (the ink next to the commanded path and the input), ``NAME_render.png``
(camera: the arm at the end | the paper), ``NAME_log.csv`` and with ``--video``
``NAME.gif``, and prints tracking-error and contact-force metrics. NAME is the input
file's name without its extension: two inputs of one name are refused, naming both, and
files already in ``--out-dir`` are replaced only with ``--force``; both are checked before
the simulation starts.
Needs the optional extra: ``pip install img2dmp[robot]``.
"""

from __future__ import annotations

import argparse
import os
import sys

from . import _args

HELP = "write a digit with a simulated KUKA arm (pybullet) and measure how well it went"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("images", nargs="*", metavar="IMAGE", help="image(s) of a digit")
    parser.add_argument("--model", help="trained model: run directory or checkpoint (with IMAGE)")
    parser.add_argument("--dmp", metavar="JSON", help="one DMP to write (instead of IMAGE)")
    parser.add_argument(
        "--image", metavar="PNG", help="with --dmp: an image to show next to the result"
    )
    parser.add_argument("--out-dir", default="robot_out", help="directory for the outputs")
    _args.add_force(parser, "files in --out-dir")
    parser.add_argument(
        "--writing-height-mm", type=float, default=40.0, help="height of the image on paper"
    )
    parser.add_argument("--force-n", type=float, default=5.0, help="contact force set point")
    parser.add_argument("--rate-hz", type=float, default=240.0, help="controller and physics rate")
    parser.add_argument(
        "--center-m",
        type=float,
        nargs=2,
        default=(0.55, 0.0),
        metavar=("X", "Y"),
        help="centre of the paper and writing area in the robot's base frame",
    )
    parser.add_argument("--video", action="store_true", help="also write an animated GIF")
    parser.add_argument(
        "--frame-interval-s", type=float, default=0.1, help="simulated time between frames"
    )
    _args.add_refine(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _inputs(args) -> list[tuple[str, object, object, tuple, object]]:
    """(name, params, config, image_size, image or None) for every input."""
    import numpy as np

    from img2dmp.robot import load_dmp_json

    if args.dmp:
        params, config, size = load_dmp_json(args.dmp)
        image = _read_image(args.image) if args.image else None
        return [(_name(args.dmp), params, config, size, image)]
    from img2dmp.predict import Predictor

    predictor = Predictor.load(args.model)
    if args.refine:
        from img2dmp.nn.refine import RefineOptions

        predictor.refine_options = RefineOptions(steps=args.refine)
    config = predictor.dmp_config
    out = []
    for path, (params, image) in zip(
        args.images, predictor.predict_paths(args.images), strict=True
    ):
        image = np.asarray(image, dtype=np.float32)
        out.append((_name(path), params, config, tuple(image.shape[-2:]), image))
    return out


def _name(path) -> str:
    return os.path.splitext(os.path.basename(path))[0]


def check_files(args) -> None:
    """The inputs (there, readable, images that open) and the outputs (the overwrite rule,
    one name per input), before anything is loaded or simulated."""
    if args.dmp and args.images:
        raise ValueError("give either IMAGE ... --model or --dmp, not both")
    if not args.dmp and not args.images:
        raise ValueError("nothing to write: give IMAGE ... --model CKPT, or --dmp params.json")
    if args.images and not args.model:
        raise ValueError("IMAGE input needs --model CKPT (a trained network)")
    inputs = [args.dmp] if args.dmp else list(args.images)
    _args.check_inputs(inputs, "--dmp file" if args.dmp else "image")
    images = list(args.images) + ([args.image] if args.image else [])
    _args.check_inputs(images, "image")
    _args.check_images(images)
    _args.check_output_dir(args.out_dir, "--out-dir")
    suffixes = ["_paper.png", "_render.png", "_log.csv"] + ([".gif"] if args.video else [])
    outputs = [
        (os.path.join(args.out_dir, _name(path) + suffix), path)
        for path in inputs
        for suffix in suffixes
    ]
    _args.check_outputs(outputs, args.force)


def _read_image(path):
    """The ``--image`` file as ``float32 [H, W]`` in [0, 1], ink = 1."""
    import numpy as np
    from PIL import Image

    with _args.reading_image(path), Image.open(path) as im:
        a = np.asarray(im.convert("L"), dtype=np.float32) / 255.0
    # Show ink dark whatever the file's polarity: ink is the minority of pixels.
    return a if a.mean() < 0.5 else 1.0 - a


def run(args) -> int:
    from img2dmp.robot import available
    from img2dmp.robot._pybullet import INSTALL_HINT

    if not available():
        print(f"img2dmp write: error: {INSTALL_HINT}", file=sys.stderr)
        return 2
    from img2dmp._progress import bar as progress_bar
    from img2dmp.robot import (
        ControllerConfig,
        SceneConfig,
        plot_writing,
        save_log_csv,
        save_render,
        save_video,
        write_dmp,
    )

    if args.frame_interval_s <= 0:
        raise ValueError(f"--frame-interval-s must be > 0, got {args.frame_interval_s}")
    check_files(args)
    scene_cfg = SceneConfig(paper_center_m=tuple(args.center_m))
    ctl_cfg = ControllerConfig(force_set_n=args.force_n)
    os.makedirs(args.out_dir, exist_ok=True)
    for name, params, config, size, image in _inputs(args):
        est_steps = int((float(params.tau) + 2.0) * args.rate_hz)
        with progress_bar(
            total=est_steps, unit="step", desc=f"writing {name}", enabled=not args.no_progress
        ) as bar:
            try:
                result = write_dmp(
                    params,
                    config,
                    size,
                    writing_height_mm=args.writing_height_mm,
                    control_rate_hz=args.rate_hz,
                    scene_config=scene_cfg,
                    controller_config=ctl_cfg,
                    frame_interval_s=args.frame_interval_s if args.video else None,
                    progress=bar.update,
                )
            except RuntimeError as e:  # the simulated arm failed (e.g. never settled)
                print(f"img2dmp write: {name}: simulation failed: {e}", file=sys.stderr)
                return 1
            bar.total = bar.n
        base = os.path.join(args.out_dir, name)
        plot_writing(result, base + "_paper.png", image=image, title=f"{name}: KUKA iiwa writes")
        save_render(result, base + "_render.png")
        save_log_csv(result, base + "_log.csv")
        written = [base + s for s in ("_paper.png", "_render.png", "_log.csv")]
        if args.video:
            save_video(result, base + ".gif", args.frame_interval_s)
            written.append(base + ".gif")
        m = result.metrics
        print(
            f"{name}: tracking error {m['tracking_error_mean_mm']:.3f} mm mean, "
            f"{m['tracking_error_max_mm']:.3f} mm max; contact force "
            f"{m['force_mean_n']:.3f} ± {m['force_std_n']:.3f} N (set {m['force_set_n']:g} N), "
            f"within ±20 % {100 * m['force_in_band_share']:.1f} % and in contact "
            f"{100 * m['contact_share']:.1f} % of the pen-down time; "
            f"{m['simulated_s']:.2f} s simulated at {m['control_rate_hz']:g} Hz, "
            f"{m['real_time_factor']:.1f}x real time"
        )
        print("  wrote " + ", ".join(written))
    return 0
