"""Reading a page as a user meets it: ``img2dmp predict PHOTO --page --out DIR``, end to end.

A 12-megapixel photo (4000 x 3000, JPEG) of a page with 60 handwritten digits on ruled
paper (:func:`img2dmp.data.clutter.generate_page`, synthetic digits, so no data is
needed; ordinary gaps between them) is read by the command as a whole process, several
runs (min / median / max), beside the floor every command pays, ``python -c "import
img2dmp.predict"`` (Python, torch and the package imported), in alternation; the ratio
of the two medians says how much of the time is the page's own work. Target: the page
in at most 3 s end to end.

``--stages`` also times the stages of one reading in this process (after a warm-up):
reading and reducing the photo, separating the ink from the paper, finding the
characters, framing them, the network and refinement, the page document and picture.

The model: the shipped default with its card's refinement (30 steps) unless ``--model``
names another (a shipped name or a run directory) or ``--tiny`` asks for a tiny one
trained here in a temporary folder (as ``bench_latency.py`` does); ``--refine`` overrides
the steps. ``--backend`` passes through to ``predict`` (default auto: NumPy, no torch).
Python's bytecode cache is on (as for an installed package) unless ``--as-environment``.

Run: ``.venv/bin/python benchmarks/bench_page.py [--stages] [--backend torch]``
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import _machine
from bench_latency import bytecode_env, img2dmp_command, make_model, run

TARGET_S = 3.0
SIZE_HW = (3000, 4000)
N_CHARACTERS = 60


def make_photo(work: Path, seed: int = 0, size_hw=SIZE_HW, n: int = N_CHARACTERS,
               char_height_px=(110.0, 130.0), n_lines: int = 5) -> Path:  # fmt: skip
    """The page photo (JPEG): ``n`` digits in ``n_lines`` lines on ruled paper."""
    import numpy as np
    from PIL import Image

    from img2dmp.data.clutter import PageOptions, generate_page, page_sources_from_synthetic

    rng = np.random.default_rng(seed)
    chars = page_sources_from_synthetic(rng, n)
    # written with ordinary gaps (the accuracy experiment's tightly written pages, 30 %
    # of them, touch and overlap; their count is measured there, the time here)
    options = PageOptions(
        n_lines=(n_lines, n_lines), char_height_px=char_height_px, tight_probability=0.0
    )
    page = generate_page(rng, chars, kind="ruled", size_hw=size_hw, options=options)
    path = work / "page.jpg"
    Image.fromarray(page.image).save(path, quality=90)
    return path


def stages(model_dir: str, refine: int | None, photo: Path, backend: str = "auto"):
    """Seconds of each stage of one reading, in this process (warmed up once)."""
    from img2dmp import page as P
    from img2dmp.data import images
    from img2dmp.data.pages import find_characters
    from img2dmp.data.paper import paper_ink
    from img2dmp.predict import load_model

    model = load_model(model_dir, refine=refine, backend=backend)
    model.predict_page(photo)  # warm-up
    out, t = [], time.perf_counter()

    def lap(name):
        nonlocal t
        now = time.perf_counter()
        out.append((name, now - t))
        t = now

    levels, reduction, size, label = images._levels_framed(photo, None, P.PAGE_WORK_PIXELS)
    lap("read and reduce the photo")
    found = paper_ink(levels)
    lap("separate the ink from the paper")
    layout = find_characters(found.mask, core=found.core, grow=P._grow(found.pen_width_px))
    lap(f"find the characters ({len(layout.characters)})")
    seg = P.PageSegmentation(levels, reduction, size, label, found, layout)
    inputs, _ = P._frame_characters(model, seg, True)
    lap("frame them")
    import numpy as np

    params, _ = model.predict_hypotheses(np.stack(inputs), refine_top_only=P.PAGE_REFINE_TOP_ONLY)
    model.trajectories(params, n_points=100)
    lap(f"network{' and refinement' if model.refine_options else ''}, rollouts")
    result = model.predict_page(photo)
    t = time.perf_counter()
    result.save(photo.parent / "stages", "page")
    lap("write the page document and picture")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", help="shipped name or run directory (default: the default model)")
    ap.add_argument("--tiny", action="store_true", help="a tiny model trained here instead")
    ap.add_argument("--refine", type=int, help="refinement steps (default: the card's)")
    ap.add_argument("--backend", default="auto", choices=("auto", "numpy", "torch"))
    ap.add_argument("--runs", type=int, default=5, help="timed runs of each command")
    ap.add_argument("--stages", action="store_true", help="also time the stages in-process")
    ap.add_argument(
        "--as-environment",
        action="store_true",
        help="time with the environment as it is (bytecode cache maybe off)",
    )
    args = ap.parse_args()
    cli = img2dmp_command()
    work = Path(tempfile.mkdtemp(prefix="img2dmp-page-"))
    try:
        print(_machine.describe())
        # absolute: the commands run in the work folder
        if args.tiny:
            model = str(make_model(work, cli)[0])
        elif args.model and Path(args.model).exists():
            model = str(Path(args.model).resolve())
        else:  # a shipped model's name, or the default one
            from img2dmp.models import default_model

            model = args.model or default_model().name
        photo = make_photo(work)
        print(
            f"photo: {SIZE_HW[1]} x {SIZE_HW[0]} JPEG, {N_CHARACTERS} digits on ruled paper, "
            f"{photo.stat().st_size / 1e6:.1f} MB; model {model}, refine "
            f"{'as its card says' if args.refine is None else args.refine}, backend {args.backend}"
        )
        env, cache = bytecode_env(work, args.as_environment)
        print(cache)
        page = (
            cli
            + [
                "predict",
                "--model",
                model,
                str(photo),
                "--page",
                "--out",
                str(work / "out"),
                "--force",
                "--backend",
                args.backend,
            ]
            + ([] if args.refine is None else ["--refine", str(args.refine)])
        )
        floor = [sys.executable, "-c", "import img2dmp.predict"]
        commands = {"predict --page (12 MP, 60 digits)": page, "import img2dmp.predict": floor}
        for cmd in commands.values():
            run(cmd, work, env=env)  # warm-up: caches, bytecode
        times = {name: [] for name in commands}
        for _ in range(args.runs):
            for name, cmd in commands.items():
                times[name].append(run(cmd, work, env=env))
        print(f"\n{args.runs} runs each, as whole processes, in alternation")
        print(f"{'command':36s} {'min (s)':>8s} {'median':>8s} {'max':>8s}")
        for name, ts in times.items():
            print(f"{name:36s} {min(ts):8.2f} {statistics.median(ts):8.2f} {max(ts):8.2f}")
        med = {k: statistics.median(v) for k, v in times.items()}
        page_s, floor_s = med[next(iter(med))], med["import img2dmp.predict"]
        verdict = "ok" if page_s <= TARGET_S else "SLOWER"
        print(
            f"page / import floor: {page_s / floor_s:.2f}x; the page's own work "
            f"{page_s - floor_s:.2f} s; target {TARGET_S:.1f} s end to end: {verdict}"
        )
        if args.stages:
            print("\nstages of one reading, in-process:")
            for name, s in stages(model, args.refine, photo, args.backend):
                print(f"  {s:6.3f} s  {name}")
        print(f"load average at the end {_machine.load_average()} (1/5/15 min)")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
