"""experiments/reproduce_table1.py: the protocols, the update count, one tiny row."""

from __future__ import annotations

import json

import pytest
import yaml

from img2dmp.config import apply_overrides, read_config_file
from img2dmp.training import TrainConfig


def _config(mod, protocol: str, row: str) -> TrainConfig:
    over = mod.protocol_overrides(protocol, row)
    return TrainConfig.from_dict(apply_overrides(read_config_file("paper"), over))


def test_the_paper_protocol_takes_cost_9_as_written_and_never_stops_early(experiment_script):
    mod = experiment_script("reproduce_table1")
    assert mod.protocol_overrides("as-configured", "cost9") == []
    shipped = _config(mod, "as-configured", "cost9")
    assert shipped.cost.parameter_weighting != "none"  # so the protocol has work to do
    for row in ("cost9", "digit2_cost9"):
        cfg = _config(mod, "paper", row)
        assert cfg.cost.parameter_weighting == "none"
        assert cfg.optim.patience == 0
        assert cfg.model.activation == "relu" and cfg.data.augment is None
    assert (
        _config(mod, "paper", "cost10").cost.parameter_weighting == shipped.cost.parameter_weighting
    )


def test_the_open_choices_rotate_only_where_the_cost_does_not_compare_weights(
    experiment_script,
):
    mod = experiment_script("reproduce_table1")
    traj = _config(mod, "paper-open", "cost10")
    param = _config(mod, "paper-open", "digit2_cost9")
    assert traj.model.activation == param.model.activation == "leaky_relu"
    assert list(traj.data.augment["rotation_deg"]) == [-5, 5]
    assert list(traj.data.augment["shear_deg"]) == [-5, 5]
    assert list(param.data.augment["rotation_deg"]) == [0, 0]
    assert list(param.data.augment["shear_deg"]) == [0, 0]
    assert list(param.data.augment["scale"]) == list(traj.data.augment["scale"]) == [0.95, 1.05]
    with pytest.raises(ValueError, match="--protocol must be one of"):
        mod.protocol_overrides("papr", "cost10")


@pytest.mark.parametrize(
    "updates, n, batch, epochs",
    [(25_000, 20_000, 128, 160), (25_000, 2_000, 128, 1_563), (10, 8, 8, 10), (1, 5, 128, 1)],
)
def test_epochs_are_sized_to_reach_the_updates(experiment_script, updates, n, batch, epochs):
    mod = experiment_script("reproduce_table1")
    got = mod.epochs_for_updates(updates, n, batch)
    assert got == epochs
    per_epoch = -(-n // batch)
    assert got * per_epoch >= updates > (got - 1) * per_epoch


def test_epochs_and_updates_together_are_refused(experiment_script, capsys):
    mod = experiment_script("reproduce_table1")
    with pytest.raises(SystemExit):
        mod.parse_args(["--epochs", "3", "--updates", "100"])
    assert "not both" in capsys.readouterr().err
    assert mod.parse_args(["--protocol", "paper"]).updates == mod.PAPER_UPDATES
    assert mod.parse_args([]).epochs == 60


def test_a_tiny_digit_2_row_runs_the_papers_protocol_to_its_update_count(
    tmp_path, experiment_script, capsys
):
    mod = experiment_script("reproduce_table1")
    out = tmp_path / "t1"
    argv = ["--out", str(out), "--rows", "digit2_cost9", "--protocol", "paper"]
    argv += ["--updates", "5", "--samples-per-digit", "20", "--val-per-digit", "4"]
    argv += ["--set", "optim.batch_size=8", "model.encoder_layers=[16, 8]"]
    argv += ["model.decoder_layers=[8]"]
    assert mod.main(argv) == 0
    row = json.loads((out / "digit2_cost9" / "done.json").read_text())
    # 20 images of digit 2 in batches of 8: 3 updates an epoch, 2 epochs for 5 updates.
    assert (row["epochs"], row["updates"]) == (2, 6)
    cfg = yaml.safe_load((out / "digit2_cost9" / "config.yaml").read_text())
    assert cfg["cost"]["parameter_weighting"] == "none"
    assert cfg["optim"]["patience"] == 0 and cfg["optim"]["epochs"] == 2
    assert "| 2 | 6 |" in (out / "results.md").read_text()
    assert "digit2_cost9" in capsys.readouterr().out
