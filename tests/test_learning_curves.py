"""experiments/learning_curves.py on hand-made metrics files."""

from __future__ import annotations

import pytest

HEADER = "epoch,step,lr,train_cost,train_error_px,val_error_px,best_val_error_px,epoch_time_s\n"


def _run(tmp_path, name, rows):
    d = tmp_path / name
    d.mkdir()
    lines = [f"{e},{s},0.001,0.1,{tr},{va},0,1.0\n" for e, (s, tr, va) in enumerate(rows)]
    (d / "metrics.csv").write_text(HEADER + "".join(lines))
    return d


def test_the_summary_reads_the_last_and_the_best_epoch(tmp_path, experiment_script):
    mod = experiment_script("learning_curves")
    d = _run(tmp_path, "a", [(16, 2.0, 2.1), (32, 1.0, 0.9), (48, 0.5, 1.2)])
    s = mod.summary(mod.read_curve(d))
    assert s == {"updates": 48, "train": 0.5, "validation": 1.2, "best": 0.9, "best_at": 32}


def test_runs_are_drawn_and_tabled_side_by_side(tmp_path, experiment_script, capsys):
    mod = experiment_script("learning_curves")
    a = _run(tmp_path, "a", [(16, 2.0, 2.1), (32, 1.0, 0.9)])
    b = _run(tmp_path, "b", [(10, 3.0, 3.1)])
    out = tmp_path / "curves.png"
    assert mod.main([f"first={a}", str(b), "--out", str(out), "--paper", "0.11"]) == 0
    text = capsys.readouterr().out
    assert out.stat().st_size > 1000
    first = next(line for line in text.splitlines() if line.startswith("first "))
    assert first.split()[1:] == ["32", "1.000", "0.900", "0.900", "32"]
    assert any(line.startswith(str(b)) for line in text.splitlines())


@pytest.mark.parametrize(
    "content, message",
    [(None, "no such file"), ("", "holds no epoch"), ("epoch,step\n0,16\n", "lacks the column")],
)
def test_a_run_without_a_usable_metrics_file_is_named(
    tmp_path, experiment_script, capsys, content, message
):
    mod = experiment_script("learning_curves")
    d = tmp_path / "run"
    d.mkdir()
    if content is not None:
        (d / "metrics.csv").write_text(content)
    assert mod.main([f"x={d}", "--out", str(tmp_path / "c.png")]) == 2
    err = capsys.readouterr().err
    assert message in err and "metrics.csv" in err
