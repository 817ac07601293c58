"""How often the synthetic digits' pen ends hide under their own ink, and what that costs.

The image must determine the movement. Where a stroke runs over its own first or last
point, no image shows where the pen set down or lifted off, and a network can only guess
those points. This script measures, per digit, for the first templates (until
2026-11-22, kept here as data) and for the current ones, with the generator's own ranges
and affine transforms but none of its checks (end clearance, start-goal gap, pen inside
the image; the last two narrow the angles a little, so the floors are slight
overestimates):

- the share of samples whose start (end) lies within ``min_end_clearance_rel * H``
  (3.6 px) of another part of the stroke (:func:`img2dmp.data.synthetic.end_clearance`);
- the error floor those hidden ends impose: the mean distance, at the shared time stamps,
  between a sample's path and the mean path over redraws of the hidden angles only (the
  start angle of the first element, the end angle of the last, when they are arcs and
  that end is hidden in most samples). Everything else stays as drawn, so a predictor
  that knew all but the hidden angles could do no better than this on average (up to the
  difference between the mean and the best point under a Euclidean loss).

Run from the repository's root: ``python experiments/hidden_ends.py [--samples 1000]
[--redraws 64]``. It prints the date, the git revision and its command line first, to go
with its table in ``experiments/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from img2dmp.data import synthetic as syn
from img2dmp.data.affine import sample_affine, warp_points
from img2dmp.data.synthetic import Arc, DigitTemplate, Line, SyntheticConfig

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record

# The templates of 0, 6, 8 and 9 before they were opened (the others did not change).
FIRST_TEMPLATES = {
    0: DigitTemplate(centre=(0.0, 0.0), elements=(Arc(0.6, 0.95, 8.0, -100.0, -520.0),)),
    6: DigitTemplate(
        centre=(0.35, 0.35),
        elements=(Arc(0.85, 1.3, 0.0, -80.0, -180.0), Arc(0.5, 0.6, 0.0, 180.0, -170.0)),
    ),
    8: DigitTemplate(
        centre=(0.0, -0.5),
        elements=(
            Arc(0.4, 0.47, 0.0, 0.0, -210.0),
            Line(0.81, 29.0),
            Arc(0.48, 0.5, 0.0, -40.0, 220.0),
            Line(0.82, -29.0),
            Arc(0.4, 0.47, 0.0, 30.0, -100.0),
        ),
    ),
    9: DigitTemplate(
        centre=(0.0, -0.45),
        elements=(Arc(0.45, 0.5, 8.0, -30.0, -380.0), Line(1.6, 103.0)),
    ),
}


def pixel_paths(template, anchor, elements, config, mats):
    """Minimum-jerk pen paths in pixels, moved by the affine matrices ``mats``."""
    h, w = config.image_size
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    unit = syn.timed_paths(template, anchor, elements, config)
    return warp_points(centre + config.unit_px * unit, mats)


def measure(template, config, n, redraws, rng):
    """Shares of hidden starts and ends, and the floor of redrawing the hidden angles."""
    h = config.image_size[0]
    clearance = config.min_end_clearance_rel * h
    anchor, elements = syn.sample_element_params(template, n, config, rng)
    mats = sample_affine(rng, n, config.image_size, config.affine)
    paths = pixel_paths(template, anchor, elements, config, mats)
    start, end = syn.end_clearance(paths, 2.0 * clearance)
    hidden_start, hidden_end = float((start < clearance).mean()), float((end < clearance).mean())
    # Redraw the angles no image can show, every other parameter kept.
    hidden = []
    if hidden_start > 0.5 and isinstance(template.elements[0], Arc):
        hidden.append((0, "start_deg", template.elements[0].start_deg))
    if hidden_end > 0.5 and isinstance(template.elements[-1], Arc):
        last = len(template.elements) - 1
        hidden.append((last, "end_deg", template.elements[-1].end_deg))
    if not hidden:
        return hidden_start, hidden_end, 0.0
    rep = np.repeat(np.arange(n), redraws)
    elems = [{k: v[rep] for k, v in e.items()} for e in elements]
    for i, key, nominal in hidden:
        elems[i][key] = nominal + (2.0 * rng.random(rep.size) - 1.0) * config.arc_angle_deg
    alt = pixel_paths(template, anchor[rep], elems, config, mats[rep])
    alt = alt.reshape(n, redraws, *alt.shape[1:])
    floor = np.linalg.norm(alt - alt.mean(1, keepdims=True), axis=-1).mean()
    return hidden_start, hidden_end, float(floor)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1000, help="samples per digit")
    ap.add_argument("--redraws", type=int, default=64, help="redraws of the hidden angles")
    ap.add_argument("--seed", type=int, default=0)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    if args.samples < 1 or args.redraws < 2:
        ap.error("--samples must be >= 1 and --redraws >= 2")
    config = SyntheticConfig()
    rng = np.random.default_rng(args.seed)
    print(format_record(run_record(__file__, argv)))
    print(
        f"{args.samples} samples per digit; an end is hidden when the stroke passes within "
        f"{config.min_end_clearance_rel * config.image_size[0]:.1f} px of it"
    )
    head = ("digit", "templates", "start hidden", "end hidden", "floor (px)")
    print("{:>5s}  {:9s} {:>12s} {:>10s} {:>10s}".format(*head))
    for digit in range(10):
        sets = [("current", syn.DIGIT_TEMPLATES[digit])]
        if digit in FIRST_TEMPLATES:
            sets.insert(0, ("first", FIRST_TEMPLATES[digit]))
        for name, template in sets:
            s, e, floor = measure(template, config, args.samples, args.redraws, rng)
            print(f"{digit:5d}  {name:9s} {s:12.1%} {e:10.1%} {floor:10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
