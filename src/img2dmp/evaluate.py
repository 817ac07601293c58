"""Evaluating a trained network the way Table I of Pahič et al. (ICRA 2018) does.

For every test sample the network's DMP is rolled out at the demonstration's own time
stamps and the Euclidean distances (px, on x and y) to the demonstrated points are
averaged: one error per sample (:func:`img2dmp.nn.costs.trajectory_error_px`, the metric
training validates with). Over samples we report the mean and standard deviation
(Table I's two numbers; population standard deviation, ``ddof = 0``), the median and the
95th percentile, overall and per digit. :func:`evaluate` writes them as JSON and a text
table and draws Fig.-4-style pictures: image, demonstrated path in blue, DMP path in red.

Beside Table I's metric it reports a timing-free *path error* (:func:`path_error_px`):
both paths resampled at evenly spaced arc lengths and compared point by point. It
separates the shape from the writer's speed, which an image does not show (on recorded
human paths the timing alone can cost more than a pixel, see docs/MNIST.md).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from .checkpoint import atomic_write_text, file_digest
from .data.store import SPLITS, load_dataset
from .nn.costs import trajectory_error_px
from .predict import Predictor


def error_statistics(errors_px) -> dict:
    """``n``, ``mean``, ``std`` (ddof 0), ``median``, ``p95`` and ``max`` of per-sample errors."""
    e = np.asarray(errors_px, dtype=np.float64)
    if e.size == 0:
        return {"n": 0, "mean": None, "std": None, "median": None, "p95": None, "max": None}
    return {
        "n": int(e.size),
        "mean": float(e.mean()),
        "std": float(e.std()),
        "median": float(np.median(e)),
        "p95": float(np.percentile(e, 95)),
        "max": float(e.max()),
    }


def path_error_px(y_a, y_b, n_points: int = 64) -> np.ndarray:
    """Timing-free distance ``[M]`` (px) between paths ``[M, T, >=2]`` (x, y used).

    Each path is resampled at ``n_points`` evenly spaced arc lengths (from its start to
    its end, linear interpolation) and the mean Euclidean distance between corresponding
    points is returned. Two paths that trace the same curve at different speeds have
    path error 0 (up to the resampling), where Table I's error would not.
    """
    a = np.asarray(y_a, dtype=np.float64)[..., :2]
    b = np.asarray(y_b, dtype=np.float64)[..., :2]
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"paths must both have shape [M, T, 2+], got {a.shape} and {b.shape}")
    diff = _by_arc_length(a, n_points) - _by_arc_length(b, n_points)
    return np.linalg.norm(diff, axis=-1).mean(-1)


def arc_fractions(paths) -> np.ndarray:
    """Share ``[M, T]`` of each path's length ``[M, T, 2]`` covered at each of its points."""
    paths = np.asarray(paths, dtype=np.float64)
    seg = np.linalg.norm(np.diff(paths, axis=1), axis=-1)
    length = np.concatenate([np.zeros((len(paths), 1)), np.cumsum(seg, axis=1)], axis=1)
    return length / np.maximum(length[:, -1:], 1e-12)


def points_at_fractions(path, fractions_of_path, fractions) -> np.ndarray:
    """Points ``[K, 2]`` of one path ``[T, 2]`` (arc fractions ``[T]``) at ``fractions``.

    Linear interpolation along the path; points where the pen did not move are skipped.
    """
    keep = np.concatenate([[True], np.diff(fractions_of_path) > 0])  # np.interp: increasing
    f = fractions_of_path[keep]
    return np.stack([np.interp(fractions, f, path[keep, k]) for k in range(2)], axis=-1)


def _by_arc_length(paths: np.ndarray, n: int) -> np.ndarray:
    lam = arc_fractions(paths)
    grid = np.linspace(0.0, 1.0, n)
    return np.stack([points_at_fractions(p, f, grid) for p, f in zip(paths, lam, strict=True)])


def summarise(errors_px, labels) -> dict:
    """Statistics overall and per digit label (keys ``"0"`` .. ``"9"`` present in ``labels``)."""
    e = np.asarray(errors_px, dtype=np.float64)
    lab = np.asarray(labels)
    per = {str(int(d)): error_statistics(e[lab == d]) for d in np.unique(lab)}
    return {"overall": error_statistics(e), "per_digit": per}


def format_table(summary: dict, title: str = "trajectory error (px)") -> str:
    """A plain-text table of :func:`summarise`'s output."""
    head = f"{'digit':>7} {'n':>6} {'mean':>8} {'std':>8} {'median':>8} {'p95':>8} {'max':>8}"
    lines = [title, head, "-" * len(head)]

    def row(name, s):
        if not s["n"]:
            return f"{name:>7} {0:>6}"
        return (
            f"{name:>7} {s['n']:>6} {s['mean']:>8.4f} {s['std']:>8.4f} {s['median']:>8.4f} "
            f"{s['p95']:>8.4f} {s['max']:>8.4f}"
        )

    for d, s in summary["per_digit"].items():
        lines.append(row(d, s))
    lines.append("-" * len(head))
    lines.append(row("all", summary["overall"]))
    if summary.get("path_error"):
        lines.append(row("path", summary["path_error"]["overall"]))
        lines.append("(path: timing-free error, both paths resampled by arc length)")
    return "\n".join(lines)


def _pick_split(data, split: str):
    if split == "all":
        return data
    if split == "auto":
        return data.select_split("test") if (data.split == SPLITS["test"]).any() else data
    if split not in SPLITS:
        raise ValueError(f"split must be one of {sorted(SPLITS)}, 'all' or 'auto', got {split!r}")
    return data.select_split(split)


def evaluate(
    model_path: str | os.PathLike,
    dataset_path: str | os.PathLike,
    *,
    split: str = "auto",
    out_dir: str | os.PathLike | None = None,
    n_figures: int = 16,
    digits: list[int] | None = None,
    batch_size: int = 2048,
    seed: int = 0,
) -> dict:
    """Table I's statistics of a trained network on a stored data set.

    Parameters
    ----------
    model_path : path
        Run directory or checkpoint file.
    dataset_path : path
        A data set (``img2dmp.data.store`` format).
    split : {"auto", "all", "train", "validation", "test"}
        Samples to evaluate; ``"auto"`` = the test split if the file has one, else all.
    out_dir : path, optional
        Where to write ``evaluation.json``, ``evaluation.txt`` and ``examples.png``.
    n_figures : int
        Samples drawn in ``examples.png`` (chosen at random with ``seed``; 0 = none).
    digits : list of int, optional
        Keep only these labels.

    Returns
    -------
    dict
        ``overall`` and ``per_digit`` statistics plus ``errors_px`` (per sample) and a
        description of the model and data.
    """
    t0 = time.perf_counter()
    predictor = Predictor.load(model_path)
    data = _evaluation_data(predictor, dataset_path, split, digits)
    y = predictor.trajectories_for_images(data.images, data.times, batch_size)  # [M, T, d]
    # Table I's metric, defined once (training validates with the same function).
    errors = trajectory_error_px(torch.as_tensor(y), torch.as_tensor(data.trajectories)).numpy()
    result = summarise(errors, data.labels)
    path_errors = path_error_px(y, data.trajectories)  # [M]
    result["path_error"] = summarise(path_errors, data.labels)
    result.update(
        model=str(model_path),
        dataset=str(dataset_path),
        dataset_sha256=file_digest(dataset_path),
        split=split,
        digits=digits,
        trained_on=predictor.meta.get("dataset"),
        cost=predictor.meta.get("train_config", {}).get("cost", {}).get("name"),
        fit_error_px=error_statistics(data.fit_error_px),
        wall_s=time.perf_counter() - t0,
        errors_px=errors.tolist(),
        path_errors_px=path_errors.tolist(),
    )
    if out_dir is not None:
        _write_evaluation(Path(out_dir), result, data, y, errors, n_figures, seed)
    return result


def _evaluation_data(predictor: Predictor, dataset_path, split: str, digits):
    """The samples of ``split`` (and ``digits``) of a data set, checked against the model."""
    data = _pick_split(load_dataset(dataset_path), split)
    if digits is not None:
        data = data.subset(np.isin(data.labels, np.asarray(digits)))
    if len(data) == 0:
        raise ValueError(
            f"data set {dataset_path} has no samples in split {split!r}"
            + (f" with labels {digits}" if digits is not None else "")
        )
    if tuple(data.image_size) != predictor.image_size:
        raise ValueError(
            f"data set {dataset_path} has {data.image_size} images, the model expects "
            f"{predictor.image_size}"
        )
    if data.dmp_config.n_dims != predictor.dmp_config.n_dims:
        raise ValueError(
            f"data set {dataset_path} has d={data.dmp_config.n_dims} dimensions, the model "
            f"d={predictor.dmp_config.n_dims}"
        )
    return data


def _write_evaluation(out: Path, result: dict, data, y, errors, n_figures: int, seed: int):
    """``evaluation.json``, ``evaluation.txt`` and (``n_figures`` > 0) ``examples.png``."""
    from .data.plotting import overlay_figure

    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "evaluation.json", json.dumps(result, indent=1) + "\n")
    atomic_write_text(out / "evaluation.txt", format_table(result) + "\n")
    if n_figures > 0:
        rng = np.random.default_rng(seed)
        pick = np.sort(rng.choice(len(data), size=min(n_figures, len(data)), replace=False))
        titles = [f"{int(data.labels[i])}: {errors[i]:.3f} px" for i in pick]
        overlay_figure(
            out / "examples.png",
            data.images[pick],
            data.trajectories[pick],
            y[pick],
            titles,
            labels=("demonstration", "network's DMP"),
        )


def __getattr__(name: str):
    # overlay_figure lives in data.plotting now; it is still importable from here, but
    # loaded on first use so that importing this module does not start matplotlib.
    if name == "overlay_figure":
        from .data.plotting import overlay_figure

        return overlay_figure
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
