"""Evaluating a trained network the way Table I of Pahič et al. (ICRA 2018) does.

For every test sample the network's DMP is rolled out at the demonstration's own time
stamps and the Euclidean distances (px, on x and y) to the demonstrated points are
averaged: one error per sample (:func:`img2dmp.nn.costs.trajectory_error_px`, the metric
training validates with). Over samples we report the mean and standard deviation
(Table I's two numbers; population standard deviation, ``ddof = 0``), the median and the
95th percentile, overall and per digit. :func:`evaluate` writes them as JSON and a text
table and draws Fig.-4-style pictures: image, demonstrated path in blue, DMP path in red.

A data set with class names (letters, symbols, shapes: ``img2dmp import``, the
``class_names`` of :mod:`img2dmp.data.store`) is summarised per class instead: the
statistics are keyed by the class names under ``per_class`` (``per_digit`` for a data set
of digits), and the tables and pictures show the names.

Beside Table I's metric it reports measures that ignore the writer's speed, which an
image does not show (on recorded human paths the timing alone can cost more than a
pixel, see docs/MNIST.md), all from :mod:`img2dmp.metrics`, overall and per digit:

- ``path_error``: both paths resampled by arc length and compared point by point;
- ``chamfer``: symmetric Chamfer distance, free of order and direction;
- ``on_ink`` / ``on_ink_human``: share of the network's / the demonstration's path on
  the image's ink (the demonstration's share is the human reference);
- ``start_error``: distance between where the two paths start writing;
- ``area_ratio``: enclosed area of the network's path over the demonstration's, for the
  closed digits (:data:`~img2dmp.metrics.CLOSED_DIGITS`; its median is the headline);
- ``width_ratio``: horizontal extent of the network's path over the demonstration's.

A network with several hypotheses per image (``predictor.hypothesis_trajectories``) is
judged on its most probable one; ``best_of_k`` adds, per sample, the smallest Table I,
path and Chamfer errors over all K hypotheses (:func:`hypothesis_metrics`).
"""

from __future__ import annotations

import json
import os
import time
from collections import Counter
from pathlib import Path

import numpy as np
import torch

from ._progress import bar
from .checkpoint import atomic_write_text, file_digest
from .data.store import SPLITS, load_dataset
from .metrics import (  # noqa: F401  (arc_fractions, points_at_fractions: re-exported)
    CLOSED_DIGITS,
    arc_fractions,
    area_ratio,
    chamfer_px,
    closed_labels,
    on_ink_share,
    path_error_px,
    points_at_fractions,
    start_error_px,
    width_ratio,
)
from .nn._stroke_layout import MAX_COUNT_VIEWS
from .nn.costs import trajectory_error_px
from .predict import MAX_BATCH_SIZE, MAX_REFINE_STEPS, Predictor, check_count, index_resampled

#: Most samples drawn in ``examples.png`` (``--figures``): the most one grid holds
#: (:data:`img2dmp.data.plotting.MAX_GRID_CELLS`, not imported here: matplotlib).
MAX_FIGURES = 1000
#: Samples predicted together when every prediction is refined (slow: a progress bar
#: moves part by part); without refinement a part is ``batch_size`` samples.
REFINE_PART = 64


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


def summarise(errors_px, labels, class_names=None) -> dict:
    """Statistics overall and per label.

    Without ``class_names`` the labels are digits: ``per_digit`` with keys ``"0"`` ..
    ``"9"`` (those present in ``labels``). With ``class_names`` (the names the labels
    index into) ``per_class`` with the names of the classes present, in label order.
    """
    e = np.asarray(errors_px, dtype=np.float64)
    lab = np.asarray(labels)
    if class_names is None:
        per = {str(int(d)): error_statistics(e[lab == d]) for d in np.unique(lab)}
        return {"overall": error_statistics(e), "per_digit": per}
    per = {str(class_names[int(c)]): error_statistics(e[lab == c]) for c in np.unique(lab)}
    return {"overall": error_statistics(e), "per_class": per}


def per_label(summary: dict) -> dict:
    """The per-label statistics of a :func:`summarise` output: ``per_class`` (keyed by
    class name) if it has them, else ``per_digit``."""
    return summary.get("per_class", summary.get("per_digit", {}))


def _label_column(summary: dict, width: int) -> tuple[str, int]:
    """The first column's title (``digit`` or ``class``) and its width (class names may
    be longer than the title)."""
    if "per_class" not in summary:
        return "digit", width
    longest = max((len(k) for k in summary["per_class"]), default=0)
    return "class", max(width, min(longest, 24))


def format_table(summary: dict, title: str = "trajectory error (px)") -> str:
    """A plain-text table of :func:`summarise`'s output; for a result of :func:`evaluate`
    (or :func:`hypothesis_metrics`) followed by :func:`format_metrics_table`'s. Its rows
    are the digits, or the class names of a data set that has them."""
    what, w = _label_column(summary, 7)
    head = f"{what:>{w}} {'n':>6} {'mean':>8} {'std':>8} {'median':>8} {'p95':>8} {'max':>8}"
    lines = [title, head, "-" * len(head)]

    def row(name, s):
        if not s["n"]:
            return f"{name:>{w}} {0:>6}"
        return (
            f"{name:>{w}} {s['n']:>6} {s['mean']:>8.4f} {s['std']:>8.4f} {s['median']:>8.4f} "
            f"{s['p95']:>8.4f} {s['max']:>8.4f}"
        )

    for d, s in per_label(summary).items():
        lines.append(row(d, s))
    lines.append("-" * len(head))
    lines.append(row("all", summary["overall"]))
    if summary.get("path_error"):
        lines.append(row("path", summary["path_error"]["overall"]))
        lines.append("(path: timing-free error, both paths resampled by arc length)")
    if "chamfer" in summary:
        lines += ["", format_metrics_table(summary)]
    return "\n".join(lines)


def _cell(stats: dict | None, key: str, width: int, scale: float = 1.0, digits: int = 4) -> str:
    value = None if not stats or not stats.get("n") else stats.get(key)
    return f"{'-':>{width}}" if value is None else f"{value * scale:>{width}.{digits}f}"


def format_metrics_table(result: dict) -> str:
    """The path measures of :func:`evaluate` per digit (or class) and overall, one line each.

    Columns: samples, Table I's mean error, mean path error, mean Chamfer distance (px),
    on-ink share of the network's path and of the demonstration's (%), median area
    ratio (closed digits only, ``-`` otherwise), mean start error (px); for K > 1
    hypotheses a line with the best-of-K means.
    """
    what, w = _label_column(result, 7)
    head = (
        f"{what:>{w}} {'n':>6} {'TableI':>8} {'path':>8} {'Chamfer':>8} {'ink %':>6} "
        f"{'human%':>6} {'area':>6} {'start':>8}"
    )
    lines = ["path measures (px; ink: % of the path on the image's ink)", head, "-" * len(head)]

    def row(name: str, d: str | None = None) -> str:
        def stats(key: str | None = None):  # None: Table I's statistics
            block = result if key is None else (result.get(key) or {})
            return block.get("overall") if d is None else per_label(block).get(d)

        return (
            f"{name:>{w}} {(stats() or {}).get('n', 0):>6} {_cell(stats(), 'mean', 8)} "
            f"{_cell(stats('path_error'), 'mean', 8)} {_cell(stats('chamfer'), 'mean', 8)} "
            f"{_cell(stats('on_ink'), 'mean', 6, 100, 1)} "
            f"{_cell(stats('on_ink_human'), 'mean', 6, 100, 1)} "
            f"{_cell(stats('area_ratio'), 'median', 6, 1, 2)} "
            f"{_cell(stats('start_error'), 'mean', 8)}"
        )

    lines += [row(d, d) for d in per_label(result)]
    lines += ["-" * len(head), row("all")]
    lines.append(
        "(means; area: median of enclosed area network / demonstration, closed digits "
        f"{', '.join(map(str, CLOSED_DIGITS))}"
        + (" only: classes of those names)" if what == "class" else ")")
    )
    best = result.get("best_of_k")
    if best:
        mean = {k: _cell(best[k]["overall"], "mean", 0) for k in ("trajectory_error", "path_error")}
        lines.append(
            f"best of K = {best['k']}: TableI {mean['trajectory_error']}, path "
            f"{mean['path_error']}, Chamfer {_cell(best['chamfer']['overall'], 'mean', 0)} px; "
            f"the most probable hypothesis is the best in {100 * best['top_is_best']:.0f} % "
            "of the samples"
        )
    strokes = result.get("strokes")
    if strokes:
        lines.append(_strokes_lines(strokes))
    if result.get("unfamiliar"):
        lines.append(_unfamiliar_line(result))
    return "\n".join(lines)


def _unfamiliar_line(result: dict) -> str:
    """How many samples the model found unfamiliar, and their refinement."""
    u, other = result["unfamiliar"], result.get("refine_unfamiliar_steps")
    steps = result.get("refine_steps")
    refined = f" (refined {other} steps instead of {steps})" if other is not None else ""
    return (
        f"unfamiliar to the model (familiarity below its line {u['line']:.4f}): "
        f"{100 * u['share']:.1f} % of the samples{refined}"
    )


def _strokes_lines(strokes: dict) -> str:
    """A stroke model's lines: the stroke count right, and the measures per alphabet."""
    views = strokes.get("count_views")
    read = f"read from {views} view{'s' * (views != 1)} of each image; " if views else ""
    lines = [f"stroke count right: {100 * strokes['count_right']:.1f} % ({read}TableI of a "
             "stroke model: its path by index at the demonstration's instants)"]  # fmt: skip
    mode = strokes.get("count_mode_right")  # absent from evaluations written before it
    if mode is not None:
        right = strokes.get("count_mode_count_right", strokes["count_right"])
        left = strokes.get("count_mode_training_left_out", 0)
        out, on = (f", its {left} training drawings left out", f", on them {100 * right:.1f} %") \
            if left else ("", "")  # fmt: skip
        lines.append(
            f"its ceiling, each class's most common count among its training drawings: "
            f"{100 * mode:.1f} % (of the {strokes['count_mode_n']} characters whose class has "
            f"training drawings{out}; the count right{on} is {100 * right / mode:.1f} % of it)"
        )
    elif "count_mode_right" in strokes:
        lines.append("its ceiling: none of these classes has training drawings (never seen)")
    bands = strokes.get("count_right_by_probability")
    if bands:
        said = "; ".join(
            f"{b['low']:.1f}-{b['high']:.1f}: {b['n']}, {100 * b['count_right']:.1f} % right"
            for b in bands
        )
        lines.append(f"the count right by the network's probability of it: {said}")
    per, modes = strokes["per_alphabet"], strokes.get("count_mode_right_per_alphabet", {})
    # with training drawings evaluated, the ceiling's rows are fewer: the count on them too
    same = strokes.get("count_mode_count_right_per_alphabet") \
        if strokes.get("count_mode_training_left_out") else None  # fmt: skip
    if len(per) > 1:
        w = max(len(a) for a in per)
        head = f"{'alphabet':>{w}} {'n':>5} {'path':>7} {'Chamfer':>8} {'ink %':>6} "
        lines.append(head + f"{'count %':>7} {'mode %':>6}" + (" on them %" if same else ""))
        for a, m in per.items():
            ceiling = f"{100 * modes[a]:>6.1f}" if a in modes else f"{'-':>6}"
            on_them = "" if not same else f" {100 * same[a]:>9.1f}" if a in same else f" {'-':>9}"
            lines.append(
                f"{a:>{w}} {m['n']:>5} {_cell(m, 'path_error', 7)} {_cell(m, 'chamfer', 8)} "
                f"{_cell(m, 'on_ink', 6, 100, 1)} {100 * m['count_right']:>7.1f} {ceiling}"
                + on_them
            )
        if same:
            lines.append("(mode % and on them %: the rows that are not training drawings; "
                         "count %: every row)")  # fmt: skip
    return "\n".join(lines)


def predict_hypotheses(predictor, images, times, batch_size: int = 2048):
    """All of a predictor's hypotheses for prepared images ``[M, H, W]`` at ``times [M, T]``.

    Uses ``predictor.hypothesis_trajectories(images, times, batch_size) -> (y [M, K, T, d],
    probs [M, K])`` when the predictor has it, else ``trajectories_for_images`` with
    K = 1 and probability 1.

    Returns
    -------
    y_all : ndarray [M, K, T, d]
    probs : ndarray float64 [M, K]
    """
    hypotheses = getattr(predictor, "hypothesis_trajectories", None)
    if hypotheses is None:
        y = np.asarray(predictor.trajectories_for_images(images, times, batch_size))  # [M, T, d]
        return y[:, None], np.ones((len(y), 1))
    y_all, probs = hypotheses(images, times, batch_size)
    return np.asarray(y_all), np.asarray(probs, dtype=np.float64)


def _check_hypotheses(y_all, probs, m: int):
    y_all, probs = np.asarray(y_all), np.asarray(probs, dtype=np.float64)
    if y_all.ndim != 4 or y_all.shape[0] != m or probs.shape != y_all.shape[:2]:
        raise ValueError(
            f"hypotheses must be y [M, K, T, d] and probs [M, K] with M = {m}, got "
            f"{y_all.shape} and {probs.shape}"
        )
    return y_all, probs


def top_hypothesis(y_all, probs):
    """The most probable hypothesis per sample: index ``[M]`` and path ``[M, T, d]``."""
    top = np.argmax(np.asarray(probs), axis=1)  # [M]
    return top, np.asarray(y_all)[np.arange(len(top)), top]


def _table1_errors(y, reference) -> np.ndarray:
    # Table I's metric, defined once (training validates with the same function).
    return trajectory_error_px(torch.as_tensor(y), torch.as_tensor(reference)).numpy()


#: Per-sample arrays of :func:`sample_metrics` and the name of their statistics.
METRIC_SUMMARIES = {
    "path_errors_px": "path_error",
    "chamfer_px": "chamfer",
    "on_ink_shares": "on_ink",
    "on_ink_human_shares": "on_ink_human",
    "start_errors_px": "start_error",
    "area_ratios": "area_ratio",
    "width_ratios": "width_ratio",
}


def sample_metrics(y, reference, images, labels, class_names=None) -> dict[str, np.ndarray]:
    """The timing-free measures ``[M]`` of paths ``y [M, T, d]`` against the
    demonstrations ``reference [M, T', d]`` drawn in ``images [M, H, W]``.

    Keys are those of :data:`METRIC_SUMMARIES`; ``area_ratios`` is NaN for digits not in
    :data:`~img2dmp.metrics.CLOSED_DIGITS` (and where the demonstration encloses nothing);
    with ``class_names``, for classes not named after one of those digits
    (:func:`~img2dmp.metrics.closed_labels`).
    """
    y, reference = np.asarray(y), np.asarray(reference)
    closed = np.isin(np.asarray(labels), closed_labels(class_names))  # [M]
    areas = np.full(len(y), np.nan)
    if closed.any():
        areas[closed] = area_ratio(y[closed], reference[closed])
    return {
        "path_errors_px": path_error_px(y, reference),
        "chamfer_px": chamfer_px(y, reference),
        "on_ink_shares": on_ink_share(images, y),
        "on_ink_human_shares": on_ink_share(images, reference),
        "start_errors_px": start_error_px(y, reference),
        "area_ratios": areas,
        "width_ratios": width_ratio(y, reference),
    }


def _summarise_finite(values, labels, class_names=None) -> dict:
    ok = np.isfinite(values)
    return summarise(values[ok], np.asarray(labels)[ok], class_names)


def _json_list(values) -> list:
    return [float(v) if np.isfinite(v) else None for v in np.asarray(values, dtype=np.float64)]


def _best_of_k(y_all, top, reference, labels, class_names=None) -> dict:
    """Per sample the smallest Table I, path and Chamfer errors over the K hypotheses."""
    m, k = y_all.shape[:2]
    flat = y_all.reshape(m * k, *y_all.shape[2:])  # [M K, T, d]
    ref_k = np.repeat(np.asarray(reference), k, axis=0)  # [M K, T, d]
    table1 = _table1_errors(y_all, np.asarray(reference)[:, None])  # [M, K]
    best = {
        "errors_px": table1.min(axis=1),
        "path_errors_px": path_error_px(flat, ref_k).reshape(m, k).min(axis=1),
        "chamfer_px": chamfer_px(flat, ref_k).reshape(m, k).min(axis=1),
    }
    names = {
        "errors_px": "trajectory_error",
        "path_errors_px": "path_error",
        "chamfer_px": "chamfer",
    }
    out = {"k": int(k), "top_is_best": float(np.mean(np.argmin(table1, axis=1) == top))}
    out.update({names[key]: summarise(v, labels, class_names) for key, v in best.items()})
    out.update({key: v.tolist() for key, v in best.items()})
    out["top_hypothesis"] = top.tolist()
    out["best_hypothesis"] = np.argmin(table1, axis=1).tolist()
    return out


def hypothesis_metrics(y_all, probs, reference, images, labels, class_names=None) -> dict:
    """Table I's statistics and the path measures of a network's hypotheses.

    Parameters
    ----------
    y_all : array [M, K, T, d]
        K hypotheses per sample at the demonstration's time stamps (K = 1: one path).
    probs : array [M, K]
        Their probabilities; the most probable one is the network's answer.
    reference : array [M, T, d]
        The demonstrations.
    images : array [M, H, W]
        The images they were written on (ink = 1).
    labels : array [M]
    class_names : sequence of str, optional
        The names the labels index into (a data set's ``class_names``); None: digits.

    Returns
    -------
    dict
        Statistics (:func:`summarise`) of the top hypothesis: ``overall`` and
        ``per_digit`` or ``per_class`` (Table I) and ``path_error``, ``chamfer``, ``on_ink``,
        ``on_ink_human``, ``start_error``, ``area_ratio`` (closed digits only),
        ``width_ratio``; per-sample lists ``errors_px`` and those of
        :data:`METRIC_SUMMARIES` (``None`` where undefined); ``hypotheses`` (K),
        ``pen_never_down`` (d = 3 paths that never write) and, for K > 1, ``best_of_k``.
    """
    reference = np.asarray(reference)
    y_all, probs = _check_hypotheses(y_all, probs, len(reference))
    labels = np.asarray(labels)
    top, y = top_hypothesis(y_all, probs)  # [M], [M, T, d]
    errors = _table1_errors(y, reference)  # [M]
    per_sample = sample_metrics(y, reference, images, labels, class_names)
    out = summarise(errors, labels, class_names)
    out.update(
        {
            name: _summarise_finite(per_sample[k], labels, class_names)
            for k, name in METRIC_SUMMARIES.items()
        }
    )
    out["errors_px"] = errors.tolist()
    out.update({k: _json_list(v) for k, v in per_sample.items()})
    out["hypotheses"] = int(y_all.shape[1])
    never = ~(y[..., 2] >= 0.5).any(axis=1) if y.shape[-1] >= 3 else np.zeros(len(y), bool)
    out["pen_never_down"] = int(never.sum())
    if y_all.shape[1] > 1:
        out["best_of_k"] = _best_of_k(y_all, top, reference, labels, class_names)
    return out


def _pick_split(data, split: str):
    if split == "all":
        return data
    if split == "auto":
        return data.select_split("test") if (data.split == SPLITS["test"]).any() else data
    if split not in SPLITS:
        raise ValueError(f"split must be one of {sorted(SPLITS)}, 'all' or 'auto', got {split!r}")
    return data.select_split(split)


def trained_on_split(meta: dict, dataset_sha256: str, splits) -> bool:
    """Whether a model (its checkpoint's ``meta``) trained on some of the samples of the
    data set with this digest whose split codes are ``splits``: its training split, and
    its validation split when it was trained with ``data.train_on_validation``. Its
    figures there are not a test."""
    trained = meta.get("dataset") or {}
    if not dataset_sha256 or trained.get("sha256") != dataset_sha256:
        return False
    data_cfg = (meta.get("train_config") or {}).get("data") or {}
    seen = [SPLITS["train"]] + [SPLITS["validation"]] * bool(data_cfg.get("train_on_validation"))
    return bool(np.isin(np.asarray(splits), seen).any())


def evaluate(
    model_path: str | os.PathLike | Predictor,
    dataset_path: str | os.PathLike,
    *,
    split: str = "auto",
    out_dir: str | os.PathLike | None = None,
    n_figures: int = 16,
    digits: list[int] | None = None,
    classes: list[str] | None = None,
    batch_size: int = 2048,
    seed: int = 0,
    refine: int = 0,
    count_views: int | None = None,
    device: str = "cpu",
    progress: bool = False,
    refine_unfamiliar: int | None = None,
) -> dict:
    """Table I's statistics and the path measures of a trained network on a data set.

    Parameters
    ----------
    model_path : path or Predictor
        Run directory or checkpoint file, or a loaded predictor (with
        ``hypothesis_trajectories`` for several hypotheses per image, see
        :func:`predict_hypotheses`).
    dataset_path : path
        A data set (``img2dmp.data.store`` format).
    split : {"auto", "all", "train", "validation", "test"}
        Samples to evaluate; ``"auto"`` = the test split if the file has one, else all.
    out_dir : path, optional
        Where to write ``evaluation.json``, ``evaluation.txt`` and ``examples.png``.
    n_figures : int
        Samples drawn in ``examples.png`` (chosen at random with ``seed``; 0 = none), at
        most ``MAX_FIGURES``.
    digits, classes : list of int, list of str, optional
        Keep only these digits (with class names: the classes named after them), or the
        classes of these names (e.g. ``["L", "T"]``); not both.
    refine, count_views : int, int or None
        Gradient steps refining each prediction on its image (:func:`img2dmp.nn.refine.refine`;
        0 = the network's output); a stroke model's views of each image to read its counts
        from (:attr:`~img2dmp.predict.Predictor.count_views`; None: the predictor's own).
    device, progress : str, bool
        Where the network runs when loaded from a path (``"cpu"``, ``"cuda"``); a bar.
    refine_unfamiliar : int or None
        Refinement steps of the images the model finds unfamiliar instead of ``refine``
        (:meth:`~img2dmp.predict.Predictor.refine_with`; the model must carry a
        familiarity); None: ``refine`` for every image.

    Returns
    -------
    dict
        ``overall`` and ``per_digit`` (or ``per_class``) statistics (Table I,
        :func:`_headline`) plus ``errors_px`` (per sample), a description of the model
        and data, and the path measures of :func:`hypothesis_metrics` (``path_error``,
        ``chamfer``, ``on_ink``, ``on_ink_human``, ``start_error``, ``area_ratio``,
        ``width_ratio`` with their per-sample lists; ``best_of_k`` for K > 1 hypotheses),
        ``refine_steps`` and ``refine_unfamiliar_steps`` (None: the same), and for a model
        that carries a familiarity ``unfamiliar``: its line, the share of the samples
        below it and every sample's familiarity.
    """
    t0 = time.perf_counter()  # the counts checked before anything slow: each bounds work
    n_figures = check_count("n_figures (--figures)", n_figures, 0, MAX_FIGURES)
    batch_size = check_count("batch_size", batch_size, 1, MAX_BATCH_SIZE)
    refine = check_count("refine (--refine)", refine, 0, MAX_REFINE_STEPS)
    predictor = _load_predictor(model_path, device, refine, count_views, refine_unfamiliar)
    whole = load_dataset(dataset_path)
    data = _evaluation_data(predictor, dataset_path, split, digits, classes, whole)
    y_all, probs, measures = _measured(predictor, data, batch_size, progress)
    if "strokes" in measures:
        st = measures["strokes"]
        st.update(count_ceiling(whole, data, st["predicted_counts"]))
    _, y = top_hypothesis(y_all, probs)  # [M, T, d]
    errors = np.asarray(measures["errors_px"])  # [M], Table I
    result = _headline(measures, data.class_names)
    result.update(_described(predictor, model_path, dataset_path, data, split, digits, classes))
    result.update(refine_steps=int(refine), **measures, **_unfamiliar(predictor, data, batch_size))
    result["wall_s"] = time.perf_counter() - t0
    if out_dir is not None:
        _write_evaluation(Path(out_dir), result, data, y, errors, n_figures, seed)
    return result


def _unfamiliar(predictor, data, batch_size: int) -> dict:
    """What :func:`evaluate` records of the unfamiliar samples: their refinement steps
    (None: the others'), and for a model with a familiarity :func:`unfamiliar_measures`."""
    out = {"refine_unfamiliar_steps": getattr(predictor, "refine_unfamiliar", None)}
    if getattr(predictor, "familiar", None) is not None:
        out["unfamiliar"] = unfamiliar_measures(predictor, data.images, batch_size)
    return out


def unfamiliar_measures(predictor, images, batch_size: int = 2048) -> dict:
    """How many of prepared images ``[M, H, W]`` the predictor's model finds unfamiliar
    (:mod:`img2dmp.familiar`): its ``line``, the ``share`` below it and every image's
    ``familiarity``."""
    line = float(predictor.familiar.line)
    fam = predictor.familiarity(images, batch_size)  # in parts, by the encoder and Familiar
    return {"line": line, "share": float(np.mean(fam < line)) if len(fam) else 0.0,
            "familiarity": [round(float(f), 6) for f in fam]}  # fmt: skip


def _described(predictor, model_path, dataset_path, data, split, digits, classes) -> dict:
    """What :func:`evaluate` measured: the model, the data set (and its digest), the
    samples chosen, and whether the model trained on them."""
    sha = file_digest(dataset_path)
    return dict(
        model=str(model_path),
        dataset=str(dataset_path),
        dataset_sha256=sha,
        split=split,
        digits=digits,
        classes=classes,
        trained_on=predictor.meta.get("dataset"),
        cost=predictor.meta.get("train_config", {}).get("cost", {}).get("name"),
        fit_error_px=error_statistics(data.fit_error_px),
        trained_on_split=trained_on_split(predictor.meta, sha, data.split),
        untrained_classes=untrained_classes(predictor.meta, data),
        framing=framing(predictor, data.images),
    )


def untrained_classes(meta: dict, data) -> list[str]:
    """The classes of ``data``'s samples that the model (its checkpoint's ``meta``) never
    trained on: outside its run's ``data.classes`` or ``data.digits``, or else outside
    the classes of the data set it trained on; [] when those are not recorded (a model
    of the generator's digits, an older checkpoint)."""
    data_cfg = (meta.get("train_config") or {}).get("data") or {}
    if data_cfg.get("classes"):
        learnt = {str(c) for c in data_cfg["classes"]}
    elif data_cfg.get("digits") is not None:
        learnt = {str(d) for d in data_cfg["digits"]}
    elif (meta.get("dataset") or {}).get("path"):
        names = (meta.get("dataset") or {}).get("class_names")
        learnt = {str(c) for c in names} if names else {str(d) for d in range(10)}
    else:
        return []
    names = data.label_names
    shown = sorted({int(label) for label in np.unique(np.asarray(data.labels))})
    return [names[label] for label in shown if names[label] not in learnt]


#: A data set's ink margin this far (share of the side) from the one its model trained
#: on is framed otherwise: its figures say how the model reads images framed unlike
#: what it learnt, not how it reads this data (:func:`framing`).
MARGIN_TOLERANCE = 0.05


def framing(predictor, images) -> dict:
    """How prepared images ``[M, H, W]`` are framed beside the model's training images:
    ``data_ink_margin`` (:func:`~img2dmp.data.images.ink_margin` of up to 500 of them),
    ``model_ink_margin`` (the predictor's; None for one without a ``margin``), and
    ``same`` (within :data:`MARGIN_TOLERANCE`; True when the model's is unknown)."""
    from .data.images import ink_margin

    data_margin = ink_margin(images[:500])
    model_margin = getattr(predictor, "margin", None)  # None: a stand-in predictor's
    if model_margin is not None:
        model_margin = round(float(model_margin), 4)
    same = model_margin is None or abs(data_margin - model_margin) <= MARGIN_TOLERANCE
    return {"data_ink_margin": round(data_margin, 4), "model_ink_margin": model_margin,
            "same": bool(same)}  # fmt: skip


def _measured(predictor, data, batch_size: int, progress: bool = False):
    """The hypotheses ``[M, K, T, d]``, their probabilities ``[M, K]`` and the path
    measures of :func:`hypothesis_metrics` (a stroke model's also ``strokes``,
    :func:`stroke_measures`, with the ``count_views`` its counts were read from).

    Predicted in parts of ``batch_size`` samples, or of :data:`REFINE_PART` when the
    predictor refines (slow work: the bar of ``progress`` moves part by part)."""
    strokes = getattr(predictor, "strokes", None) is not None
    refining = getattr(getattr(predictor, "refine_options", None), "steps", 0)
    step = min(batch_size, REFINE_PART) if refining else batch_size
    t, parts = data.trajectories.shape[1], []
    with bar(desc="evaluate", total=len(data), unit="sample", enabled=progress) as shown:
        for a in range(0, len(data), step):
            part = slice(a, a + step)
            if strokes:  # (y, probs, counts, the counts' probabilities)
                parts.append(_stroke_predictions(predictor, data.images[part], t, batch_size))
            else:  # (y, probs)
                parts.append(predict_hypotheses(predictor, data.images[part], data.times[part],
                                                batch_size))  # fmt: skip
            shown.update(len(parts[-1][0]))
    joined = [np.concatenate(v) for v in zip(*parts, strict=True)]
    y_all, probs = joined[0], joined[1]
    measures = hypothesis_metrics(
        y_all, probs, data.trajectories, data.images, data.labels, data.class_names
    )
    if strokes:
        read = {"count_views": int(predictor.count_views)}
        measures["strokes"] = {**stroke_measures(joined[2], data, measures, joined[3]), **read}
    return y_all, probs, measures


def _stroke_predictions(predictor, images, t: int, batch_size: int):
    """A stroke model's characters ``[M, 1, t, 3]`` of prepared images ``[M, H, W]`` (the
    path by its instants' index at t, :meth:`~img2dmp.predict.Predictor.stroke_paths`),
    probabilities 1, the predicted stroke counts ``[M]`` and the network's probability
    of each count read ``[M]``."""
    from .nn.strokes import character_paths

    strokes, probs = predictor.predict_strokes(images, batch_size, return_counts=True)
    paths = character_paths(strokes, predictor.normaliser, predictor.strokes)
    y = np.stack([index_resampled(p, t) for p in paths])[:, None]
    counts = np.array([len(v) for v, _ in strokes])
    return y, np.ones((len(y), 1)), counts, probs[np.arange(len(counts)), counts - 1]


def _share(ok: np.ndarray, groups: np.ndarray, names) -> dict:
    return {str(names[g]): float(np.mean(ok[groups == g])) for g in np.unique(groups)}


def stroke_measures(counts, data, measures: dict, sure=None) -> dict:
    """What a stroke model adds to the evaluation: the share of characters whose stroke
    count is right (overall, per class, per alphabet: the class name's part before
    ``/``, as Omniglot's ``alphabet/character``), the true and predicted counts, and the
    path measures per alphabet; with ``sure`` (the network's probability of each count
    read ``[M]``) those probabilities and the count right by them
    (:func:`count_right_by_probability`)."""
    truth = stroke_counts(data)
    ok = np.asarray(counts) == truth
    names = data.label_names
    alphabets, groups = np.unique(row_alphabets(data), return_inverse=True)
    per_alphabet = {}
    for key, name in (("path_errors_px", "path_error"), ("chamfer_px", "chamfer"),
                      ("on_ink_shares", "on_ink")):  # fmt: skip
        v = np.asarray(measures[key], dtype=np.float64)
        for g, a in enumerate(alphabets):
            sel = (groups == g) & np.isfinite(v)
            per_alphabet.setdefault(str(a), {})[name] = float(v[sel].mean()) if sel.any() else None
    for g, a in enumerate(alphabets):
        sel = groups == g
        per_alphabet[str(a)].update(n=int(sel.sum()), count_right=float(ok[sel].mean()))
    result = {
        "count_right": float(ok.mean()),
        "count_right_per_class": _share(ok, np.asarray(data.labels), names),
        "per_alphabet": per_alphabet,
        "true_counts": truth.tolist(),
        "predicted_counts": np.asarray(counts).tolist(),
    }
    if sure is not None:
        sure = np.asarray(sure, dtype=np.float64)
        result["count_probabilities"] = [round(float(p), 6) for p in sure]
        result["count_right_by_probability"] = count_right_by_probability(ok, sure)
    return result


#: The edges of the bands of the count's probability in which the evaluation reports the
#: count right (:func:`count_right_by_probability`).
COUNT_SURE_EDGES = (0.5, 0.7, 0.9)


def count_right_by_probability(ok, sure, edges=COUNT_SURE_EDGES) -> list[dict]:
    """How often counts said with a probability in each band are right: per band
    ``[low, high)`` of ``edges`` (from 0 to 1, the last band closed) the number of
    characters, the share whose count is right (``ok [M]``) and their mean probability
    (``sure [M]``); empty bands are left out. A calibrated count is right about as often
    as its probability says."""
    ok, sure = np.asarray(ok, dtype=bool), np.asarray(sure, dtype=np.float64)
    bounds = [0.0, *edges, 1.0]
    rows = []
    for low, high in zip(bounds[:-1], bounds[1:], strict=True):
        sel = (sure >= low) & ((sure < high) if high < 1.0 else (sure <= high))
        if sel.any():
            rows.append({"low": low, "high": high, "n": int(sel.sum()),
                         "count_right": float(ok[sel].mean()),
                         "mean_probability": float(sure[sel].mean())})  # fmt: skip
    return rows


def row_alphabets(data) -> np.ndarray:
    """The alphabet of every row ``[N]``: its class name's part before ``/``, as
    Omniglot's ``alphabet/character`` (a digit's name, ``"3"``, is its own)."""
    names = data.label_names
    return np.array([str(names[int(c)]).split("/")[0] for c in data.labels])


def stroke_counts(data) -> np.ndarray:
    """The stroke count of every row of a data set ``[N]`` (its recorded stroke spans)."""
    return np.array([len(data.stroke_spans(i)) for i in range(len(data))], dtype=np.int64)


def class_modes(data, counts: np.ndarray | None = None) -> dict[int, int]:
    """Each class's most common stroke count among its training drawings (ties: the
    smaller count), for the classes that have training drawings; ``counts`` the stroke
    count of every row (:func:`stroke_counts`), if already read."""
    counts = stroke_counts(data) if counts is None else np.asarray(counts)
    labels = np.asarray(data.labels)
    train = np.asarray(data.split) == SPLITS["train"]
    mode = {}
    for c in np.unique(labels[train]):
        seen = Counter(counts[(labels == c) & train].tolist())
        mode[int(c)] = min(seen, key=lambda k: (-seen[k], k))
    return mode


def count_ceiling(whole, data, predicted=None) -> dict:
    """What a reader that recognised every character and answered its class's most
    common count among the training drawings of ``whole`` (:func:`class_modes`) would
    score on the rows of ``data`` (a selection of ``whole``: the same labels): the count
    right's ceiling for a count learnt per character (RESULTS 8.3).

    ``count_mode_right`` (overall, ``None`` when no evaluated class has training
    drawings: characters never seen in training) over the ``count_mode_n`` rows whose
    class has training drawings, and per alphabet (``count_mode_right_per_alphabet``).
    Training rows among ``data`` (an evaluation of ``all`` or ``train``) are left out, as
    their own counts make the modes (``count_mode_training_left_out`` of them). With the
    rows' ``predicted`` counts, ``count_mode_count_right``: the count right on the same
    rows, for comparing with the ceiling (and per alphabet,
    ``count_mode_count_right_per_alphabet``)."""
    modes = class_modes(whole)
    truth, labels = stroke_counts(data), np.asarray(data.labels)
    training = np.asarray(data.split) == SPLITS["train"]
    seen = np.isin(labels, list(modes)) & ~training
    ok = np.array([seen[i] and truth[i] == modes[int(labels[i])] for i in range(len(data))])
    alphabet = row_alphabets(data)
    per = {str(a): float(ok[(alphabet == a) & seen].mean())
           for a in np.unique(alphabet) if ((alphabet == a) & seen).any()}  # fmt: skip
    out = {
        "count_mode_right": float(ok[seen].mean()) if seen.any() else None,
        "count_mode_n": int(seen.sum()),
        "count_mode_right_per_alphabet": per,
        "count_mode_training_left_out": int(training.sum()),
    }
    if predicted is not None and seen.any():
        right = np.asarray(predicted) == truth
        out["count_mode_count_right"] = float(right[seen].mean())
        out["count_mode_count_right_per_alphabet"] = {
            a: float(right[(alphabet == a) & seen].mean()) for a in per
        }
    return out


def _headline(measures: dict, class_names) -> dict:
    """Table I's statistics, taken out of :func:`hypothesis_metrics`' ``measures``:
    ``overall``, ``per_digit`` and ``path_error``; for a data set with class names
    ``per_class`` (keyed by class name) and the ``class_names`` instead of ``per_digit``."""
    per = "per_digit" if class_names is None else "per_class"
    result = {key: measures.pop(key) for key in ("overall", per, "path_error")}
    if class_names is not None:
        result["class_names"] = list(class_names)
    return result


def _load_predictor(model, device: str = "cpu", refine: int = 0, count_views=None,
                    refine_unfamiliar=None):  # fmt: skip
    """A :class:`Predictor` loaded from a path, or ``model`` itself if it is one already
    (any object with ``trajectories_for_images`` or ``hypothesis_trajectories``), set to
    refine its predictions with ``refine`` steps (when not 0; the unfamiliar ones with
    ``refine_unfamiliar`` when not None) and, a stroke model, to read its counts from
    ``count_views`` views (when not None; a one-DMP model refuses it)."""
    if count_views is not None:  # before the model is read
        check_count("count_views (--count-views)", count_views, 1, MAX_COUNT_VIEWS)
    if refine_unfamiliar is not None:
        check_count("refine_unfamiliar (--refine-unfamiliar)", refine_unfamiliar, 0,
                    MAX_REFINE_STEPS)  # fmt: skip
    if not (hasattr(model, "trajectories_for_images") or hasattr(model, "hypothesis_trajectories")):
        model = Predictor.load(model, device=device)
    if count_views is not None:
        model.count_with(count_views)
    if (refine or refine_unfamiliar is not None) and hasattr(model, "refine_with"):
        model.refine_with(int(refine), refine_unfamiliar)
    elif refine_unfamiliar is not None:
        raise ValueError("refine_unfamiliar (--refine-unfamiliar) needs a Predictor")
    elif refine:
        from .nn.refine import RefineOptions

        model.refine_options = RefineOptions(steps=int(refine))
    return model


def _evaluation_data(predictor: Predictor, dataset_path, split: str, digits, classes=None,
                     whole=None):  # fmt: skip
    """The samples of ``split`` (and ``digits`` or ``classes``) of a data set (``whole``
    if already read), checked against the model."""
    data = _pick_split(load_dataset(dataset_path) if whole is None else whole, split)
    wanted = data.labels_selected(digits, classes)
    if wanted is not None:
        data = data.subset(np.isin(data.labels, wanted))
    if len(data) == 0:
        raise ValueError(
            f"data set {dataset_path} has no samples in split {split!r}"
            + (f" with labels {digits}" if digits is not None else "")
            + (f" of the classes {classes}" if classes is not None else "")
        )
    if tuple(data.image_size) != predictor.image_size:
        raise ValueError(
            f"data set {dataset_path} has {data.image_size} images, the model expects "
            f"{predictor.image_size}"
        )
    strokes = getattr(predictor, "strokes", None) is not None  # any path: its pen runs
    if not strokes and data.dmp_config.n_dims != predictor.dmp_config.n_dims:
        raise ValueError(
            f"data set {dataset_path} has d={data.dmp_config.n_dims} dimensions, the model "
            f"d={predictor.dmp_config.n_dims}"
        )
    return data


def _write_evaluation(out: Path, result: dict, data, y, errors, n_figures: int, seed: int):
    """``evaluation.json``, ``evaluation.txt`` and (``n_figures`` > 0) ``examples.png``
    (random samples) and ``worst.png`` (the 12 largest path errors)."""
    from .data.plotting import overlay_figure

    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "evaluation.json", json.dumps(result, indent=1) + "\n")
    atomic_write_text(out / "evaluation.txt", format_table(result) + "\n")
    if n_figures <= 0:
        return
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(len(data), size=min(n_figures, len(data)), replace=False))
    names = data.label_names
    titles = [f"{names[int(data.labels[i])]}: {errors[i]:.3f} px" for i in pick]
    labels = ("demonstration", "network's DMP")
    overlay_figure(out / "examples.png", data.images[pick], data.trajectories[pick], y[pick],
                   titles, labels=labels)  # fmt: skip
    # The samples the network does worst on, by the timing-free path error.
    path_errors = np.asarray(result["path_errors_px"])
    worst = np.argsort(-path_errors)[: min(n_figures, 12, len(data))]
    titles = [f"{names[int(data.labels[i])]}: path {path_errors[i]:.2f} px" for i in worst]
    overlay_figure(out / "worst.png", data.images[worst], data.trajectories[worst], y[worst],
                   titles, labels=labels)  # fmt: skip


def __getattr__(name: str):
    # overlay_figure lives in data.plotting now; it is still importable from here, but
    # loaded on first use so that importing this module does not start matplotlib.
    if name == "overlay_figure":
        from .data.plotting import overlay_figure

        return overlay_figure
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
