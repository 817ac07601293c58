"""Write a digit with a simulated KUKA LBR iiwa (pybullet): joint-torque control, IK in the
plane and an admittance loop holding the pen's contact force.

Input is either images and a trained model (``IMAGE ... [--model RUN|NAME]``; without
``--model`` the shipped model digits-real, refined as its card recommends) or one DMP file
(``--dmp params.json``: the one DMP file of img2dmp, e.g. ``NAME_dmp.json`` of
``img2dmp predict --out``; format in docs/ROBOT.md). The robot writes the top hypothesis,
or the one of rank ``--hypothesis K``, in the frame of the file's ``image_size`` (for a
prediction: the model's input, whose height is ``--writing-height-mm``). An
``img2dmp predict`` record from before the format's version 2 does not store the model's
input size: give it with ``--image-size H W``. A stroke model's ``NAME_dmp.json`` (format
``img2dmp-strokes``) is written stroke by stroke, as ``IMAGE --model`` writes it. For
each input it writes
``NAME_paper.png`` (the ink next to the commanded path and the input), ``NAME_render.png``
(camera: the arm at the end | the paper), ``NAME_log.csv`` (joint positions and velocities
included), with ``--video`` ``NAME.gif`` and, where imageio-ffmpeg is installed,
``NAME.mp4``, with ``--export-joints FILE`` the joint trajectory as ``FILE.csv`` and
``FILE.json`` (``FILE_NAME.*`` for several inputs; checked against the iiwa's joint
limits; ``--joints reference``, the default, or ``measured``), and prints
tracking-error, contact-force and per-stroke ink metrics. NAME is the input file's name
without its extension: two inputs of one name are refused, naming both, and files
already in ``--out-dir`` are replaced only with ``--force``; both are checked before the
simulation starts. An image the model reads with flags (several characters, unfamiliar,
off the ink: as ``img2dmp predict`` says) gets predict's one-line warning on stderr
before the arm writes it.

``--page`` writes a whole page in one run (:mod:`img2dmp.robot.page`): ``PAGE.json
--page`` a page document (``img2dmp predict PHOTO --page`` writes one), ``PHOTO --page
--model RUN [--refine N]`` the page the model reads in the photo
(``Predictor.predict_page``). The characters' boxes together are written
``--width-mm`` wide (aspect kept, centred on the paper), in reading order, the pen
lifted and travelling between characters; ``--skip-flagged`` leaves out the characters
with flags, ``--skip-flags FLAGS`` those with any of these. The outputs are those of
one DMP for the whole page (one log, one joint trajectory, one video) plus
``NAME_characters.csv``, one row of measures per character and the page's totals; NAME
is the page document's or the photo's name.
``--goal X,Y``, ``--start X,Y``, ``--shift DX,DY``, ``--scale S``, ``--rotate DEG`` and
``--tempo K`` bend the DMP before the arm writes it (:func:`img2dmp.dmp.bend_dmp`; which
changes are exact and which change the shape: docs/DMP.md, "Bending a DMP"). Positions are
pixels of the frame the DMP is written in (that of its ``image_size``; for ``IMAGE
--model`` the model's input), as the left panel of ``NAME_paper.png`` shows them.
Needs the optional extra: ``pip install -e '/path/to/img2dmp[robot]'``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

from . import _args

HELP = "write a digit or a page with a simulated KUKA arm (pybullet) and measure how well it went"
DEFAULT_WRITING_HEIGHT_MM = 40.0
DEFAULT_PAGE_WIDTH_MM = 160.0  # img2dmp.robot.page.DEFAULT_WIDTH_MM (not imported: no NumPy here)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "images",
        nargs="*",
        metavar="IMAGE",
        help="image(s) of a digit; with --page one page document (PAGE.json) or, with "
        "--model, one photo of a page",
    )
    _args.add_model(
        parser,
        help="trained network that reads IMAGE: run directory, checkpoint or the name of a "
        f"model shipped with img2dmp (default: the shipped model {_args.DEFAULT_MODEL_NAME})",
    )
    parser.add_argument(
        "--dmp",
        metavar="JSON",
        help="a DMP file to write (instead of IMAGE): one DMP, or a stroke model's prediction",
    )
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
        "--writing-height-mm",
        type=float,
        default=None,
        help=f"height of the image on paper (default {DEFAULT_WRITING_HEIGHT_MM:g}; not with "
        "--page, which --width-mm scales)",
    )
    _add_page_arguments(parser)
    _add_bend_arguments(parser)
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
    _add_joint_arguments(parser)
    parser.add_argument(
        "--frame-interval-s", type=float, default=0.1, help="simulated time between frames"
    )
    _args.add_refine(parser)
    _args.add_count_views(parser)
    _args.add_backend(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _add_joint_arguments(parser: argparse.ArgumentParser) -> None:
    """``--export-joints``, ``--joints``, ``--no-slowing``, ``--acceleration-share``: the
    motion for a real iiwa."""
    parser.add_argument(
        "--export-joints",
        metavar="FILE",
        help="also write the joint trajectory (time, 7 joint positions and velocities) as "
        "FILE.csv and FILE.json for a real iiwa to replay; if it exceeds the iiwa's joint "
        "position or velocity limits, nothing of that input is written (accelerations over "
        "the 10 rad/s^2 planning limit: a warning)",
    )
    parser.add_argument(
        "--joints",
        choices=("reference", "measured"),
        default=None,
        help="with --export-joints, which joint positions are written: 'reference' (the "
        "default), the controller's inverse kinematics of the commanded pen path, at the "
        "depth the simulated pen pressed to, for a position-controlled iiwa; 'measured', "
        "the simulated torque-controlled arm's joints after each step",
    )
    parser.add_argument(
        "--no-slowing",
        action="store_true",
        help="write each DMP at its own tempo even where a real iiwa's joints could not "
        "follow it (default: a DMP whose planned joint speeds exceed 60 %% of the iiwa's "
        "limits, or whose planned joint accelerations exceed --acceleration-share of the "
        "10 rad/s^2 planning limit, is written that much slower, the same path, with a "
        "note)",
    )
    parser.add_argument(
        "--acceleration-share",
        type=float,
        default=None,
        metavar="SHARE",
        help="keep the joint accelerations planned along each DMP within this share, in "
        "(0, 1], of 10 rad/s^2 per joint (a planning limit of the iiwa 14 in wide use; "
        "KUKA publishes none; default 0.6, room for the arm's own transients); not with "
        "--no-slowing",
    )


def _add_page_arguments(parser: argparse.ArgumentParser) -> None:
    """``--page``, ``--width-mm``, ``--skip-flagged``, ``--skip-flags``: a whole page."""
    parser.add_argument(
        "--page",
        action="store_true",
        help="write a whole page: IMAGE is a page document (PAGE.json, from img2dmp predict "
        "--page), or with --model a photo whose characters the model reads",
    )
    parser.add_argument(
        "--width-mm",
        type=_args.positive_float,
        default=None,
        help=f"with --page: width on paper of the page's characters (the union of their "
        f"boxes, aspect kept; default {DEFAULT_PAGE_WIDTH_MM:g}, or the widest that fits the "
        "sheet if narrower); a width given is refused if the page does not fit the sheet or "
        "the arm's reach",
    )
    parser.add_argument(
        "--skip-flagged",
        action="store_true",
        help="with --page: do not write the characters that have flags (e.g. off_ink); "
        "the others keep their places",
    )
    parser.add_argument(
        "--skip-flags",
        metavar="FLAGS",
        help="with --page: do not write the characters that have any of these flags (e.g. "
        "off_ink,unexplained_ink: those only unfamiliar are written)",
    )


#: The options that bend the DMP, by the keyword of :func:`img2dmp.dmp.bend_dmp`.
BEND_OPTIONS = {"goal": "--goal", "start": "--start", "shift": "--shift", "scale": "--scale",
                "rotate_deg": "--rotate", "tempo": "--tempo"}  # fmt: skip


def _add_bend_arguments(parser: argparse.ArgumentParser) -> None:
    """``--goal``, ``--start``, ``--shift``, ``--scale``, ``--rotate``, ``--tempo``."""
    group = parser.add_argument_group(
        "bending the DMP (docs/DMP.md, 'Bending a DMP'; positions in pixels of the DMP's "
        "frame, x = column, y = row, e.g. --shift -5,3)"
    )
    point = _args.point
    group.add_argument(
        "--goal",
        type=point,
        metavar="X,Y",
        help="a new goal (the weights kept: with the paper's diag(g - y0) "
        "scaling the path stretches per axis, without scaling it bends)",
    )
    group.add_argument(
        "--start", type=point, metavar="X,Y", help="a new start (the weights and the goal kept)"
    )
    group.add_argument(
        "--shift", type=point, metavar="DX,DY", help="move the whole movement (exact)"
    )
    group.add_argument(
        "--scale",
        type=_args.positive_float,
        metavar="S",
        help="scale the movement about its start (exact)",
    )
    group.add_argument(
        "--rotate",
        dest="rotate_deg",
        type=_args.finite_float,
        metavar="DEG",
        help="turn the movement about its start, degrees from the x axis "
        "toward the y axis: clockwise as seen in an image (exact)",
    )
    group.add_argument(
        "--tempo",
        type=_args.positive_float,
        metavar="K",
        help="the same path K times as fast (K = 0.5: half as fast; exact)",
    )


def bend_options(args) -> dict:
    """The bending asked for, as keywords of :func:`img2dmp.dmp.bend_dmp` (empty: none)."""
    return {k: getattr(args, k) for k in BEND_OPTIONS if getattr(args, k, None) is not None}


def _bent(args, name: str, params, config):
    """``params`` bent as the options say, and the line saying so (None: not bent)."""
    options = bend_options(args)
    if not options:
        return params, None
    from img2dmp.dmp import bend_dmp

    bent = bend_dmp(params, config, **options)
    asked = " ".join(f"{BEND_OPTIONS[k]} {_written(v)}" for k, v in options.items())
    g, y0 = bent.g, bent.y0
    line = (
        f"  {name}: bent ({asked}): start ({y0[0]:.2f}, {y0[1]:.2f}) px, goal "
        f"({g[0]:.2f}, {g[1]:.2f}) px, tau {float(params.tau):.3f} -> {float(bent.tau):.3f} s"
    )
    return bent, line


def _written(v) -> str:
    """An option's value as it would be written: ``12,30`` or ``1.5``."""
    return ",".join(f"{x:g}" for x in v) if isinstance(v, tuple) else f"{v:g}"


def _inputs(args, predictor=None) -> list[tuple[str, object, object, tuple, object]]:
    """(name, params, config, image_size, image or None) for every input (images read
    by ``predictor``, else by :func:`_predictor`'s)."""
    import numpy as np

    from img2dmp.robot import load_dmp_json

    if args.dmp:
        size = tuple(args.image_size) if args.image_size else None
        params, config, size = load_dmp_json(args.dmp, hypothesis=args.hypothesis, image_size=size)
        image = _read_image(args.image) if args.image else None
        return [(_name(args.dmp), params, config, size, image)]
    predictor = predictor or _predictor(args)
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
            pred = predictor.predict(path)  # the one reading predict gives, flags and all
        _args.warn_flags("write", path, pred)
        image = np.asarray(pred.image, dtype=np.float32)
        params = pred.params[k - 1]  # ranked; the top one refined alone
        out.append((_name(path), params, config, tuple(image.shape[-2:]), image))
    return out


def _predictor(args):
    """The network of ``--model``, refined as ``--refine`` says (or as a shipped model's
    card recommends), a stroke model's count read from ``--count-views`` views."""
    from img2dmp.predict import Predictor

    _args.one_thread()
    predictor = Predictor.load(args.model, backend=args.backend)
    _args.set_count_views(args, predictor)
    _args.set_refinement(args, args.model, predictor, "write")
    return predictor


def _default_model(args) -> None:
    """Images without ``--model`` are read by the default shipped model (a page document,
    ``PAGE.json --page``, and ``--dmp`` need no model)."""
    if args.model or args.dmp or not args.images:
        return
    if args.page and args.images[0].lower().endswith(".json"):
        return
    args.model = _args.model_or_default(None)


def _name(path) -> str:
    return os.path.splitext(os.path.basename(path))[0]


def _check_export_joints(given) -> None:
    """``--export-joints FILE`` names a file to write beside others (FILE.csv, FILE.json):
    not nothing, not a directory (``DIR/`` wrote the hidden ``DIR/.csv``)."""
    if given is None:
        return
    base = os.path.splitext(given)[0] if given.lower().endswith((".csv", ".json")) else given
    if not os.path.basename(base) or os.path.isdir(given):
        what = "an empty name" if not given else f"{given!r}, a directory"
        raise ValueError(f"--export-joints needs a file name (FILE: FILE.csv and FILE.json "
                         f"are written), got {what}")  # fmt: skip


def check_files(args) -> None:
    """The inputs (there, readable, images that open) and the outputs (the overwrite rule,
    one name per input), before anything is loaded or simulated."""
    _default_model(args)
    _check_export_joints(args.export_joints)
    if getattr(args, "joints", None) is not None and not args.export_joints:
        raise ValueError("--joints chooses what --export-joints writes; give --export-joints FILE")
    if args.no_slowing and getattr(args, "acceleration_share", None) is not None:
        raise ValueError("--acceleration-share is for the slowing; not with --no-slowing")
    _joint_acceleration_share(args)
    if args.page:
        _check_page_files(args)
        return
    for given, flag in (
        (args.width_mm is not None, "--width-mm"),
        (args.skip_flagged, "--skip-flagged"),
        (args.skip_flags is not None, "--skip-flags"),
    ):
        if given:
            raise ValueError(f"{flag} is for --page (a whole page)")
    if args.dmp and args.images:
        raise ValueError("give either IMAGE ... --model or --dmp, not both")
    if not args.dmp and not args.images:
        raise ValueError("nothing to write: give IMAGE ... [--model RUN], or --dmp params.json")
    if args.image_size and not args.dmp:
        raise ValueError("--image-size is for --dmp files (old img2dmp predict records)")
    inputs = [args.dmp] if args.dmp else list(args.images)
    _args.check_inputs(inputs, "--dmp file" if args.dmp else "image")
    images = list(args.images) + ([args.image] if args.image else [])
    _args.check_inputs(images, "image")
    _args.check_images(images)
    _args.check_output_dir(args.out_dir, "--out-dir")
    suffixes = _output_suffixes(args, False)
    args.stroke_doc = _stroke_document(args.dmp) if args.dmp else None  # read once, here
    if args.stroke_doc is not None:
        suffixes.append("_strokes.csv")
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


def _output_suffixes(args, page: bool) -> list[str]:
    suffixes = ["_paper.png", "_render.png", "_log.csv"] + (["_characters.csv"] if page else [])
    suffixes += [".gif"] if args.video else []
    return suffixes + ([".mp4"] if args.video and _mp4_available() else [])


def _check_page_files(args) -> None:
    """``--page``: one page document, or one photo with ``--model``; the options of one
    DMP refused; the outputs checked."""
    if len(args.images) != 1 or args.dmp:
        raise ValueError("--page writes one page: give PAGE.json, or PHOTO --model RUN")
    bent = [BEND_OPTIONS[k] for k in bend_options(args)]
    refused = (
        (bent, f"{', '.join(bent)} bend one DMP, not a page (--page)"),
        (args.image, "--image is for --dmp (the page's photo is the document's image)"),
        (args.image_size, "--image-size is for --dmp files, not for --page"),
        (args.hypothesis != 1, "--hypothesis is not for --page: it writes each character's "
                               "top hypothesis"),
        (args.writing_height_mm is not None, "--writing-height-mm is not for --page: "
                                             "--width-mm scales a page"),
        (args.refine and not args.model, "--refine refines what --model reads in a photo; "
                                         "a page document is written as it is"),
        (args.refine_unfamiliar is not None and not args.model,
         "--refine-unfamiliar refines what --model reads in a photo; a page document is "
         "written as it is"),
    )  # fmt: skip
    for given, message in refused:
        if given:
            raise ValueError(message)
    source = args.images[0]
    _args.check_inputs([source], "photo" if args.model else "page document")
    if args.model:
        _args.check_images([source])
    _args.check_output_dir(args.out_dir, "--out-dir")
    name = _name(source)
    outputs = [(os.path.join(args.out_dir, name + s), source) for s in _output_suffixes(args, True)]
    if args.export_joints:
        from img2dmp.robot.joints import export_paths

        outputs += [(f, source) for f in export_paths(_joints_base(args, name, 1))]
    _args.check_outputs(outputs, args.force)


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
    _args.one_thread()  # first: before NumPy is imported, so that OpenBLAS takes it too
    from img2dmp.robot import available
    from img2dmp.robot._pybullet import INSTALL_HINT

    if not available():
        print(f"img2dmp write: error: {INSTALL_HINT}", file=sys.stderr)
        return 2
    from img2dmp.robot import ControllerConfig, SceneConfig

    if args.frame_interval_s <= 0:
        raise ValueError(f"--frame-interval-s must be > 0, got {args.frame_interval_s}")
    check_files(args)
    scene_cfg = SceneConfig(paper_center_m=tuple(args.center_m))
    ctl_cfg = ControllerConfig(force_set_n=args.force_n)
    if args.page:
        return _run_page(args, scene_cfg, ctl_cfg)
    return _run_dmps(args, scene_cfg, ctl_cfg)


def _run_dmps(args, scene_cfg, ctl_cfg) -> int:
    """One run per input DMP (``IMAGE ... --model``, ``--dmp``)."""
    from img2dmp._progress import bar as progress_bar
    from img2dmp.robot import plot_writing, summary_lines, write_dmp
    from img2dmp.robot.outputs import writing_warnings

    height_mm = args.writing_height_mm
    height_mm = DEFAULT_WRITING_HEIGHT_MM if height_mm is None else height_mm
    if getattr(args, "stroke_doc", None) is not None:  # check_files read it
        return _run_stroke_document(args, scene_cfg, ctl_cfg, args.stroke_doc)
    predictor = None if args.dmp else _predictor(args)
    if getattr(predictor, "strokes", None) is not None:
        return _run_strokes(args, scene_cfg, ctl_cfg, predictor)
    for name, params, config, size, image in _inputs(args, predictor):
        params, bent_line = _bent(args, name, params, config)
        if bent_line:
            print(bent_line)
        est_steps = int((float(params.tau) + 2.0) * args.rate_hz)
        with progress_bar(
            total=est_steps, unit="step", desc=f"writing {name}", enabled=not args.no_progress
        ) as bar:

            def on_tempo(tau_s: float, bar=bar) -> None:  # slowed: a longer run
                bar.total = int((tau_s + 2.0) * args.rate_hz)

            try:
                result = write_dmp(
                    params,
                    config,
                    size,
                    writing_height_mm=height_mm,
                    control_rate_hz=args.rate_hz,
                    scene_config=scene_cfg,
                    controller_config=ctl_cfg,
                    frame_interval_s=args.frame_interval_s if args.video else None,
                    joint_speed_share=_joint_speed_share(args),
                    joint_acceleration_share=_joint_acceleration_share(args),
                    progress=bar.update,
                    on_tempo=on_tempo,
                )
            except RuntimeError as e:  # the simulated arm failed (e.g. never settled)
                print(f"img2dmp write: {name}: simulation failed: {e}", file=sys.stderr)
                return 1
            bar.total = bar.n
        if result.slowing is not None and result.slowing.slowed:
            _note(f"{name}: written {result.slowing.words()}; {SLOWING_WHY}")
        print("\n".join(summary_lines(name, result)))
        for warning in writing_warnings(result):
            print(f"img2dmp write: warning: {name}: {warning}", file=sys.stderr)
        n_inputs = len(args.images) or 1
        trajectory = _joint_trajectory(args, result, name, n_inputs)  # before any file
        os.makedirs(args.out_dir, exist_ok=True)  # once written: a refusal leaves no folder
        base = os.path.join(args.out_dir, name)
        plot_writing(result, base + "_paper.png", image=image, title=f"{name}: KUKA iiwa writes")
        written = [base + "_paper.png"] + _save_run(args, result, name, n_inputs, trajectory)
        print("  wrote " + ", ".join(written))
    return 0


#: Why a note says a DMP was slowed, and how not to.
SLOWING_WHY = ("slowed so that a real iiwa's joints can follow (planned within 60 % of "
               "their speed limits, their accelerations within --acceleration-share, default "
               "0.6, of 10 rad/s^2; --no-slowing: the DMP's own tempo)")  # fmt: skip


def _note(text: str) -> None:
    print(f"img2dmp write: note: {text}", file=sys.stderr)


def _joint_speed_share(args):
    """The share of the iiwa's joint speed limits the planned motion is kept within
    (:data:`img2dmp.robot.tempo.JOINT_SPEED_SHARE`), or None with ``--no-slowing``."""
    from img2dmp.robot.tempo import JOINT_SPEED_SHARE

    return None if args.no_slowing else JOINT_SPEED_SHARE


def _joint_acceleration_share(args):
    """``--acceleration-share`` (default :data:`img2dmp.robot.tempo.JOINT_ACCELERATION_SHARE`),
    or None with ``--no-slowing``; ``ValueError`` for a share not in (0, 1]."""
    from img2dmp.robot.tempo import JOINT_ACCELERATION_SHARE

    share = getattr(args, "acceleration_share", None)
    if args.no_slowing:
        return None
    if share is None:
        return JOINT_ACCELERATION_SHARE
    if not (math.isfinite(share) and 0.0 < share <= 1.0):
        raise ValueError(f"--acceleration-share must be in (0, 1], got {share:g}")
    return share


def _joint_trajectory(args, result, name: str, n_inputs: int):
    """With ``--export-joints``, the run's joint trajectory, checked against the iiwa's
    limits before any file of this input is written (``ValueError`` saying that nothing
    of it was), its accelerations against the planning limit (a warning line); None
    without."""
    if not args.export_joints:
        return None
    from img2dmp.robot.joints import JointTrajectory, export_paths

    trajectory = JointTrajectory.from_result(result, getattr(args, "joints", None) or "reference")
    violation = trajectory.limit_violation()
    if violation is not None:
        json_path = export_paths(_joints_base(args, name, n_inputs))[1]
        hint = "" if not args.no_slowing else "; without --no-slowing the DMP is slowed to fit"
        raise ValueError(
            f"{json_path}: joint trajectory: {violation}; nothing of {name} written (no "
            f"joint trajectory, figure, log or video){hint}"
        )
    over = trajectory.acceleration_violation()
    if over is not None:  # a planning limit, not the hardware's: said, not refused
        json_path = export_paths(_joints_base(args, name, n_inputs))[1]
        print(f"img2dmp write: warning: {json_path}: joint trajectory: {over}; written all "
              "the same (a planning limit, not KUKA's)", file=sys.stderr)  # fmt: skip
    return trajectory


def _save_run(args, result, name: str, n_inputs: int, trajectory=None) -> list[str]:
    """The render, the log, the video and the joint trajectory (checked already:
    :func:`_joint_trajectory`) of a run; the files."""
    from img2dmp.robot import save_log_csv, save_render, save_videos

    base = os.path.join(args.out_dir, name)
    save_render(result, base + "_render.png")
    save_log_csv(result, base + "_log.csv")
    written = [base + "_render.png", base + "_log.csv"]
    if args.video:
        written += save_videos(result, base, args.frame_interval_s)
    if trajectory is not None:
        from img2dmp.robot.joints import save_joint_trajectory

        written += save_joint_trajectory(trajectory, _joints_base(args, name, n_inputs))
    return written


def _page_input(args):
    """``(name, page, photo view or None)``: the page document, or the page the model
    reads in the photo (``Predictor.predict_page(PHOTO).to_document()``)."""
    import json

    from img2dmp.robot import check_page_document, read_page

    source = args.images[0]
    if not args.model:
        page = read_page(source)
        return _name(source), page, _page_photo(page, os.path.dirname(source))
    predictor = _predictor(args)
    with _args.reading_image(source):
        read = predictor.predict_page(source)
    skipping = args.skip_flagged or args.skip_flags is not None
    _args.warn_page("write", source, read,
                    "" if skipping else " (written; --skip-flagged leaves them out)")  # fmt: skip
    document = read.to_document()
    try:  # checked as the file `img2dmp predict --page` would write would be read
        document = json.loads(json.dumps(document))
    except (TypeError, ValueError) as e:
        raise ValueError(f"{source}: the model's page document is not plain JSON: {e}") from e
    page = check_page_document(document, f"{source} (the page read by {args.model})")
    return _name(source), page, _photo_view(source)


def _photo_view(path):
    """The photo as ink levels for the figure (reduced; any size spans the photo's
    frame in the figure), or None if it cannot be shown: it is only a picture."""
    from img2dmp.data.images import ink_view

    try:
        with _args.reading_image(path):
            return ink_view(path, max_side=2048)[0]
    except ValueError:  # e.g. a page without ink: the figure says "no photo"
        return None


def _page_photo(page, directory: str):
    """The page document's photo for the figure, if it is there (as given, or next to
    the document) and of the page's size; else None (the figure says so)."""
    if page.image is None:
        return None
    from PIL import Image

    from img2dmp.data.images import shown_size

    for path in (page.image, os.path.join(directory, page.image)):
        if not os.path.isfile(path):
            continue
        try:
            with Image.open(path) as im:
                h, w = shown_size(im)
        except (OSError, ValueError, Image.DecompressionBombError):
            return None
        return _photo_view(path) if (w, h) == tuple(page.image_size_px) else None
    return None


def _writing_options(args, scene_cfg, ctl_cfg):
    from img2dmp.robot import WritingOptions

    return WritingOptions(
        control_rate_hz=args.rate_hz,
        scene_config=scene_cfg,
        controller_config=ctl_cfg,
        frame_interval_s=args.frame_interval_s if args.video else None,
        joint_speed_share=_joint_speed_share(args),
        joint_acceleration_share=_joint_acceleration_share(args),
    )


def _run_page(args, scene_cfg, ctl_cfg) -> int:
    """``--page``: every character of one page in one run."""
    from img2dmp.robot import plan_page

    options = _writing_options(args, scene_cfg, ctl_cfg)
    name, page, photo = _page_input(args)
    plan = plan_page(page, options, width_mm=args.width_mm, skip_flagged=_skip_flags(args))
    if args.width_mm is None and plan.width_mm < DEFAULT_PAGE_WIDTH_MM:
        print(f"img2dmp write: note: {name} is written {plan.width_mm:g} mm wide, the widest "
              f"that fits the sheet (default {DEFAULT_PAGE_WIDTH_MM:g} mm; --width-mm to choose)",
              file=sys.stderr)  # fmt: skip
    what, noun = plan.words()  # a stroke model's page: each entry a stroke
    return _write_plan(args, name, plan, photo, what, "_characters.csv", noun)


def _skip_flags(args) -> bool | tuple[str, ...]:
    """``--skip-flagged`` (True: any flag), or ``--skip-flags`` (these names), or False."""
    given = args.skip_flags
    if given is None:
        return args.skip_flagged
    if args.skip_flagged:
        raise ValueError("give --skip-flagged (any flag) or --skip-flags FLAGS, not both")
    names = tuple(n.strip() for n in given.split(","))
    if not all(names):
        raise ValueError(f"--skip-flags takes flag names separated by commas, got {given!r}")
    return names


def _run_strokes(args, scene_cfg, ctl_cfg, predictor) -> int:
    """A stroke model's characters, one run each: its strokes as a page of one line
    (:meth:`img2dmp.predict.StrokePrediction.to_page_document`), the pen lifted
    :data:`img2dmp.robot.page.STROKE_LIFT_M` between them, at the scale of
    ``--writing-height-mm`` for the model's frame (as a one-DMP model's digit)."""
    import numpy as np

    from img2dmp.robot import check_page_document

    _refuse_one_dmp_options(args, f"{args.model} is a stroke model")
    outputs = [(os.path.join(args.out_dir, _name(p) + "_strokes.csv"), p) for p in args.images]
    _args.check_outputs(outputs, args.force, _args.model_inputs(args.model))
    options = _writing_options(args, scene_cfg, ctl_cfg)
    for path in args.images:
        with _args.reading_image(path):
            pred = predictor.predict(path)
        _args.warn_flags("write", path, pred)
        where = f"{path} (the strokes read by {args.model})"
        page = check_page_document(pred.to_page_document(), where)
        image = np.asarray(pred.image, dtype=np.float32)
        code = _write_stroke_page(args, options, _name(path), page, image)
        if code:
            return code
    return 0


def _refuse_one_dmp_options(args, why: str) -> None:
    if bend_options(args) or args.hypothesis != 1:
        what = "bending" if bend_options(args) else "--hypothesis"
        raise ValueError(f"{what} is for one-DMP models; {why}")


def _write_stroke_page(args, options, name: str, page, image) -> int:
    """One character's strokes (a page of one line in the model's frame) at the scale of
    ``--writing-height-mm`` for that frame, the pen lifted between strokes."""
    from img2dmp.robot import plan_page
    from img2dmp.robot.page import STROKE_LIFT_M

    height_mm = args.writing_height_mm
    height_mm = DEFAULT_WRITING_HEIGHT_MM if height_mm is None else height_mm
    x0, _, x1, _ = page.written_area_px
    width_mm = height_mm * (x1 - x0) / page.image_size_px[1]
    travel_m = options.controller_config.lift_height_m + STROKE_LIFT_M
    plan = plan_page(page, options, width_mm=width_mm, travel_height_m=travel_m)
    n = len(page.characters)
    return _write_plan(args, name, plan, image, f"{n} stroke{'s' if n > 1 else ''}",
                       "_strokes.csv", "stroke")  # fmt: skip


def _stroke_document(path):
    """The JSON of ``path`` if it is a stroke model's prediction (``img2dmp-strokes``, as
    ``img2dmp predict --out`` writes it for a stroke model), else None (the DMP file's
    reader says what else is wrong)."""
    from img2dmp._files import parse_json
    from img2dmp.robot.dmpfile import MAX_FILE_BYTES
    from img2dmp.robot.pagefile import STROKES_FORMAT

    with open(path, "rb") as f:
        raw = f.read(MAX_FILE_BYTES + 1)
    if len(raw) > MAX_FILE_BYTES or STROKES_FORMAT.encode() not in raw:
        return None
    try:
        doc = parse_json(raw, path, allow_nan=False)
    except ValueError:
        return None
    return doc if isinstance(doc, dict) and doc.get("format") == STROKES_FORMAT else None


def _run_stroke_document(args, scene_cfg, ctl_cfg, doc) -> int:
    """``--dmp FILE`` of a stroke model's prediction: its strokes, as ``write IMAGE
    --model`` writes them (:func:`img2dmp.robot.pagefile.strokes_page_document`)."""
    from img2dmp.robot import check_page_document
    from img2dmp.robot.pagefile import strokes_page_document

    _refuse_one_dmp_options(args, f"{args.dmp} is a stroke model's prediction")
    if args.image_size:
        raise ValueError(f"--image-size: {args.dmp} gives its own image_size")
    page = check_page_document(strokes_page_document(doc, args.dmp), args.dmp)
    image = _read_image(args.image) if args.image else None
    options = _writing_options(args, scene_cfg, ctl_cfg)
    return _write_stroke_page(args, options, _name(args.dmp), page, image)


def _write_plan(args, name: str, plan, photo, what: str, table: str, noun="character") -> int:
    """Simulate a planned page (or a stroke model's character), then its figure, the
    table of its characters (or strokes) ``<name><table>``, the run's files and its
    summary."""
    from img2dmp._progress import bar as progress_bar
    from img2dmp.robot import (
        page_summary_lines,
        plot_page,
        ready_page_plan,
        save_characters_csv,
        write_page_plan,
    )
    from img2dmp.robot.outputs import joint_acceleration_warning, joint_speed_warning

    plan = ready_page_plan(plan)  # slowed where need be: the bar's total counts it
    n, started, labels = len(plan.characters), [], plan.entry_labels()
    with progress_bar(
        total=plan.estimated_steps(),
        unit="step",
        desc=f"writing {name}",
        enabled=not args.no_progress,
    ) as bar:

        def on_character(cp) -> None:
            started.append(cp)
            stroke = labels.get(cp.character.index)  # "character C: S of N" on a stroke page
            said = f"{cp.label}, {len(started)} of {n}" if stroke is None else f"{stroke} strokes"
            bar.set_description(f"writing {name}: {said}")

        try:
            result = write_page_plan(plan, progress=bar.update, on_character=on_character)
        except RuntimeError as e:  # the simulated arm failed (e.g. never settled)
            where = f" at {started[-1].label}" if started else ""
            print(f"img2dmp write: {name}: simulation failed{where}: {e}", file=sys.stderr)
            return 1
        bar.total = bar.n
    _note_slowed_entries(name, result, noun)
    print("\n".join(page_summary_lines(name, result, noun, plan.entry_labels())))
    m = result.metrics
    for warning in (joint_speed_warning(m), joint_acceleration_warning(m, noun)):
        if warning:
            print(f"img2dmp write: warning: {name}: {warning}", file=sys.stderr)
    trajectory = _joint_trajectory(args, result, name, 1)  # before any file
    os.makedirs(args.out_dir, exist_ok=True)  # once written: a refusal leaves no folder
    base = os.path.join(args.out_dir, name)
    plot_page(result, base + "_paper.png", image=photo, title=f"{name}: KUKA iiwa writes {what}",
              noun=noun)  # fmt: skip
    save_characters_csv(result, base + table, plan.entry_owners())
    written = [base + "_paper.png", base + table] + _save_run(args, result, name, 1, trajectory)
    print("  wrote " + ", ".join(written))
    return 0


#: A note names at most this many slowed characters of a page (the most slowed first).
NOTE_SLOWED_AT_MOST = 3


def _note_slowed_entries(name: str, result, noun: str) -> None:
    """One note naming the characters (or strokes) of a page that were written slower
    for the iiwa's joint speed limits, the most slowed first, and how much."""
    slowed = [r for r in result.characters
              if r.written and r.metrics.get("slowdown", 1.0) > 1.0]  # fmt: skip
    if not slowed:
        return
    slowed.sort(key=lambda r: -r.metrics["slowdown"])
    plans = {cp.character.index: cp for cp in result.page_plan.characters}
    named = [f"{noun} {r.character.index} {plans[r.character.index].slowing.words()}"
             for r in slowed[:NOTE_SLOWED_AT_MOST]]  # fmt: skip
    more = len(slowed) - len(named)
    named += [f"{more} more"] if more else []
    n = result.metrics["characters_written"]
    _note(f"{name}: {len(slowed)} of {n} {noun}s written slower: {'; '.join(named)}; "
          f"{SLOWING_WHY}")  # fmt: skip
