"""What a run leaves for people: ``metrics.csv`` and ``training_curve.png``."""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

from .._files import atomic_write_text, new_figure, save_figure

#: Columns of ``metrics.csv``, one row per epoch (:class:`~.state.EpochStats`).
METRIC_FIELDS = (
    "epoch",
    "step",
    "lr",
    "train_cost",
    "train_error_px",
    "val_error_px",
    "best_val_error_px",
    "epoch_time_s",
)


#: What a run's errors (``train_error_px``, ``val_error_px``, ``best_val_error_px`` in
#: ``metrics.csv`` and the checkpoints) measure, by the checkpoints' ``val_error_measure``
#: (a record without it, of an earlier img2dmp: ``"stroke-shape"`` when its ``strokes`` is
#: set, else ``"trajectory"``): Table I's trajectory error, the mean distance
#: between the whole path and the DMP rolled out at its time stamps (a one-DMP model; as
#: ``img2dmp evaluate`` reports it), or a stroke model's stroke shape error, the root mean
#: squared distance between each true stroke and the predicted stroke matched to it, each
#: over its own duration, averaged over the true strokes (no count, order, timing or
#: pen-up travel in it: smaller than ``evaluate``'s trajectory error of the same model,
#: often ten times).
ERROR_MEASURES = {"trajectory": "trajectory error", "stroke-shape": "stroke shape error"}


def error_measure(strokes: bool) -> str:
    """The key of :data:`ERROR_MEASURES` of a stroke model's run (``strokes``) or a
    one-DMP model's."""
    return "stroke-shape" if strokes else "trajectory"


def write_metrics_csv(path: str | os.PathLike, history: list[dict]) -> None:
    """``history`` (one dict per epoch) as ``metrics.csv``, written atomically."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=METRIC_FIELDS, lineterminator="\n")
    w.writeheader()
    for row in history:
        w.writerow({k: row.get(k, "") for k in METRIC_FIELDS})
    atomic_write_text(path, buf.getvalue())


def read_metrics_csv(path: str | os.PathLike) -> list[dict]:
    """Rows of a ``metrics.csv`` as dicts of floats (``epoch``/``step`` as int)."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    out = []
    for r in rows:
        out.append({k: (int(v) if k in ("epoch", "step") else float(v)) for k, v in r.items()})
    return out


def plot_training_curve(
    path: str | os.PathLike, history: list[dict], title: str = "", measure: str = "trajectory"
) -> Path:
    """Train and validation error (px, log scale; ``measure`` a key of
    :data:`ERROR_MEASURES`) per epoch, saved atomically."""
    import matplotlib.ticker

    ep = [r["epoch"] for r in history]
    fig = new_figure(figsize=(6, 4), dpi=100)
    ax = fig.subplots()
    ax.plot(ep, [r["train_error_px"] for r in history], label="train", color="tab:blue")
    ax.plot(ep, [r["val_error_px"] for r in history], label="validation", color="tab:red")
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.yaxis.set_minor_formatter(matplotlib.ticker.FormatStrFormatter("%.2g"))
    ax.set_xlabel("epoch")
    ax.set_ylabel(f"mean {ERROR_MEASURES[measure]} (px)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if title:
        ax.set_title(title, fontsize=9)
    return save_figure(fig, path)


__all__ = [
    "ERROR_MEASURES",
    "METRIC_FIELDS",
    "error_measure",
    "plot_training_curve",
    "read_metrics_csv",
    "write_metrics_csv",
]
