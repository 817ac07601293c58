"""The benchmark scripts' helpers run (the full benchmarks take minutes and are not tests)."""

from __future__ import annotations

import importlib
import os
import sys
import time
from pathlib import Path

import pytest
import torch

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def bench(monkeypatch):
    """``load(name)``: ``benchmarks/<name>.py`` imported as the script would import it."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))

    def load(name: str):
        sys.modules.pop(name, None)
        return importlib.import_module(name)

    return load


def test_machine_description_names_cpu_threads_and_load(bench):
    machine = bench("_machine")
    before = torch.get_num_threads()
    line = machine.describe()
    assert torch.get_num_threads() == before  # looking at numba's threads changed nothing
    for part in ("CPU: ", "cores", "torch threads", "load average"):
        assert part in line
    assert machine.cpu_model()


def test_busy_neighbour_runs_inside_the_block_only(bench):
    machine = bench("_machine")
    with machine.busy_neighbour(max_seconds=30.0) as what:
        pid = int(what.split("pid ")[1].split(")")[0])
        time.sleep(0.2)
        os.kill(pid, 0)  # alive (raises if not)
    time.sleep(0.1)
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
    with machine.busy_neighbour(enabled=False) as what:
        assert what is None


def test_rollout_benchmark_times_fixed_threads_and_restores_them(bench):
    br = bench("bench_rollout")
    cfg, p_np, t_np = br.make_batch(b=8, t_count=21)
    methods, threads = br.build_methods(cfg, p_np, t_np)
    assert threads["fast rollout, fused (float32), 2 threads"] == 2
    fused = {k: v for k, v in methods.items() if k.startswith("fast rollout, fused")}
    before = torch.get_num_threads()
    per_round, outs = br.interleaved(fused, rounds=1, fast_calls=1, threads=threads)
    assert torch.get_num_threads() == before
    assert set(per_round) == set(fused) and all(len(v) == 1 for v in per_round.values())
    assert "float32 0 of" in br.subnormal_entries(cfg)
    assert "default threads for B=128" in br.rule_threads(128)


def test_latency_benchmark_finds_the_command_line(bench):
    bl = bench("bench_latency")
    cmd = bl.img2dmp_command()
    assert cmd and ("img2dmp" in cmd[0] or cmd[-1] == "img2dmp")
    assert bl.TARGETS["img2dmp --help"] == 0.5


def test_latency_benchmark_times_with_python_s_bytecode_cache_on(bench, tmp_path, monkeypatch):
    bl = bench("bench_latency")
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    env, line = bl.bytecode_env(tmp_path, as_environment=False)
    assert "PYTHONDONTWRITEBYTECODE" not in env
    assert env["PYTHONPYCACHEPREFIX"] == str(tmp_path / "pycache")
    assert line.startswith("bytecode cache: on, in a private folder")
    env, line = bl.bytecode_env(tmp_path, as_environment=True)
    assert env["PYTHONDONTWRITEBYTECODE"] == "1" and line.startswith("bytecode cache: off")
    monkeypatch.delenv("PYTHONDONTWRITEBYTECODE")
    env, line = bl.bytecode_env(tmp_path, as_environment=False)
    assert env.get("PYTHONPYCACHEPREFIX") != str(tmp_path / "pycache")
    assert line == "bytecode cache: on"


def test_time_to_accuracy_writes_curve_and_table(bench, tmp_path, capsys):
    tta = bench("time_to_accuracy")
    before = torch.get_num_threads()
    tiny = ["model.conv_channels=[4]", "model.encoder_layers=[8]", "model.decoder_layers=[8]"]
    small = ["data.samples_per_epoch=64", "data.val_samples=16", "optim.batch_size=32"]
    argv = ["--set", *tiny, *small, "--eval-per-digit", "2", "--budget-min", "0.03"]
    try:
        assert tta.main([*argv, "--out", str(tmp_path)]) == 0
    finally:
        torch.set_num_threads(before)  # the config's threads: 1
    out = capsys.readouterr().out
    assert out.startswith("CPU: ") and "load average at start" in out
    assert "target (px)  reached  wall min  epoch" in out
    assert "0.23" in out and "0.15" in out and "2 per digit" in out
    rows = (tmp_path / "metrics.csv").read_text().splitlines()
    assert rows[0] == "train_wall_s,epoch,eval_error_px,eval_s" and len(rows) >= 2
    assert (tmp_path / "learning_curve.png").stat().st_size > 0


def test_web_benchmark_serves_times_and_counts_errors(bench, capsys):
    pytest.importorskip("fastapi")
    bw = bench("bench_web")
    before = torch.get_num_threads()
    try:
        argv = ["--requests", "3", "--warmup", "1", "--clients", "3", "--total", "7"]
        assert bw.main(argv) == 0
    finally:
        torch.set_num_threads(before)  # the in-process prediction runs on one thread
    out = capsys.readouterr().out
    assert out.startswith("CPU: ") and "\nmodel: " in out
    for part in ("HTTP round trip", "server elapsed_ms", "Predictor.predict in-process",
                 "ratio round trip / in-process", "target p95 <= 50 ms",
                 "3 clients at once, 7 requests in all", "errors: 0"):  # fmt: skip
        assert part in out, part
    assert bw.quantiles([1.0, 2.0, 3.0, 4.0]) == (2.5, pytest.approx(3.85), 4.0)


def test_page_benchmark_makes_its_photo_and_times_the_stages(bench, tmp_path):
    from PIL import Image

    bp = bench("bench_page")
    photo = bp.make_photo(tmp_path, size_hw=(600, 800), n=6, char_height_px=(40.0, 50.0),
                          n_lines=2)  # fmt: skip
    assert Image.open(photo).size == (800, 600)
    run = bp.make_model(tmp_path, bp.img2dmp_command())[0]
    names = [name for name, _ in bp.stages(str(run), 0, photo)]
    assert len(names) == 6 and names[2].startswith("find the characters (")


def test_peers_benchmark_runs_at_its_smallest_settings(bench, capsys):
    """Every code path of bench_peers but dopri5 (its adaptive steps cost seconds even
    here); a peer that is not installed is reported, not fatal."""
    bp = bench("bench_peers")
    before = torch.get_num_threads()
    peers = "prodmp,mp_pytorch_dmp,torchdiffeq_rk4,movement_primitives,pydmps"
    argv = ["--batch", "2", "--rounds", "1", "--fast-calls", "1", "--time-stamps", "21"]
    argv += ["--fit-demos", "2", "--fit-rounds", "1", "--prodmp-steps", "50", "--peers", peers]
    out_dict = bp.main(argv)
    assert torch.get_num_threads() == before
    out = capsys.readouterr().out
    assert out.startswith("CPU: ") and "load average" in out
    for part in ("forward, float32", "forward + backward of sum(y^2), float64",
                 "max err vs solve_ivp", "gradient vs img2dmp's", "fitting 2 demonstrations",
                 "img2dmp fused"):  # fmt: skip
        assert part in out, part
    present, missing = bp.installed(peers.split(","))
    for name in present:
        assert bp.LABELS[name] in out
    for name in missing:
        assert f"not installed, skipped: {bp.LABELS[name]}" in out
    assert out_dict["errors"]["fused"] < 1e-5  # the exact rollout, against solve_ivp
    with pytest.raises(SystemExit):
        bp.parse_args(["--peers", "nope"])


def test_small_call_benchmark_times_old_and_new_paths(bench, capsys):
    bs = bench("bench_small_call")
    per_call = bs.main(["--calls", "4", "--rounds", "2", "--fresh-calls", "3"])
    out = capsys.readouterr().out
    assert out.startswith("CPU: ") and "load average" in out
    parts = ["rollout(p, t), new", "rollout(p, t), old", "/ 60 us", "old / new"]
    parts += ["fused forward kernel alone", "3 calls of rollout(p, t) in a new process"]
    for part in parts:
        assert part in out, part
    assert all(len(v) == 4 for v in per_call.values())
    assert bs._rollout._direct_rollout.__name__ == "_direct_rollout"  # switched back on


def test_kernel_benchmark_prints_cycles_per_stamp(bench, capsys):
    bk = bench("bench_kernel")
    argv = ["--batch", "1", "3", "--time-stamps", "5", "--rounds", "2", "--seconds", "0.001"]
    rows = bk.main([*argv, "--before", ""])
    assert {(r["dtype"], r["b"], r["pass_"]) for r in rows} == {
        (dt, b, p) for dt in ("float32", "float64") for b in (1, 3) for p in ("forward", "backward")
    }
    assert all(r["offset"] == "0" and r["diff"] == 0 for r in rows)
    out = capsys.readouterr().out
    assert "cycles / stamp" in out and "load average" in out and "CPU: " in out


def test_kernel_benchmark_times_a_git_revision_s_kernels(bench):
    bk = bench("bench_kernel")
    try:
        old = bk.kernels_at("HEAD")
    except Exception as exc:  # not a git checkout
        pytest.skip(f"no git revision to compare with: {exc}")
    rows = bk.time_case(
        {"now": (bk._kernels, None), "HEAD, +16 B": (old, 16)},
        2,
        torch.float64,
        bk.parse_args(["--time-stamps", "4", "--rounds", "1", "--seconds", "0.001"]),
    )
    assert [r["offset"] for r in rows[2:]] == ["16", "16"]
    assert all(r["diff"] < 1e-12 for r in rows)
