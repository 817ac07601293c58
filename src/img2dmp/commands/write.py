"""Write a digit with a simulated KUKA LBR iiwa (pybullet): joint-torque control, IK in the
plane and an admittance loop holding the pen's contact force.

Input is either images and a trained model (``IMAGE ... --model CKPT``) or one DMP file
(``--dmp params.json``: the one DMP file of img2dmp, e.g. ``NAME_dmp.json`` of
``img2dmp predict --out``; format in docs/ROBOT.md). The robot writes the top hypothesis,
or the one of rank ``--hypothesis K``, in the frame of the file's ``image_size`` (for a
prediction: the model's input, whose height is ``--writing-height-mm``). An
``img2dmp predict`` record from before the format's version 2 does not store the model's
input size: give it with ``--image-size H W``. For each input it writes
``NAME_paper.png`` (the ink next to the commanded path and the input), ``NAME_render.png``
(camera: the arm at the end | the paper), ``NAME_log.csv`` (joint positions and velocities
included), with ``--video`` ``NAME.gif`` and, where imageio-ffmpeg is installed,
``NAME.mp4``, with ``--export-joints FILE`` the joint trajectory as ``FILE.csv`` and
``FILE.json`` (``FILE_NAME.*`` for several inputs; checked against the iiwa's joint
limits), and prints tracking-error, contact-force and per-stroke ink metrics. NAME is the input
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
    parser.add_argument(
        "--hypothesis",
        metavar="K",
        type=_args.int_at_least(1),
        default=1,
        help="write the hypothesis of rank K (1 = the most probable, the default) of a "
        "network with several, or of a DMP file that lists several",
    )
    parser.add_argument(
        "--image-size",
        metavar=("H", "W"),
        type=_args.int_at_least(1),
        nargs=2,
        help="with --dmp: the model's input size, for an img2dmp predict record from "
        "before version 2 of the DMP file (which does not store it)",
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
    parser.add_argument(
        "--video",
        action="store_true",
        help="also write the video: an animated GIF, and an MP4 where imageio-ffmpeg is installed",
    )
    parser.add_argument(
        "--export-joints",
        metavar="FILE",
        help="also write the joint trajectory (time, 7 joint positions and velocities) as "
        "FILE.csv and FILE.json for a real iiwa to replay; refused if it exceeds the "
        "iiwa's joint position or velocity limits",
    )
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
        size = tuple(args.image_size) if args.image_size else None
        params, config, size = load_dmp_json(args.dmp, hypothesis=args.hypothesis, image_size=size)
        image = _read_image(args.image) if args.image else None
        return [(_name(args.dmp), params, config, size, image)]
    from img2dmp.predict import Predictor

    predictor = Predictor.load(args.model)
    if args.refine:
        from img2dmp.nn.refine import RefineOptions

        predictor.refine_options = RefineOptions(steps=args.refine)
    k, n = args.hypothesis, predictor.n_hypotheses
    if k > n:
        raise ValueError(
            f"--hypothesis {k}: the model proposes {n} hypothes{'i' if n == 1 else 'e'}s "
            f"per image (ranks 1..{n})"
        )
    config = predictor.dmp_config
    out = []
    for path in args.images:
        with _args.reading_image(path):
            image = np.asarray(predictor.prepare(path)[0], dtype=np.float32)
        if k == 1:  # the top one alone (refined alone)
            params = predictor.predict_images(image[None])[0]
        else:
            params = predictor.predict_hypotheses(image[None])[0][0, k - 1]
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
    if args.image_size and not args.dmp:
        raise ValueError("--image-size is for --dmp files (old img2dmp predict records)")
    inputs = [args.dmp] if args.dmp else list(args.images)
    _args.check_inputs(inputs, "--dmp file" if args.dmp else "image")
    images = list(args.images) + ([args.image] if args.image else [])
    _args.check_inputs(images, "image")
    _args.check_images(images)
    _args.check_output_dir(args.out_dir, "--out-dir")
    suffixes = ["_paper.png", "_render.png", "_log.csv"] + ([".gif"] if args.video else [])
    suffixes += [".mp4"] if args.video and _mp4_available() else []
    outputs = [
        (os.path.join(args.out_dir, _name(path) + suffix), path)
        for path in inputs
        for suffix in suffixes
    ]
    if args.export_joints:
        from img2dmp.robot.joints import export_paths

        for path in inputs:
            base = _joints_base(args, _name(path), len(inputs))
            outputs += [(f, path) for f in export_paths(base)]
    read = [("--dmp file" if args.dmp else "image", path) for path in inputs]
    read += [("image", args.image)] if args.image else []
    _args.check_outputs(outputs, args.force, read + _args.model_inputs(args.model))


def _mp4_available() -> bool:
    from img2dmp.robot.animation import mp4_available

    return mp4_available()


def _joints_base(args, name: str, n_inputs: int) -> str:
    """``--export-joints FILE`` for input ``name``: FILE (its .csv/.json suffix dropped),
    or ``FILE_NAME`` when there are several inputs."""
    root, ext = os.path.splitext(args.export_joints)
    base = root if ext.lower() in (".csv", ".json") else args.export_joints
    return base if n_inputs == 1 else f"{base}_{name}"


def _read_image(path):
    """The ``--image`` file as ``float32 [H, W]`` in [0, 1], ink = 1, read as ``predict``
    reads images (upright, transparency on white, either polarity, 8 or 16 bits)."""
    from img2dmp.data.images import ink_view

    with _args.reading_image(path):
        return ink_view(path, max_side=1024)[0]


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
        save_videos,
        summary_lines,
        write_dmp,
    )

    if args.frame_interval_s <= 0:
        raise ValueError(f"--frame-interval-s must be > 0, got {args.frame_interval_s}")
    check_files(args)
    scene_cfg = SceneConfig(paper_center_m=tuple(args.center_m))
    ctl_cfg = ControllerConfig(force_set_n=args.force_n)
    for name, params, config, size, image in _inputs(args):
        os.makedirs(args.out_dir, exist_ok=True)  # once the first input is read and checked
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
            written += save_videos(result, base, args.frame_interval_s)
        if args.export_joints:
            from img2dmp.robot.joints import JointTrajectory, save_joint_trajectory

            n_inputs = len(args.images) or 1
            trajectory = JointTrajectory.from_result(result)
            written += save_joint_trajectory(trajectory, _joints_base(args, name, n_inputs))
        print("\n".join(summary_lines(name, result)))
        print("  wrote " + ", ".join(written))
    return 0
