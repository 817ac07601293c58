"""The README's main job end to end on a small built-in example.

:func:`run_demo` generates a small synthetic data set (:mod:`img2dmp.data.synthetic`),
trains a small encoder-decoder network briefly with cost (10) (or (9)), evaluates it as
in Table I and draws Fig.-4-style pictures. On a 2-core CPU it takes a few minutes. The
error after so short a training is far from Table I's; it is printed as measured.

The network and optimiser are the package's ``configs/demo.yaml`` (:func:`demo_config`),
the one copy of the demo's configuration.

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
from importlib import resources
from pathlib import Path

from ._files import atomic_write_text
from .config import merge, parse_yaml

#: Size of the demo's data set (the CLI's default too).
DEMO_SAMPLES_PER_DIGIT = 300


def demo_config() -> dict:
    """The demo's training configuration, read from the package's ``configs/demo.yaml``."""
    text = resources.files("img2dmp").joinpath("configs", "demo.yaml").read_text("utf-8")
    return parse_yaml(text)


#: The demo's training configuration (a mapping of TrainConfig fields) and its length.
DEMO_CONFIG = demo_config()
DEMO_EPOCHS = int(DEMO_CONFIG["optim"]["epochs"])


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
    progress : bool
        Say what happens (stages on standard output, progress on standard error).
    overrides : dict, optional
        Merged into :data:`DEMO_CONFIG` section by section (e.g. a tinier model in tests).

    Returns
    -------
    dict
        The summary also written to ``summary.json``.
    """
    if isinstance(samples_per_digit, bool) or int(samples_per_digit) < 10:
        raise ValueError(
            "samples_per_digit must be >= 10 (10 % of them make the test split), got "
            f"{samples_per_digit!r}"
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    say = print if progress else (lambda *a, **k: None)
    t0 = time.perf_counter()

    say(f"[1/4] generating {samples_per_digit} synthetic samples per digit ...", flush=True)
    data_path = _generate(out, samples_per_digit, seed, progress)
    t_data = time.perf_counter() - t0

    say(f"[2/4] training for {epochs} epochs with cost {cost!r} ...", flush=True)
    cfg = _train_config(data_path, epochs, cost, seed, progress, overrides)
    from .train import train

    res = train(cfg, out / "run", overwrite=True)
    t_train = time.perf_counter() - t0 - t_data

    say("[3/4] evaluating on the test split ...", flush=True)
    from .evaluate import evaluate, format_table

    ev = evaluate(out / "run", data_path, split="test", out_dir=out / "evaluation")
    say(format_table(ev, "trajectory error (px) on the test split"))

    say("[4/4] pictures: run/training_curve.png, evaluation/examples.png")
    times = {"data": t_data, "train": t_train, "total": time.perf_counter() - t0}
    summary = _summary(out, data_path, samples_per_digit, cost, res, ev, times)
    m = ev["overall"]
    say(
        f"done in {times['total']:.0f} s: test error {m['mean']:.3f} +- {m['std']:.3f} px "
        f"(mean +- std over {m['n']} samples) after {res.epochs_run} epochs (the paper's "
        "Table I, fully trained: 0.23 px with cost 10, 0.40 px with cost 9)"
    )
    return summary


def _generate(out: Path, samples_per_digit: int, seed: int, progress: bool) -> Path:
    from .data.store import save_dataset
    from .data.synthetic import generate_dataset

    path = out / "data.safetensors"
    save_dataset(path, generate_dataset(samples_per_digit, seed=seed, progress=progress))
    return path


def _train_config(data_path, epochs, cost, seed, progress, overrides):
    from .training import TrainConfig

    d = merge(DEMO_CONFIG, overrides or {})  # merge copies: DEMO_CONFIG stays as read
    d = merge(d, {"data": {"path": str(data_path)}, "optim": {"epochs": int(epochs)}})
    d = merge(d, {"cost": {"name": cost}, "seed": int(seed), "progress": bool(progress)})
    return TrainConfig.from_dict(d)


def _summary(out: Path, data_path: Path, samples_per_digit, cost, res, ev, times) -> dict:
    from .training.state import numerics

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
        "time_s": times,
        "numerics": numerics(),  # what else decides the figures' last digits
    }
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1) + "\n")
    return summary
