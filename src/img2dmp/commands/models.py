"""List the trained models shipped inside img2dmp, or show one's model card.

Each shipped model is used by its name wherever a run directory or checkpoint is taken
(--model NAME in predict, write, serve, evaluate, export; train --init-from NAME;
img2dmp.load_model("NAME") in Python). The default one (marked *) is used when no model
is given, with the settings its card recommends. The list gives each one's size, what it
is, its measured test-part figures and whether its file matches the SHA-256 recorded when
it was shipped (a damaged file is refused wherever it would be loaded).

  img2dmp models
  img2dmp models digits-real      (its model card)
"""

from __future__ import annotations

import argparse

HELP = "the trained models shipped with img2dmp (--model NAME), or one's model card"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="?", metavar="NAME", help="print this model's card")


def _figures(f: dict) -> str:
    if not f:
        return "no figures recorded"
    strokes = "count_right" in f  # a stroke model's: characters, and their stroke count
    return (
        f"{f['split']} part ({f['n']} {'characters' if strokes else 'digits'}, "
        f"--refine {f['refine']}"
        + (f", --refine-unfamiliar {f['refine_unfamiliar']}" if "refine_unfamiliar" in f else "")
        + (f", --count-views {f['count_views']}" if "count_views" in f else "")
        + f"): Chamfer {f['chamfer_px']:.4f} px, path on the ink "
        f"{100 * f['path_on_ink']:.1f} %, path error {f['path_error_px']:.3f} px "
        + (_count(f) if strokes else "(top hypothesis)")
    )


def _count(f: dict) -> str:
    """A stroke model's count right, and beside it its ceiling when recorded."""
    said = f"stroke count right {100 * f['count_right']:.1f} %"
    if f.get("count_mode_right"):
        mode = f["count_mode_right"]
        said += (f"; a class's most common count {100 * mode:.1f} %: "
                 f"{100 * f['count_right'] / mode:.1f} % of it")  # fmt: skip
    return f"({said})"


def _describe(model) -> list[str]:
    from ..errors import ShippedModelError
    from ..models import verified_familiar, verified_weights

    try:
        verified_weights(model)
        check = f"sha256 {model.sha256[:12]}... verified"
        if verified_familiar(model) is not None:
            line = model.record["familiar"].get("line")
            check += f"; familiarity ({model.familiar.name}, line {line}) verified"
    except ShippedModelError as e:
        check = f"DAMAGED: {e}"
    settings = ", ".join(f"--{k.replace('_', '-')} {v}" for k, v in model.recommended.items())
    settings = settings or "none"
    mark = "*" if model.default else " "
    return [
        f"{mark} {model.name}  {model.size_bytes / 1e6:.2f} MB  {model.summary}",
        f"    {_figures(model.figures)}",
        f"    recommended: {settings}; card: {model.card}",
        f"    {check}",
    ]


def run(args: argparse.Namespace) -> int:
    from ..models import find_shipped, models_root, shipped_models

    if args.name is not None:
        model = find_shipped(args.name)
        print(model.card.read_text(encoding="utf-8").rstrip())
        return 0
    models = shipped_models()
    print(f"models shipped with img2dmp ({models_root()}); * = the default:")
    for model in models:
        print("\n".join(_describe(model)))
    return 0
