"""Stroke models: a character as up to S strokes, each its own DMP (issue 32, part 4).

Against hand-made strokes: where the samplers read a path's strokes, that the matching
pairs each true stroke with the slot that holds it (in any order, or in order only with
``matching="order"``), how a network output is read (count, presence, order keys) and
rolled out (strokes with straight pen-up travel), that refinement pulls strokes onto
the ink, the configuration's refusals, and a short training on Omniglot-like drawings
that must learn the stroke counts.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import torch

from img2dmp import cli
from img2dmp.config import ConfigError
from img2dmp.data.store import load_dataset
from img2dmp.nn.refine import RefineOptions
from img2dmp.nn.strokes import (
    COUNT_VIEWS,
    StrokeCost,
    StrokeLayout,
    character_paths,
    count_probabilities,
    count_views,
    fit_stroke_normaliser,
    fit_stroke_vectors,
    ink_pieces,
    pen_spans,
    read_strokes,
    refine_strokes,
    stroke_samplers,
    stroke_targets,
)
from img2dmp.training.config import load_config
from img2dmp.training.data import count_targets, one_dmp_note, slots_note


def _path(strokes: list[np.ndarray], gap: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Strokes ``[k, 2]`` as one path ``[T, 3]`` (pen 1 on them, 0 on ``gap`` travel
    points between) at 0.01 s per instant."""
    rows = []
    for i, s in enumerate(strokes):
        rows.append(np.column_stack([s, np.ones(len(s))]))
        if i + 1 < len(strokes):
            f = np.linspace(0, 1, gap + 2)[1:-1, None]
            a, b = s[-1], strokes[i + 1][0]
            rows.append(np.column_stack([a + f * (b - a), np.zeros(gap)]))
    p = np.concatenate(rows)
    return p, np.arange(len(p)) * 0.01


BAR = np.linspace([5.0, 10.0], [30.0, 10.0], 26)
DOT = np.array([[20.0, 20.0]])
_A = np.linspace(0, np.pi, 31)
ARC = np.stack([18 + 8 * np.cos(_A), 28 + 6 * np.sin(_A)], -1)


def test_the_pen_runs_are_the_strokes_and_a_two_dimensional_path_is_one():
    p, _ = _path([BAR, DOT, ARC])
    assert pen_spans(p) == [(0, 25), (29, 29), (33, 63)]
    assert pen_spans(p[:, :2]) == [(0, len(p) - 1)]
    assert pen_spans(np.column_stack([p[:, :2], np.zeros(len(p))])) == [(0, len(p) - 1)]


def test_samplers_read_each_stroke_evenly_in_time_keep_a_dot_and_count_beyond_s():
    lay = StrokeLayout(slots=2, n_points=11)
    p, t = _path([BAR, DOT, ARC])
    pts, present, duration, n = stroke_targets(
        torch.as_tensor(p[None]), torch.as_tensor(t[None]), lay
    )
    assert n.tolist() == [3]  # all strokes counted, the first S kept
    assert present.tolist() == [[True, True]]
    np.testing.assert_allclose(pts[0, 0].numpy(), np.linspace(BAR[0], BAR[-1], 11), atol=1e-12)
    np.testing.assert_allclose(pts[0, 1].numpy(), np.repeat(DOT, 11, 0), atol=1e-12)
    np.testing.assert_allclose(duration[0].numpy(), [0.25, 0.02])  # a dot: MIN_STROKE_S
    with pytest.raises(ValueError, match="row 0 has no stroke"):
        stroke_samplers([[]], t[None], lay)


def _setting(strokes, slots=3, matching="best"):
    lay = StrokeLayout(slots=slots, n_points=24, matching=matching)
    p, t = _path(strokes)
    target, present, duration, n = stroke_targets(
        torch.as_tensor(p[None]), torch.as_tensor(t[None]), lay
    )
    pts, dur = target[present].numpy(), duration[present].numpy()
    rng = np.random.default_rng(0)  # a normaliser needs spread: jittered copies
    jitter = pts[None] + rng.normal(0, 1.0, (8, *pts.shape))
    norm = fit_stroke_normaliser(jitter.reshape(-1, *pts.shape[1:]), np.tile(dur, 8), lay)
    vectors, err = fit_stroke_vectors(pts, dur, lay)
    assert err < 0.05
    return lay, norm, torch.as_tensor(vectors), (target, present, duration, n)


def _output(lay, norm, vectors, slots_order, count, keys=None):
    """A network output ``[1, S (P + 3)]`` whose slots ``slots_order[j]`` hold stroke j."""
    z = norm.normalise(vectors)  # [n, P]
    out = torch.zeros(lay.slots, lay.slot_width, dtype=torch.float64)
    out[:, lay.n_params] = -8.0  # absent
    for j, slot in enumerate(slots_order):
        out[slot, : lay.n_params] = z[j]
        out[slot, lay.n_params] = 8.0
        out[slot, lay.n_params + 1] = (keys or slots_order)[j] if keys else j / (lay.slots - 1)
    counts = torch.full((lay.slots,), -8.0, dtype=torch.float64)
    counts[count - 1] = 8.0
    return torch.cat([out.reshape(-1), counts])[None]


def test_best_matching_finds_the_strokes_in_any_slots_and_order_matching_only_in_order():
    lay, norm, vectors, (target, present, duration, n) = _setting([BAR, ARC])
    cost = StrokeCost(lay, norm, presence_weight=0, count_weight=0, order_weight=0, tau_weight=0)
    swapped = _output(lay, norm, vectors, [2, 0], 2)
    _, err = cost.strokes_cost(swapped, target, present, duration, n)
    assert float(err[0]) < 0.05  # each stroke found in its slot
    lay_o = StrokeLayout(slots=3, n_points=24, matching="order")
    cost_o = StrokeCost(lay_o, norm, presence_weight=0, count_weight=0, tau_weight=0)
    _, err_o = cost_o.strokes_cost(swapped, target, present, duration, n)
    assert float(err_o[0]) > 5.0  # slot 0 holds the arc, compared with the bar
    in_order = _output(lay, norm, vectors, [0, 1], 2)
    assert float(cost_o.strokes_cost(in_order, target, present, duration, n)[1][0]) < 0.05


def test_the_cost_has_gradients_everywhere_and_steps_on_it_learn_a_character():
    lay, norm, vectors, (target, present, duration, n) = _setting([BAR, DOT, ARC])
    cost = StrokeCost(lay, norm)
    out = torch.zeros(1, lay.n_outputs, dtype=torch.float64, requires_grad=True)
    first, _ = cost.strokes_cost(out, target, present, duration, n)
    adam = torch.optim.Adam([out], lr=0.05)
    for _ in range(300):
        loss, err = cost.strokes_cost(out, target, present, duration, n)
        adam.zero_grad()
        loss.backward()
        assert torch.isfinite(out.grad).all()
        adam.step()
    assert float(loss.detach()) < 0.1 * float(first.detach())
    assert float(err[0]) < 1.0
    (strokes,) = read_strokes(out.detach().numpy(), lay, 1)
    assert len(strokes[0]) == 3  # count, presence and order learnt


def test_a_character_is_its_strokes_in_key_order_with_straight_pen_up_travel():
    lay, norm, vectors, _ = _setting([BAR, DOT, ARC])
    out = _output(lay, norm, vectors, [1, 2, 0], 3, keys=[0.1, 0.5, 0.9]).numpy()
    (strokes,) = read_strokes(out, lay, 1)
    (path,) = character_paths([strokes], norm, lay, n_per_stroke=20, n_travel=4)
    assert path.shape == (3 * 20 + 2 * 4, 3)
    assert pen_spans(path) == [(0, 19), (24, 43), (48, 67)]
    np.testing.assert_allclose(path[0, :2], BAR[0], atol=0.1)  # the bar first (key 0.1)
    np.testing.assert_allclose(path[24:44, :2], np.repeat(DOT, 20, 0), atol=0.1)
    np.testing.assert_allclose(path[-1, :2], ARC[-1], atol=0.1)
    travel = path[20:24, :2]
    line = np.linspace(path[19, :2], path[24, :2], 6)[1:-1]
    np.testing.assert_allclose(travel, line, atol=1e-9)
    out_two = _output(lay, norm, vectors, [1, 2, 0], 2, keys=[0.1, 0.5, 0.9]).numpy()
    assert len(read_strokes(out_two, lay, 1)[0][0]) == 2  # the count decides


def test_the_count_is_read_from_given_probabilities_and_never_below_the_ink_pieces():
    lay, norm, vectors, _ = _setting([BAR, DOT, ARC])
    out = _output(lay, norm, vectors, [1, 2, 0], 2, keys=[0.1, 0.5, 0.9]).numpy()
    assert len(read_strokes(out, lay, 1)[0][0]) == 2  # the outputs' own count
    probs = np.zeros((1, 1, lay.slots))
    probs[0, 0, 2] = 0.6  # averaged views say 3
    assert len(read_strokes(out, lay, 1, count_probs=probs)[0][0]) == 3
    # three pieces of ink cannot be two strokes: the likeliest count of at least 3
    assert len(read_strokes(out, lay, 1, min_counts=[3])[0][0]) == 3
    assert len(read_strokes(out, lay, 1, min_counts=[40])[0][0]) == lay.slots  # capped at S


def test_ink_pieces_count_unbroken_lines_and_leave_single_specks_out():
    image = np.zeros((3, 40, 40))
    image[0, 10, 5:30] = 1.0  # a bar
    image[0, 12:30, 20] = 0.8  # a stroke below it, not touching
    image[0, 35, 35] = 1.0  # a speck of one pixel
    image[1, 10, 5:30] = 1.0
    image[1, 11:30, 20] = 0.8  # touching the bar: one piece
    image[2, 20:22, 20:22] = 0.4  # too faint
    assert ink_pieces(image).tolist() == [2, 1, 0]


def test_count_views_are_small_fixed_affine_copies():
    rng = np.random.default_rng(3)
    x = rng.random((2, 40, 40)).astype(np.float32)
    views = count_views(x, 5)
    assert views.shape == (4, 2, 40, 40) and views.dtype == np.float32
    np.testing.assert_array_equal(views, count_views(x, 5))  # the same views every call
    assert count_views(x, 1).shape == (0, 2, 40, 40)
    moved = np.abs(views - x[None]).mean((1, 2, 3))
    assert (moved > 0.01).all() and (moved < 0.5).all()  # moved, a little


def test_count_probabilities_average_the_views_softmax():
    a = np.array([[[[0.0, 2.0]]], [[[2.0, 0.0]]]])  # two views [V, B, K, S] that disagree
    np.testing.assert_allclose(count_probabilities(a), [[[0.5, 0.5]]])
    one = count_probabilities(a[0])
    np.testing.assert_allclose(one.sum(-1), 1.0)
    assert one[0, 0, 1] > 0.85


class _Drawings:
    """What count_targets reads of a data set: labels and each row's strokes."""

    def __init__(self, labels, counts):
        self.labels, self.counts = np.asarray(labels), counts

    def stroke_spans(self, row):
        return [(2 * j, 2 * j + 1) for j in range(self.counts[row])]

    def __len__(self):
        return len(self.labels)


def test_the_count_target_mixes_a_drawing_s_count_with_its_class_s_among_training_rows():
    a = _Drawings([0, 0, 0, 0, 1, 2], [2, 2, 3, 9, 1, 4])
    train = np.array([0, 1, 2, 4])
    own = count_targets(a, np.arange(6), train, slots=4, class_weight=0.0).numpy()
    np.testing.assert_array_equal(own.argmax(1), [1, 1, 2, 3, 0, 3])  # 9 strokes count as S
    np.testing.assert_array_equal(own.sum(1), 1.0)
    mixed = count_targets(a, np.array([2, 3, 5]), train, slots=4, class_weight=0.5).numpy()
    class0 = np.array([0, 2, 1, 0]) / 3  # class 0's training rows: 2, 2 and 3 strokes
    np.testing.assert_allclose(mixed[0], 0.5 * np.eye(4)[2] + 0.5 * class0, atol=1e-7)
    np.testing.assert_allclose(mixed[1], 0.5 * np.eye(4)[3] + 0.5 * class0, atol=1e-7)
    np.testing.assert_allclose(mixed[2], np.eye(4)[3])  # class 2 has no training row


def test_training_notes_drawings_of_more_strokes_than_slots_and_is_silent_without():
    a = _Drawings([0, 0, 1, 1, 2], [2, 9, 4, 5, 12])
    assert slots_note(a, np.array([0, 2, 3]), slots=5) is None
    note = slots_note(a, np.arange(5), slots=5)
    assert note.startswith("note: 2 of 5 training drawings (40.0 %) have more than")
    assert "strokes.slots = 5 strokes (up to 12)" in note and "\n" not in note
    assert note.endswith("--set strokes.slots=12 holds them all (at most 32)")
    assert slots_note(a, np.arange(5), slots=12) is None


def test_a_one_dmp_model_of_drawings_of_several_strokes_is_pointed_to_stroke_models():
    a = _Drawings([0, 0, 1, 1], [1, 1, 3, 1])
    assert one_dmp_note(a, np.array([0, 1, 3])) is None  # one stroke each: nothing to say
    note = one_dmp_note(a, np.arange(4))
    assert note.startswith("note: 1 of 4 training drawings (25.0 %) have several strokes")
    assert "(up to 3)" in note and "--config omniglot" in note and "\n" not in note


def test_the_slots_note_names_the_limit_and_the_drawings_beyond_it():
    a = _Drawings([0, 1, 1, 1, 2], [2, 40, 40, 33, 9])  # rows 1 and 2: one file, augmented
    a.label_names, files = ("eye", "grid", "hook"), ["e/0.csv", "g/0.csv", "g/0.csv", "g/1.csv"]
    a.meta = {"rows": {"trajectory": [*files, "h/0.csv"]}}
    note = slots_note(a, np.arange(5), slots=8)
    assert "(up to 40)" in note and "strokes.slots is at most 32" in note and "\n" not in note
    assert "the 2 drawing(s) of the class grid (g/0.csv, g/1.csv), which have more" in note
    assert note.endswith("or learn their first 32 strokes (--set strokes.slots=32)")
    assert slots_note(a, np.arange(5), slots=32).endswith("their first 32 strokes")
    a.meta = {}  # no files recorded: the rows
    assert "(row 1, row 2, row 3)" in slots_note(a, np.arange(5), slots=8)


def test_a_one_count_target_is_the_count_s_own_cross_entropy_and_a_class_s_pulls_its_mode():
    lay, norm, vectors, (target, present, duration, n) = _setting([BAR, ARC])
    cost = StrokeCost(lay, norm, count_weight=1.0)
    logits = torch.randn(1, 1, lay.slots, dtype=torch.float64, requires_grad=True)
    hard = cost._count_ce(logits, n)
    onehot = torch.nn.functional.one_hot(n.clamp(1, lay.slots) - 1, lay.slots).double()
    torch.testing.assert_close(cost._count_ce(logits, n, onehot), hard)
    soft = torch.zeros(1, lay.slots, dtype=torch.float64)
    soft[0, 2] = 1.0  # the class's drawers mostly drew 3 strokes
    cost._count_ce(logits, n, soft).sum().backward()
    assert logits.grad[0, 0, 2] < 0  # a step raises the count 3


def test_refinement_pulls_a_shifted_stroke_back_onto_its_ink():
    lay, norm, vectors, _ = _setting([BAR, ARC], slots=2)
    image = np.zeros((40, 40))
    for s in (BAR, ARC):
        fine = np.concatenate([np.linspace(a, b, 10) for a, b in zip(s[:-1], s[1:], strict=True)])
        image[np.round(fine[:, 1]).astype(int), np.round(fine[:, 0]).astype(int)] = 1.0
    v = vectors.clone()
    v[:, -4:] += 2.5  # g and y0 of both strokes moved 2.5 px off the ink
    z = norm.normalise(v).numpy()
    strokes = [(z, np.ones(2))]

    def off(st):
        (path,) = character_paths(st, norm, lay)
        ink = np.argwhere(image > 0)[:, ::-1]
        d = np.linalg.norm(path[path[:, 2] > 0.5, None, :2] - ink[None], axis=-1)
        return d.min(1).mean()

    refined = refine_strokes(strokes, image[None], norm, lay, RefineOptions(steps=60))
    assert off(refined) < 0.5 * off(strokes)


@pytest.mark.parametrize(
    "setting, message",
    [
        ("strokes.slots=40", "strokes.slots must be an integer from 1 to 32"),
        ("strokes.matching=greedy", "strokes.matching must be one of"),
        ("strokes.presence_weight=-1", "strokes.presence_weight"),
        ("strokes.count_class_weight=1.5", "strokes.count_class_weight must be a number from 0"),
    ],
)
def test_bad_stroke_settings_are_refused_by_name(setting, message):
    with pytest.raises(ConfigError, match=message):
        load_config(None, ["data.path=x.safetensors", setting])


def test_a_stroke_model_refuses_what_it_cannot_honour(tmp_path, capsys):
    base = ["strokes.slots=4", "data.path=x.safetensors"]
    with pytest.raises(ConfigError, match="cost.name must be 'trajectory'"):
        load_config(None, [*base, "cost.name=parameter"])
    load_config(None, ["strokes.slots=4"])  # a configuration without its data loads ...
    assert cli.main(["train", "--config", "omniglot", "--run-dir", str(tmp_path / "r")]) == 2
    assert "set data.path" in capsys.readouterr().err  # ... and does not train
    with pytest.raises(ConfigError, match="cost.path_weight is not used"):
        load_config(None, [*base, "cost.path_weight=1"])


@pytest.fixture(scope="module")
def trained(stroke_run):
    """The tiny stroke model of conftest's ``stroke_run`` (on ``small_omniglot``)."""
    return stroke_run


def test_a_short_training_learns_the_stroke_counts_and_shapes(small_omniglot, trained):
    from img2dmp.checkpoint import load_checkpoint
    from img2dmp.nn.model import ModelConfig, build_model

    ckpt = load_checkpoint(trained)
    lay = StrokeLayout.from_dict(ckpt.meta["strokes"])
    assert lay.slots == 8
    curve = np.genfromtxt(trained / "metrics.csv", delimiter=",", names=True)
    assert curve["val_error_px"][-1] < 0.5 * curve["val_error_px"][0]
    data = load_dataset(small_omniglot)
    val = np.flatnonzero(data.split > 0)
    net = build_model(ModelConfig.from_dict(ckpt.meta["model"]))
    net.load_state_dict(ckpt.model_state)
    with torch.no_grad():
        out = net.eval()(torch.as_tensor(data.images[val])).numpy()
    counts = [len(v) for v, _ in read_strokes(out, lay, 1)]
    truth = [len(data.stroke_spans(i)) for i in val]
    assert np.mean(np.equal(counts, truth)) >= 0.9


def test_a_stroke_run_names_its_error_the_stroke_shape_error_not_the_trajectory_error(
    small_omniglot, tmp_path, capsys
):
    from img2dmp.checkpoint import read_checkpoint_meta

    run = tmp_path / "run"
    args = ["train", "--config", "omniglot", "--data", str(small_omniglot), "--run-dir",
            str(run), "--epochs", "2", "--set", "optim.batch_size=16", "--set", "threads=1",
            "--set", "progress=true", "--set", "cost.ink_weight=0",
            "--set", "cost.coverage_weight=0"]  # fmt: skip
    assert cli.main(args) == 0
    out, err = capsys.readouterr()
    assert "best validation stroke shape error" in out and "trajectory error" in out
    assert "matched predicted stroke" in out and "epoch 2/2: stroke shape error train" in err
    meta = read_checkpoint_meta(run / "checkpoints" / "best.json")
    assert meta["val_error_measure"] == "stroke-shape"  # the keys stay as they were
    curve = np.genfromtxt(run / "metrics.csv", delimiter=",", names=True)
    assert meta["best_val_error_px"] == pytest.approx(curve["val_error_px"].min())


def test_predict_writes_a_stroke_document_with_the_whole_characters_path_and_pen(
    omni_root, trained, tmp_path
):
    from img2dmp.predict import StrokePrediction, load_model

    # a test drawer's hook and tick (2 strokes) as the drawer's own 105-px PNG
    image = omni_root / "images_test" / "Alpha" / "character02" / "0102_20.png"
    out = tmp_path / "out"
    assert cli.main(["predict", str(image), "--model", str(trained), "--out", str(out)]) == 0
    doc = json.loads((out / "0102_20_dmp.json").read_text())
    assert doc["format"] == "img2dmp-strokes"
    top = doc["hypotheses"][0]["trajectory"]
    xy, pen = np.asarray(top["xy_image_px"]), np.asarray(top["pen"])
    assert xy.shape == (len(pen), 2) and set(np.unique(pen)) <= {0.0, 1.0}
    runs = pen_spans(np.column_stack([xy, pen]))
    assert len(runs) == len(doc["strokes"]) == 2
    starts = [s["t_start_s"] for s in doc["strokes"]]
    assert starts == sorted(starts) and starts[0] == 0.0
    assert xy[:, 0].max() > 40  # the image frame: the 105-px image, not the model's 40
    count = doc["count"]
    assert count["views"] == COUNT_VIEWS  # a run directory's default
    # the probabilities of 1 .. S strokes the count was read from, and the one read
    p = np.asarray(count["probabilities"])
    assert p.shape == (8,) and p.sum() == pytest.approx(1.0, abs=1e-5)
    assert count["probability"] == p[len(doc["strokes"]) - 1]
    argv = ["predict", str(image), "--model", str(trained), "--out", str(out), "--force"]
    assert cli.main([*argv, "--count-views", "1"]) == 0
    one_view = json.loads((out / "0102_20_dmp.json").read_text())["count"]
    assert one_view["views"] == 1
    pred = load_model(trained).predict(image)
    assert isinstance(pred, StrokePrediction) and pred.n_strokes == len(doc["strokes"])
    # ... the network's own count probabilities of the prepared image, one view
    predictor = load_model(trained)
    predictor.count_with(1)
    prepared, _ = predictor.prepare(image)
    own = predictor.stroke_count_probabilities(prepared[None])[0, 0]
    np.testing.assert_allclose(one_view["probabilities"], np.round(own, 6), atol=2e-6)
    with pytest.raises(ValueError, match="one per stroke"):
        pred.dmp  # noqa: B018 (the robot's one DMP is refused by name)


_NO_TORCH = """
import json, sys
sys.modules["torch"] = None  # any import of torch now fails, loudly
import img2dmp
pred = img2dmp.load_model(sys.argv[1]).predict(sys.argv[2])
print(json.dumps({"n": pred.n_strokes, "path": pred.path_model.tolist()}))
"""


def test_a_stroke_model_reads_a_character_without_torch_as_with_it(omni_root, trained):
    import subprocess
    import sys

    from img2dmp.predict import load_model

    image = omni_root / "images_test" / "Alpha" / "character02" / "0102_20.png"
    code = [sys.executable, "-c", _NO_TORCH, str(trained), str(image)]
    proc = subprocess.run(code, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    pred = load_model(trained, backend="torch").predict(image)
    assert got["n"] == pred.n_strokes
    np.testing.assert_allclose(got["path"], pred.path_model, atol=1e-3)


def test_evaluate_reports_the_stroke_count_and_the_measures_per_alphabet(small_omniglot, trained):
    from img2dmp.evaluate import evaluate, format_metrics_table

    res = evaluate(trained, small_omniglot, split="validation", n_figures=0)
    st = res["strokes"]
    ok = np.equal(st["true_counts"], st["predicted_counts"])
    assert st["count_right"] == pytest.approx(ok.mean())
    assert set(st["per_alphabet"]) == {"Alpha", "Beta"}
    assert sum(a["n"] for a in st["per_alphabet"].values()) == len(ok) == res["overall"]["n"]
    assert res["chamfer"]["overall"]["mean"] < 2.0  # learnt shapes, on a 40-px frame
    # every character of the tree is drawn with one count: its class's mode is always right
    assert st["count_mode_right"] == 1.0 and st["count_mode_n"] == len(ok)
    assert st["count_mode_right_per_alphabet"] == {"Alpha": 1.0, "Beta": 1.0}
    # the count right by how sure the network was of each count read
    sure = np.asarray(st["count_probabilities"])
    assert sure.shape == ok.shape and ((sure > 0) & (sure <= 1)).all()
    bands = st["count_right_by_probability"]
    assert sum(b["n"] for b in bands) == len(ok)
    for b in bands:
        sel = (sure >= b["low"]) & ((sure < b["high"]) if b["high"] < 1 else (sure <= 1))
        assert b["n"] == sel.sum() and b["count_right"] == pytest.approx(ok[sel].mean())
    assert "the count right by the network's probability of it" in format_metrics_table(res)


def test_the_count_right_by_probability_bands_a_hand_made_case():
    from img2dmp.evaluate import count_right_by_probability

    ok = [True, False, True, True, False, True]
    sure = [0.3, 0.45, 0.6, 0.95, 0.92, 1.0]
    bands = count_right_by_probability(ok, sure)
    assert [(b["low"], b["high"], b["n"]) for b in bands] == [
        (0.0, 0.5, 2),
        (0.5, 0.7, 1),
        (0.9, 1.0, 3),
    ]  # the empty band 0.7-0.9 is left out; 1.0 falls in the last, closed band
    assert [b["count_right"] for b in bands] == pytest.approx([0.5, 1.0, 2 / 3])
    assert bands[2]["mean_probability"] == pytest.approx((0.95 + 0.92 + 1.0) / 3)


def test_the_count_ceiling_is_the_class_mode_of_the_training_drawings_only(small_omniglot):
    from img2dmp.data.store import STROKE_SPANS_KEY, DigitData
    from img2dmp.evaluate import _strokes_lines, class_modes, count_ceiling

    data = load_dataset(small_omniglot)
    spans = [list(v) for v in data.meta[STROKE_SPANS_KEY]]
    labels, split = np.asarray(data.labels), np.asarray(data.split)
    # class 0: two of its test drawings one stroke more (the mode, from training, stays)
    extra = np.flatnonzero((labels == 0) & (split == 2))[:2]
    for i in extra:
        spans[i] = spans[i] + [spans[i][-1]]
    # class 1: its training drawings made validation rows: no mode, left out of the ceiling
    arrays = data.arrays()
    arrays["split"] = np.where((labels == 1) & (split == 0), 1, split).astype(split.dtype)
    fake = DigitData(**arrays, meta={**data.meta, STROKE_SPANS_KEY: spans})
    assert 1 not in class_modes(fake) and class_modes(fake)[0] == len(spans[extra[0]]) - 1
    test = fake.subset(arrays["split"] == 2)
    got = count_ceiling(fake, test)
    seen = np.asarray(test.labels) != 1
    assert got["count_mode_n"] == int(seen.sum())
    assert got["count_mode_right"] == pytest.approx(1 - 2 / seen.sum())
    alpha = [c for c in range(len(data.class_names)) if data.class_names[c].startswith("Alpha")]
    assert 0 in alpha and got["count_mode_right_per_alphabet"]["Alpha"] < 1.0
    # characters never seen in training: no ceiling, and the table says so
    unseen = fake.subset((np.asarray(fake.labels) == 1) & (arrays["split"] == 2))
    none = count_ceiling(fake, unseen)
    assert none["count_mode_right"] is None and none["count_mode_n"] == 0
    assert "never seen" in _strokes_lines({"count_right": 0.5, "per_alphabet": {}, **none})
    line = _strokes_lines({"count_right": 0.5, "per_alphabet": {}, **got}).splitlines()[1]
    assert f"{100 * got['count_mode_right']:.1f} %" in line
    assert f"{100 * 0.5 / got['count_mode_right']:.1f} % of it" in line
    # an evaluation of all rows: the training drawings, whose counts make the modes, are
    # left out of the ceiling, and the count right it is compared with is on the same rows
    every = count_ceiling(fake, fake, predicted=np.ones(len(fake.labels), int))
    kept = (np.asarray(fake.labels) != 1) & (arrays["split"] != 0)
    assert every["count_mode_n"] == int(kept.sum()) > 0
    assert every["count_mode_training_left_out"] == int((arrays["split"] == 0).sum()) > 0
    truth = np.array([len(v) for v in spans])
    assert every["count_mode_count_right"] == pytest.approx(np.mean(truth[kept] == 1))
    line = _strokes_lines({"count_right": 0.9, "per_alphabet": {}, **every}).splitlines()[1]
    assert f"its {every['count_mode_training_left_out']} training drawings left out" in line
    share = every["count_mode_count_right"] / every["count_mode_right"]
    assert f"on them {100 * every['count_mode_count_right']:.1f} % is {100 * share:.1f} %" in line
    # and per alphabet: the table gives the count on the ceiling's rows beside its mode %
    alphabets = np.array([fake.class_names[c].split("/")[0] for c in fake.labels])
    per = {a: {"n": 1, "count_right": 0.9} for a in ("Alpha", "Beta")}
    table = _strokes_lines({"count_right": 0.9, "per_alphabet": per, **every}).splitlines()
    assert table[-4].endswith("mode % on them %") and table[-1].startswith("(mode % and on them")
    for a, row in zip(("Alpha", "Beta"), table[-3:-1], strict=True):
        on_them = np.mean(truth[kept & (alphabets == a)] == 1)
        assert row.split()[0] == a and row.split()[-1] == f"{100 * on_them:.1f}"
        assert every["count_mode_count_right_per_alphabet"][a] == pytest.approx(on_them)
    plain = _strokes_lines({"count_right": 0.9, "per_alphabet": per, **got}).splitlines()
    assert plain[-3].endswith("mode %") and "on them" not in plain[-1]


def test_evaluate_and_export_read_the_count_from_the_views_asked_for(
    small_omniglot, trained, tmp_path, monkeypatch
):
    from img2dmp import predict
    from img2dmp.evaluate import evaluate, format_metrics_table
    from img2dmp.export import export_onnx

    calls = []
    real = predict.count_views
    monkeypatch.setattr(predict, "count_views", lambda x, n: calls.append(n) or real(x, n))
    res = evaluate(trained, small_omniglot, split="validation", n_figures=0)
    assert res["strokes"]["count_views"] == COUNT_VIEWS and set(calls) == {COUNT_VIEWS}
    calls.clear()
    one = evaluate(trained, small_omniglot, split="validation", n_figures=0, count_views=1)
    assert one["strokes"]["count_views"] == 1 and set(calls) == {1}
    assert "read from 1 view of each image" in format_metrics_table(one)
    predictor = predict.Predictor.load(trained)
    predictor.count_views = 1
    data = load_dataset(small_omniglot)
    val = np.flatnonzero(data.split == 1)
    counts = [len(v) for v, _ in predictor.predict_strokes(data.images[val])]
    assert one["strokes"]["predicted_counts"] == counts
    with pytest.raises(ValueError, match=r"count_views \(--count-views\) must be a whole number "
                       r"in \[1, 64\], got 0"):  # fmt: skip
        evaluate(trained, small_omniglot, split="validation", n_figures=0, count_views=0)
    predictor.count_views = 3
    export_onnx(predictor, tmp_path / "s.onnx", n_check=3)
    assert json.loads((tmp_path / "s.json").read_text())["strokes"]["count_views"] == 3


def test_evaluate_refines_in_parts_with_the_numbers_of_one_batch_and_says_its_progress(
    small_omniglot, trained, tmp_path, monkeypatch, capsys
):
    from img2dmp import evaluate as ev
    from img2dmp import predict

    whole = ev.evaluate(trained, small_omniglot, split="test", n_figures=0, refine=5)
    monkeypatch.setattr(ev, "REFINE_PART", 5)  # 12 test rows: parts of 5, 5 and 2
    monkeypatch.setattr(predict, "REFINE_ROWS", 16)  # 8 slots: 2 characters refined at once
    sizes, real = [], predict.refine_strokes_numpy  # the NumPy backend's (auto on the CPU)
    spy = lambda strokes, *a: sizes.append(len(strokes)) or real(strokes, *a)  # noqa: E731
    monkeypatch.setattr(predict, "refine_strokes_numpy", spy)
    parts = ev.evaluate(trained, small_omniglot, split="test", n_figures=0, refine=5)
    assert sizes == [2, 2, 1, 2, 2, 1, 2]  # evaluate's parts of 5, 5 and 2, refined 2 by 2
    assert parts["strokes"]["predicted_counts"] == whole["strokes"]["predicted_counts"]
    for key in ("chamfer_px", "on_ink_shares", "path_errors_px", "errors_px"):
        np.testing.assert_allclose(parts[key], whole[key], atol=1e-4, err_msg=key)
    capsys.readouterr()
    argv = ["evaluate", "--model", str(trained), "--data", str(small_omniglot), "--split",
            "test", "--figures", "0", "--refine", "5", "--out", str(tmp_path / "e")]  # fmt: skip
    monkeypatch.setenv("IMG2DMP_PROGRESS", "lines")
    assert cli.main(argv) == 0
    assert re.search(r"^evaluate: 12 samples in [\d.]+ s$", capsys.readouterr().err, re.M)
    assert cli.main([*argv, "--force", "--no-progress"]) == 0
    assert "evaluate:" not in capsys.readouterr().err


def test_the_page_document_of_a_characters_strokes_holds_each_stroke_as_its_dmp(omni_root, trained):
    from img2dmp.predict import load_model
    from img2dmp.robot.pagefile import check_page_document

    pred = load_model(trained).predict(omni_root / "images_test/Beta/character01/0201_20.png")
    page = check_page_document(pred.to_page_document(), "strokes")
    assert len(page.characters) == pred.n_strokes and page.lines == (tuple(range(pred.n_strokes)),)
    for j, c in enumerate(page.characters):
        rows = pred.stroke_rows(j)
        assert np.all(pred.path_model[0, rows, 2] == 1)  # the stroke's own rows, pen down
        np.testing.assert_allclose(c.path_image_px, pred.path_model[0, rows, :2], atol=1e-3)
        np.testing.assert_allclose(c.params_image.g, pred.strokes[j].g)  # in the model frame
        x0, y0, x1, y1 = c.box_image_px
        inside = np.clip(c.path_image_px, 0, 39)
        assert (inside[:, 0] >= x0 - 0.5).all() and (inside[:, 0] < x1 + 0.5).all()
        assert (inside[:, 1] >= y0 - 0.5).all() and (inside[:, 1] < y1 + 0.5).all()


@pytest.mark.skipif(
    not __import__("img2dmp.robot", fromlist=["available"]).available(),
    reason="pybullet is not installed (pip install -e '/path/to/img2dmp[robot]')",
)
def test_write_has_the_arm_write_each_stroke_and_lift_the_pen_between(
    omni_root, trained, tmp_path, capsys
):
    import csv

    image = omni_root / "images_test" / "Alpha" / "character02" / "0102_20.png"
    out = tmp_path / "robot"
    argv = ["write", str(image), "--model", str(trained), "--out-dir", str(out), "--no-progress"]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "2 of 2 strokes written" in printed and "no ink between strokes" in printed
    with open(out / "0102_20_strokes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["index"] for r in rows] == ["0", "1", "page"]
    assert all(r["written"] == "1" for r in rows[:2]) and float(rows[2]["ink_share"]) >= 0.95
    # 40 mm for the model's 40-px frame, as a one-DMP model's digit
    assert "--goal" not in printed
    assert cli.main(argv + ["--goal", "3,4", "--force"]) == 2
    assert "bending is for one-DMP models" in capsys.readouterr().err
    # What predict --out wrote (the stroke document) is written by write --dmp, as the
    # image was: the same strokes, the same commanded paths.
    predict = ["predict", str(image), "--model", str(trained), "--out", str(tmp_path / "p")]
    assert cli.main(predict) == 0
    doc = tmp_path / "p" / "0102_20_dmp.json"
    argv = ["write", "--dmp", str(doc), "--out-dir", str(out), "--no-progress"]
    assert cli.main(argv) == 0
    assert "2 of 2 strokes written" in capsys.readouterr().out
    with open(out / "0102_20_dmp_log.csv", newline="") as f:
        from_doc = [(r["cmd_x_m"], r["cmd_y_m"]) for r in csv.DictReader(f)]
    with open(out / "0102_20_log.csv", newline="") as f:
        from_image = [(r["cmd_x_m"], r["cmd_y_m"]) for r in csv.DictReader(f)]
    assert from_doc == from_image
    assert cli.main(argv + ["--hypothesis", "2", "--force"]) == 2
    assert "is a stroke model's prediction" in capsys.readouterr().err


def test_the_onnx_graph_of_a_stroke_model_reads_as_its_strokes(omni_root, trained, tmp_path):
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnxscript")
    import onnxruntime as ort

    from img2dmp.export import STROKE_OUTPUTS, export_onnx
    from img2dmp.predict import load_model

    report = export_onnx(trained, tmp_path / "s.onnx", n_check=8)
    assert report.max_difference < 1e-4
    info = json.loads((tmp_path / "s.json").read_text())
    assert [o["name"] for o in info["outputs"]] == list(STROKE_OUTPUTS)
    assert info["strokes"]["slots"] == 8 and "argmax(count" in info["strokes"]["reading"]
    predictor = load_model(trained, refine=0)
    image = omni_root / "images_test" / "Beta" / "character02" / "0202_19.png"
    x = np.asarray(predictor.prepare(image)[0], dtype=np.float32)[None]
    session = ort.InferenceSession(str(tmp_path / "s.onnx"), providers=["CPUExecutionProvider"])
    strokes, presence, order, count = session.run(list(STROKE_OUTPUTS), {"images": x})
    predictor.count_views = 1  # one view: the reading the description gives
    c = max(int(count[0].argmax()) + 1, int(ink_pieces(x)[0]))
    on = np.sort(np.argsort(-presence[0], kind="stable")[:c])
    on = on[np.argsort(order[0, on], kind="stable")]
    pred = predictor.predict(image)
    np.testing.assert_allclose(strokes[0, on], pred.strokes.to_vector(), rtol=1e-4, atol=1e-4)


def test_the_class_mode_count_share_is_counted_against_the_training_drawers(
    small_omniglot, experiment_script, monkeypatch
):
    mod = experiment_script("stroke_choices")
    data = load_dataset(small_omniglot)
    counts = np.array([len(data.stroke_spans(i)) for i in range(len(data))])
    shares = mod.class_mode_shares(data)
    assert set(shares) == {"train", "validation", "test"}
    # the tree's characters are drawn with one count each: the mode is always right
    assert all(v == 1.0 for v in shares.values()) and set(counts) == {2, 3}
    # one training drawer per class drawing another count moves train's share, not test's
    fake = counts.copy()
    first = [int(np.flatnonzero((data.labels == c) & (data.split == 0))[0]) for c in range(4)]
    fake[first] += 1
    monkeypatch.setattr(type(data), "stroke_spans", lambda self, i: [None] * fake[i])
    again = mod.class_mode_shares(data)
    assert again["train"] == pytest.approx(1 - 4 / 60) and again["test"] == 1.0


def test_the_count_readings_compare_views_and_the_pieces_bound(
    small_omniglot, trained, experiment_script
):
    from img2dmp.predict import Predictor

    mod = experiment_script("stroke_choices")
    predictor = Predictor.load(trained)
    data = load_dataset(small_omniglot)
    rows = mod.count_readings(predictor, data)
    assert [(r["views"], r["pieces_bound"]) for r in rows] == [
        (1, False), (1, True), (8, False), (8, True)
    ]  # fmt: skip
    val = np.flatnonzero(data.split == 1)
    _, out = predictor._raw_outputs(data.images[val], 64)
    plain = [len(v) for v, _ in read_strokes(out, predictor.strokes, 1)]
    truth = [len(data.stroke_spans(int(i))) for i in val]
    assert rows[0]["count_right"] == pytest.approx(np.mean(np.equal(plain, truth)))
    assert predictor.count_views == 8  # left as it was


def _two_characters_page(omni_root, path):
    """A page of two Omniglot characters side by side on white paper, saved at ``path``."""
    from PIL import Image

    chars = [omni_root / "images_test" / "Alpha" / "character02" / "0102_20.png",
             omni_root / "images_test" / "Beta" / "character02" / "0202_19.png"]  # fmt: skip
    ink = [np.asarray(Image.open(c).convert("L")) for c in chars]
    page = np.full((140, 300), 255, np.uint8)
    page[15:120, 20:125] = ink[0]
    page[15:120, 170:275] = ink[1]
    Image.fromarray(page).save(path)
    return path


def test_a_page_read_by_a_stroke_model_lists_every_stroke_in_the_photos_pixels(
    omni_root, trained, tmp_path, capsys, monkeypatch
):
    from img2dmp import page as page_module
    from img2dmp.dmp import DMPParams
    from img2dmp.dmp._numpy_rollout import rollout_numpy
    from img2dmp.predict import StrokePrediction, load_model
    from img2dmp.robot.pagefile import check_page_document

    photo = _two_characters_page(omni_root, tmp_path / "two.png")
    cuts, segment = [], page_module.segment_page
    spy = lambda *a, **k: cuts.append((k["cut"], k["join_sides"])) or segment(*a, **k)  # noqa: E731
    monkeypatch.setattr(page_module, "segment_page", spy)
    page = load_model(trained, refine=5).predict_page(photo)
    # a stroke model's letters keep their waists (STROKE_PAGE_CUT) and join pieces side by
    # side (STROKE_PAGE_JOIN)
    assert cuts == [(False, True)]
    load_model("digits-real").predict_page(photo)  # digits: cut, never joined side by side
    assert cuts[1:] == [(True, False)]
    assert len(page.characters) == 2 and len(page.lines) == 1
    preds = [c.prediction for c in page.characters]
    assert all(isinstance(p, StrokePrediction) for p in preds)
    assert preds[0].path_image[0, :, 0].max() < 150 < preds[1].path_image[0, :, 0].min()
    doc = page.to_document()
    n = [p.n_strokes for p in preds]
    assert doc["entries"] == "strokes" and doc["n_characters"] == 2
    entries = doc["characters"]
    assert [e["index"] for e in entries] == list(range(sum(n)))
    assert doc["lines"] == [{"index": 0, "characters": list(range(sum(n)))}]
    assert [(e["character"], e["stroke"]) for e in entries] == [
        (k, j + 1) for k in range(2) for j in range(n[k])
    ]  # fmt: skip
    assert [e["count_probability"] for e in entries] == [
        round(preds[k].count_probability, 6) for k in range(2) for _ in range(n[k])
    ]  # fmt: skip
    assert all(0 < p.count_probability <= 1 for p in preds)
    checked = check_page_document(json.loads(json.dumps(doc)), "two_page.json")
    for e, c in zip(entries, checked.characters, strict=True):
        k, j = e["character"], e["stroke"] - 1
        rows = preds[k].stroke_rows(j)
        assert np.allclose(e["path_image_px"], preds[k].path_image[0, rows, :2], atol=1e-3)
        assert e["character_box_image_px"] == list(page.characters[k].box_image)
        x0, y0, x1, y1 = c.box_image_px  # the stroke's own box holds its path
        xy = np.asarray(e["path_image_px"])
        assert (xy[:, 0] >= x0 - 0.5).all() and (xy[:, 0] < x1 + 0.5).all()
        assert (xy[:, 1] >= y0 - 0.5).all() and (xy[:, 1] < y1 + 0.5).all()
        # each entry's DMP, in the photo's pixels, rolls out to its path
        p = DMPParams.from_dict(e["dmp"]["params"])
        t = np.asarray(e["times_s"])
        y = rollout_numpy(p.to_numpy(), t, preds[k].dmp_config)
        assert np.abs(y - np.asarray(e["path_image_px"])).max() < 2e-3
    out = tmp_path / "out"
    assert cli.main(["predict", str(photo), "--page", "--model", str(trained), "--refine",
                     "5", "--out", str(out)]) == 0  # fmt: skip
    assert f"2 characters ({sum(n)} strokes) in 1 lines" in capsys.readouterr().out
    written = json.loads((out / "two_page.json").read_text())
    assert len(written["characters"]) == sum(n) and (out / "two_page.png").exists()


@pytest.mark.skipif(
    not __import__("img2dmp.robot", fromlist=["available"]).available(),
    reason="pybullet is not installed (pip install -e '/path/to/img2dmp[robot]')",
)
def test_write_page_with_a_stroke_model_writes_every_stroke_and_lifts_the_pen(
    omni_root, trained, tmp_path, capsys
):
    photo = _two_characters_page(omni_root, tmp_path / "two.png")
    out = tmp_path / "robot"
    argv = ["write", str(photo), "--page", "--model", str(trained), "--refine", "5",
            "--out-dir", str(out), "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    m = re.search(r"two: (\d+) of (\d+) strokes written", printed)
    assert m and m.group(1) == m.group(2) and int(m.group(1)) >= 2, printed
    assert "no ink between strokes" in printed
    assert "  stroke 0, character 0: 1 of " in printed  # which character's stroke
    # the pen rises less between two strokes of one character than between characters
    from img2dmp.predict import load_model
    from img2dmp.robot import check_page_document, plan_page
    from img2dmp.robot.controller import ControllerConfig
    from img2dmp.robot.page import STROKE_LIFT_M, TRAVEL_HEIGHT_M

    doc = load_model(trained, refine=5).predict_page(photo).to_document()
    plan = plan_page(check_page_document(json.loads(json.dumps(doc)), "two_page.json"))
    owners = [e["character"] for e in doc["characters"]]
    low = ControllerConfig().lift_height_m + STROKE_LIFT_M
    assert plan.travel_heights_m() == [
        low if a == b else TRAVEL_HEIGHT_M for a, b in zip(owners[:-1], owners[1:], strict=True)
    ]  # fmt: skip
    assert TRAVEL_HEIGHT_M in plan.travel_heights_m()  # between the two characters
    assert (out / "two_paper.png").exists() and (out / "two_characters.csv").exists()
    # the robot's table names each stroke's character and its place in it
    import csv

    with open(out / "two_characters.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["index"] != "page"]
    assert [(int(r["character"]), int(r["stroke"])) for r in rows] == [
        (e["character"], e["stroke"]) for e in doc["characters"]
    ]  # fmt: skip
    assert plan.entry_owners() == {
        i: (e["character"], e["stroke"], e["n_strokes"]) for i, e in enumerate(doc["characters"])
    }  # fmt: skip
    edited = json.loads(json.dumps(doc))  # a hand-edited note names nothing, breaks nothing
    edited["characters"][0]["character"] = "first"
    odd = plan_page(check_page_document(edited, "edited_page.json"))
    assert set(odd.entry_owners()) == set(plan.entry_owners()) - {0}
    assert 0 not in odd.entry_labels() and len(odd.travel_heights_m()) == len(owners) - 1


def test_the_stroke_page_experiment_reads_a_drawers_page_and_counts_its_strokes(
    omni_root, trained, experiment_script, tmp_path, capsys, monkeypatch
):
    mod = experiment_script("stroke_page")
    argv = ["--omniglot", str(omni_root), "--model", str(trained), "--drawer", "18",
            "--n", "4", "--per-line", "2", "--out", str(tmp_path)]  # fmt: skip
    assert mod.main(argv) == 0
    out = capsys.readouterr().out
    assert re.search(r"4 characters placed, \d+ found in \d+ lines", out), out
    # the tree's strokes do not touch: each is found as a character of its own
    cells = [line for line in out.splitlines() if line.startswith("  cell ")]
    assert len(cells) == 4 and all("found as" in c for c in cells), out
    chosen = mod.characters(omni_root, 18)
    assert len(chosen) == 4 and {n for _, _, n in chosen} <= {2, 3}  # the tree's strokes
    assert (tmp_path / "drawer18_page_page.json").exists()
    with pytest.raises(SystemExit, match="fewer than --n"):
        mod.main([*argv[:-4], "--n", "9", "--out", str(tmp_path)])
    from PIL import Image

    capsys.readouterr()
    assert mod.main([*argv, "--paper", "ruled"]) == 0  # the ink on photographed paper
    photo = np.asarray(Image.open(tmp_path / "drawer18_page.png"))
    assert photo.ndim == 3 and len(np.unique(photo.reshape(-1, 3), axis=0)) > 100
    assert "4 characters placed" in capsys.readouterr().out
    # spaced as handwriting: each line's ink boxes G character heights apart, ink to ink
    page, boxes = mod.layout(chosen, 2, 0.3)
    height = float(np.median([b[3] - b[1] for b in boxes]))
    for a, b in ((0, 1), (2, 3)):
        assert abs((boxes[b][0] - boxes[a][2]) - 0.3 * height) <= 1.0, boxes
    for x0, y0, x1, y1 in boxes:  # every placed box holds ink at its edges
        assert (page[y0:y1, x0:x1] < 128).any(axis=0)[[0, -1]].all()
    assert mod.main([*argv, "--gap", "0.3", "--join", "no"]) == 0
    said = capsys.readouterr().out
    assert re.search(r"4 characters placed.*\d+ found joined to a neighbour", said), said
    import img2dmp.data.pages as pages
    import img2dmp.page

    # the join's limits are the options' for the run, the library's again after it
    kept = (pages.SIDE_WIDTH, pages.SIDE_GAP, img2dmp.page.STROKE_PAGE_JOIN)
    seen, join = [], pages._join_sides
    spy = lambda *a: seen.append((pages.SIDE_WIDTH, pages.SIDE_GAP)) or join(*a)  # noqa: E731
    monkeypatch.setattr(pages, "_join_sides", spy)
    args = ["--gap", "0.3", "--side-width", "1.6", "--side-gap", "0.4", "--join", "yes"]
    assert mod.main([*argv, *args]) == 0
    assert seen and set(seen) == {(1.6, 0.4)}
    assert (pages.SIDE_WIDTH, pages.SIDE_GAP, img2dmp.page.STROKE_PAGE_JOIN) == kept
    capsys.readouterr()
    for bad in (["--gap", "-1"], ["--side-gap", "nan"], ["--side-width", "inf"]):
        with pytest.raises(SystemExit):
            mod.main([*argv, *bad])
        assert f"{bad[0]} must be at least 0" in capsys.readouterr().err


def test_stroke_choices_refuses_a_model_that_trained_on_the_validation_drawers(
    small_omniglot, trained, experiment_script, tmp_path, capsys
):
    from img2dmp.checkpoint import load_checkpoint, save_checkpoint

    ck = load_checkpoint(trained)
    meta = json.loads(json.dumps(ck.meta))
    meta["train_config"]["data"]["train_on_validation"] = True
    final = save_checkpoint(tmp_path / "final.safetensors", ck.model_state, meta)
    mod = experiment_script("stroke_choices")
    with pytest.raises(SystemExit) as e:
        mod.main(["--model", str(final), "--data", str(small_omniglot)])
    assert e.value.code == 2
    assert "trained on the validation split" in capsys.readouterr().err


def test_count_probes_drop_drawers_train_a_class_head_and_read_counts(
    small_omniglot, trained, experiment_script, tmp_path, capsys
):
    from img2dmp.checkpoint import load_checkpoint
    from img2dmp.nn import strokes as nn_strokes
    from img2dmp.predict import Predictor
    from img2dmp.training import data as tdata

    mod = experiment_script("count_probes")
    data = load_dataset(small_omniglot)
    who = mod.drawers(data)
    assert set(who) == set(range(1, 21))
    fewer = mod.drop_drawers(data, [14, 15])
    moved = (data.split == 0) & np.isin(who, [14, 15])
    assert moved.sum() == 8 and (fewer.split[moved] == 2).all()
    assert np.array_equal(fewer.split[~moved], data.split[~moved])

    run = tmp_path / "head"
    kept = (tdata.count_targets, nn_strokes.StrokeCost.__call__)
    assert mod.train_with_class_head(str(small_omniglot), str(run), 1.0, 0, 2) == 0
    assert (tdata.count_targets, nn_strokes.StrokeCost.__call__) == kept  # patches undone
    last = load_checkpoint(run / "checkpoints" / "last.safetensors").model_state
    best = load_checkpoint(run / "checkpoints" / "best.safetensors").model_state
    assert last["class_head.weight"].shape[0] == 4 and not any("class_head" in k for k in best)

    acc = mod.recognise(str(small_omniglot), "omniglot", epochs=60)
    # the tree's two alphabets draw their characters alike: 1/2 is all there is to learn,
    # chance is 1/4
    assert acc[0] >= 0.45 and acc[1] >= 0.45
    assert mod.main(["recognise", "--data", str(small_omniglot), "--encoders", "batchnorm",
                     "--epochs", "1"]) == 0  # fmt: skip
    assert "batchnorm: character recognised" in capsys.readouterr().out

    assert mod.main(["read", "--data", str(small_omniglot), str(trained), str(run)]) == 0
    out = capsys.readouterr().out
    assert "all runs averaged" in out and "most common count" in out
    row = [ln for ln in out.splitlines() if ln.strip().startswith(str(trained)[-40:])]
    share = float(row[0].split()[1])
    val = np.flatnonzero(data.split == 1)
    p = Predictor.load(trained)
    said = [len(s) for s, _ in p.predict_strokes(data.images[val])]
    truth = [len(data.stroke_spans(int(i))) for i in val]
    assert share == pytest.approx(100 * np.mean(np.equal(said, truth)), abs=0.05)


def test_count_probes_ceilings_and_the_count_chosen_by_its_fit_to_the_ink(
    small_omniglot, trained, experiment_script, capsys
):
    from img2dmp.predict import Predictor

    mod = experiment_script("count_probes")
    data = load_dataset(small_omniglot)
    assert mod.main(["ceilings", "--data", str(small_omniglot)]) == 0
    rows = {ln.split()[0]: ln.split() for ln in capsys.readouterr().out.splitlines()[2:]}
    # the tree's characters are drawn with one count each: a reader that knew the
    # character would always be right
    assert rows["validation"][2:] == ["100.0%", "100.0%"] and rows["test"][2] == "100.0%"
    assert int(rows["test"][1]) == int(np.sum(data.split == 2))
    assert mod.main(["fit", "--data", str(small_omniglot), str(trained)]) == 0
    out = capsys.readouterr().out
    first = float(re.search(r"the most probable ([\d.]+) %", out).group(1))
    val = np.flatnonzero(data.split == 1)
    p = Predictor.load(trained)
    p.count_views = 1
    said = [len(s) for s, _ in p.predict_strokes(data.images[val])]
    truth = [len(data.stroke_spans(int(i))) for i in val]
    assert first == pytest.approx(100 * np.mean(np.equal(said, truth)), abs=0.05)
    assert len(re.findall(r"taken, count right", out)) == len(mod.FIT_MARGINS)


def test_count_probes_ink_reads_the_count_from_the_ink_and_chooses_on_the_others(
    small_omniglot, trained, experiment_script, tmp_path, capsys
):
    from img2dmp.nn.strokes import ink_pieces

    mod = experiment_script("count_probes")
    # the skeleton's ends: a bar 2, a plus 4, a ring none
    images = np.zeros((3, 40, 40), np.float32)
    images[0, 20, 5:35] = 1
    images[1, 20, 5:35] = images[1, 5:35, 20] = 1
    yy, xx = np.mgrid[:40, :40]
    images[2][np.abs(np.hypot(yy - 20, xx - 20) - 10) < 1] = 1
    assert mod.skeleton_ends(images).tolist() == [2, 4, 0]

    out = tmp_path / "ev"
    argv = ["evaluate", "--model", str(trained), "--data", str(small_omniglot),
            "--split", "validation", "--figures", "0", "--out", str(out)]  # fmt: skip
    assert cli.main(argv) == 0
    capsys.readouterr()
    ev = out / "evaluation.json"
    assert mod.main(["ink", str(ev), str(small_omniglot), str(ev), str(small_omniglot)]) == 0
    lines = capsys.readouterr().out.splitlines()
    cells = [ln.split(" | ") for ln in lines if ln.startswith("| ")]
    rows = {c[0].strip("| "): c[1:] for c in cells}
    evaluation = json.loads(ev.read_text())
    data = load_dataset(small_omniglot)
    val = np.flatnonzero(data.split == 1)
    truth = np.array([len(data.stroke_spans(int(i))) for i in val])
    network = 100 * evaluation["strokes"]["count_right"]
    assert rows["the network"][0] == f"{network:.1f}"
    pieces = 100 * np.mean(ink_pieces(data.images[val]) == truth)
    assert rows["pieces of ink"][0] == f"{pieces:.1f}"
    # each evaluation's rule is the one the other (here the same) chooses
    best = max(float(v[0]) for k, v in rows.items() if not k.startswith("chosen"))
    assert rows["chosen on the others of its split"][0].startswith(f"{best:.1f} (")
    with pytest.raises(SystemExit):
        mod.main(["ink", str(ev)])


def test_the_stroke_jitter_probe_moves_each_stroke_and_its_ink_together(
    small_omniglot, experiment_script
):
    mod = experiment_script("count_probes")
    data = load_dataset(small_omniglot)
    images, paths = torch.as_tensor(data.images[:6]), torch.as_tensor(data.trajectories[:6])
    rng = np.random.default_rng(0)
    same_images, same_paths = mod.stroke_jitter(images, paths, 0.0, 0.0, 0.0, rng)
    assert torch.allclose(same_images, images, atol=1e-5) and torch.equal(same_paths, paths)
    moved_images, moved = mod.stroke_jitter(images, paths, 0.0, 0.0, 2.0, rng)
    pen = paths[..., 2] > 0.5
    shifts = set()
    for i in range(len(paths)):  # a pure shift: one vector per stroke, within 2 px
        for s, e in data.stroke_spans(i):
            d = (moved[i, s : e + 1, :2] - paths[i, s : e + 1, :2]).numpy()
            assert np.allclose(d, d[0], atol=1e-4) and np.abs(d[0]).max() <= 2.0
            shifts.add(tuple(np.round(d[0], 3)))
    assert len(shifts) > len(paths)  # the strokes of a character move apart
    assert torch.equal(moved[..., 2], paths[..., 2])

    def ink_at(images, paths):  # the image's ink under the pen-down instants, 0-1
        x, y = (paths[..., k].round().long().clamp(0, images.shape[-1] - 1) for k in (0, 1))
        return float(images[torch.arange(len(images))[:, None], y, x][pen].mean())

    # the ink went with its stroke: under the moved paths in the moved images, not in
    # the images as they were
    kept, left = ink_at(moved_images, moved), ink_at(images, moved)
    assert kept > ink_at(images, paths) - 0.15 and kept > left + 0.1, (kept, left)


def test_one_character_is_checked_for_others_as_its_model_reads_them(
    omni_root, trained, tmp_path, monkeypatch
):
    from PIL import Image

    import img2dmp.predict as predict_module

    seen, count = [], predict_module.count_characters
    spy = lambda mask, letters=False: seen.append(letters) or count(mask, letters)  # noqa: E731
    monkeypatch.setattr(predict_module, "count_characters", spy)
    photo = _two_characters_page(omni_root, tmp_path / "two.png")
    image = np.asarray(Image.open(photo).convert("L"))
    one = image[:, :150]  # the first character alone
    assert "several_characters" not in predict_module.load_model(trained).predict(one).flags
    predict_module.load_model("digits-real").predict(one)
    # a stroke model's letters keep their waists and pieces (as its pages), digits are cut
    assert seen == [True, False]


def test_the_unseen_alphabets_experiment_holds_one_alphabet_out_and_evaluates_on_it(
    small_omniglot, experiment_script, tmp_path, capsys
):
    mod = experiment_script("unseen_alphabets")
    data = load_dataset(small_omniglot)
    alphabets, drawers = mod.alphabets_of(data), mod.drawers(data)
    first = sorted(set(alphabets))[0]
    held = mod.held_out(data, first)
    # every drawing of the alphabet is a test drawing; of the others none is
    assert (held.split[alphabets == first] == 2).all()
    assert (held.split[alphabets != first] != 2).all()
    others = alphabets != first
    assert (held.split[others & (drawers <= 15)] == 0).all()
    assert (held.split[others & (drawers >= 16)] == 1).all()
    with pytest.raises(ValueError, match="no alphabet 'Klingon'"):
        mod.held_out(data, "Klingon")

    out = tmp_path / "ua"
    args = ["--data", str(small_omniglot), "--out", str(out), "--alphabets", first,
            "--epochs", "1", "--jobs", "1"]  # fmt: skip
    assert mod.main(args) == 0
    ev = json.loads((out / first / "evaluation" / "evaluation.json").read_text())
    assert ev["overall"]["n"] == int((alphabets == first).sum())
    table = (out / "results.md").read_text()
    assert f"| {first} | {ev['overall']['n']} |" in table
    assert f"{100 * ev['strokes']['count_right']:.1f} %" in table
    capsys.readouterr()
    assert mod.main(args) == 0  # resumable: done before, not run again
    assert f"{first}: done before" in capsys.readouterr().out
    # the same run evaluated with other refinement steps: its own evaluation and table
    assert mod.main([*args, "--refine", "0"]) == 0
    again = json.loads((out / first / "evaluation_refine0" / "evaluation.json").read_text())
    assert again["refine_steps"] == 0 and ev["refine_steps"] == 60
    assert (out / "results_refine0.md").is_file()
    # how far the encoder tells the held-out alphabet from known characters
    assert mod.main([*args, "--familiarity"]) == 0
    row = mod.familiarity_row(out / first, first)
    assert 0.0 <= row["auc"] <= 1.0 and 0.0 <= row["below"] <= 1.0
    assert -1.0 <= row["unseen_median"] <= 1.0 and row["known_median"] <= 1.0 + 1e-9
    assert (
        f"| {first} | {row['known_median']:.3f} / {row['unseen_median']:.3f} | "
        in (out / "familiarity.md").read_text()
    )
    # the AUC: the share of (negative, positive) pairs ordered right, ties a half
    assert mod.auc([1.0, 2.0], [3.0, 4.0]) == 1.0 and mod.auc([3.0, 4.0], [1.0, 2.0]) == 0.0
    assert mod.auc([1.0, 3.0], [2.0, 3.0]) == (1 + 0.5 + 1) / 4
    with pytest.raises(SystemExit):
        mod.main(["--data", str(small_omniglot), "--out", str(out), "--alphabets", "Klingon"])


def test_the_hanzi_experiment_draws_imports_and_reads_a_font_script(
    trained, experiment_script, tmp_path
):
    mod = experiment_script("hanzi_script")
    pkg = tmp_path / "package"
    pkg.mkdir()

    def medians(n):  # n parallel slanted strokes in the 1024-unit box, y up
        y = np.linspace(800, 150, 6)
        return [np.stack([np.linspace(150, 300, 6) + 90 * k, y], 1).astype(int).tolist()
                for k in range(n)]  # fmt: skip

    for i in range(12):  # CJK unified ideographs of 1-3 strokes
        (pkg / f"{chr(0x4E00 + i)}.json").write_text(json.dumps({"medians": medians(1 + i % 3)}))
    (pkg / "\u2e80.json").write_text(json.dumps({"medians": medians(1)}))  # a radical: not read
    (pkg / f"{chr(0x4E00 + 40)}.json").write_text(json.dumps({"medians": medians(9)}))  # > 8
    chars = mod.characters(pkg, 8)
    assert sorted(chars) == [chr(0x4E00 + i) for i in range(12)]
    out = tmp_path / "hz"
    assert mod.main(["--hanzi", str(pkg), "--out", str(out), "--model", str(trained),
                     "--n", "10"]) == 0  # fmt: skip
    names = json.loads((out / "characters.json").read_text())
    assert len(names) == 10
    for i, (name, char) in enumerate(names.items(), 1):  # one BREAK a stroke, in order
        text = (out / "tree" / "strokes_hanzi" / "Hanzi" / name / f"{i:04d}_01.txt").read_text()
        assert text.startswith("START\n") and text.count("BREAK") == len(chars[char])
    ev = json.loads((out / "evaluation" / "evaluation.json").read_text())
    assert ev["overall"]["n"] == 10 and sorted(ev["strokes"]["true_counts"]) == sorted(
        len(chars[c]) for c in names.values()
    )
    rows = [r.split("|") for r in (out / "by_count.md").read_text().splitlines()
            if re.match(r"\| \d+-\d+ \|", r)]  # fmt: skip
    assert sum(int(r[2]) for r in rows) == 10
    # a second run into the same folder imports its own characters only
    assert mod.main(["--hanzi", str(pkg), "--out", str(out), "--model", str(trained),
                     "--n", "10", "--max-strokes", "1"]) == 0  # fmt: skip
    ev = json.loads((out / "evaluation" / "evaluation.json").read_text())
    assert ev["overall"]["n"] == 4 and set(ev["strokes"]["true_counts"]) == {1}
    with pytest.raises(SystemExit, match="no character files"):
        mod.characters(tmp_path / "hz", 8)
