"""The README's main job end to end on a small built-in example.

:func:`run_demo` generates a small synthetic data set (:mod:`img2dmp.data.synthetic`),
trains a small encoder-decoder network briefly with cost (10) (or (9)), evaluates it as
in Table I and draws Fig.-4-style pictures. On a 2-core CPU it takes a few minutes. The
error after so short a training is far from Table I's; it is printed as measured.

Output directory::

    data.safetensors            the generated data set (train / validation / test split)
    run/                        config.yaml, metrics.csv, training_curve.png, checkpoints/
    evaluation/                 evaluation.json, evaluation.txt, examples.png (test split)
    summary.json                what was done, with the headline numbers and timings
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from .checkpoint import atomic_write_text
from .evaluate import evaluate, format_table
from .train import TrainConfig, train

#: Size of the demo's data set and length of its training (the CLI's defaults too).
DEMO_SAMPLES_PER_DIGIT = 300
DEMO_EPOCHS = 60

#: The demo's network and optimiser. configs/demo.yaml holds the same as a file for
#: ``img2dmp train --config``; tests/test_train.py checks that the two agree.
DEMO_CONFIG = {
    "model": {
        "encoder": "fc",
        "image_size": [40, 40],
        "encoder_layers": [512, 256, 64, 20],
        "decoder_layers": [35],
        "activation": "relu",
    },
    "optim": {"lr": 1e-3, "batch_size": 64, "epochs": 60, "patience": 15, "schedule": "cosine"},
    "cost": {"name": "trajectory"},
    "threads": 1,
}


def run_demo(
    out_dir: str | os.PathLike,
    *,
    samples_per_digit: int = DEMO_SAMPLES_PER_DIGIT,
    epochs: int = DEMO_EPOCHS,
    cost: str = "trajectory",
    seed: int = 0,
    progress: bool = True,
    overrides: dict | None = None,
) -> dict:
    """Generate -> train -> evaluate -> pictures, into ``out_dir``.

    Parameters
    ----------
    out_dir : path
        Created if needed; an earlier demo there is replaced.
    samples_per_digit : int
        Synthetic samples per digit (80 % train, 10 % validation, 10 % test).
    epochs : int
        Training epochs.
    cost : str
        ``"trajectory"`` (eq. 10) or ``"parameter"`` (eq. 9).
    overrides : dict, optional
        Merged into :data:`DEMO_CONFIG` section by section (e.g. a tinier model in tests).

    Returns
    -------
    dict
        The summary also written to ``summary.json``.
    """
    from .data.store import save_dataset
    from .data.synthetic import generate_dataset

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    say = print if progress else (lambda *a, **k: None)

    say(f"[1/4] generating {samples_per_digit} synthetic samples per digit ...")
    data_path = out / "data.safetensors"
    save_dataset(data_path, generate_dataset(samples_per_digit, seed=seed, progress=progress))
    t_data = time.perf_counter() - t0

    say(f"[2/4] training for {epochs} epochs with cost {cost!r} ...")
    cfg_dict = json.loads(json.dumps(DEMO_CONFIG))
    for section, values in (overrides or {}).items():
        if isinstance(values, dict):
            cfg_dict.setdefault(section, {}).update(values)
        else:
            cfg_dict[section] = values
    cfg_dict.setdefault("data", {})["path"] = str(data_path)
    cfg_dict["optim"]["epochs"] = int(epochs)
    cfg_dict["cost"]["name"] = cost
    cfg_dict["seed"] = int(seed)
    cfg_dict["progress"] = progress
    res = train(TrainConfig.from_dict(cfg_dict), out / "run", overwrite=True)
    t_train = time.perf_counter() - t0 - t_data

    say("[3/4] evaluating on the test split ...")
    ev = evaluate(out / "run", data_path, split="test", out_dir=out / "evaluation")
    say(format_table(ev, "trajectory error (px) on the test split"))

    say("[4/4] pictures: run/training_curve.png, evaluation/examples.png")
    summary = {
        "data": str(data_path),
        "run_dir": str(out / "run"),
        "evaluation": str(out / "evaluation" / "evaluation.json"),
        "pictures": [
            str(out / "run" / "training_curve.png"),
            str(out / "evaluation" / "examples.png"),
        ],
        "samples_per_digit": samples_per_digit,
        "epochs_run": res.epochs_run,
        "cost": cost,
        "best_val_error_px": res.best_val_error_px,
        "test_error_px": {k: ev["overall"][k] for k in ("mean", "std", "median", "p95")},
        "time_s": {"data": t_data, "train": t_train, "total": time.perf_counter() - t0},
    }
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    m = ev["overall"]
    say(
        f"done in {summary['time_s']['total']:.0f} s: test error {m['mean']:.3f} +- "
        f"{m['std']:.3f} px (mean +- std over {m['n']} samples) after {res.epochs_run} "
        f"epochs (the paper's Table I, fully trained: 0.23 px with cost 10, 0.40 px with cost 9)"
    )
    return summary
