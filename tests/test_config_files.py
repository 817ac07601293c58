"""A ``--config FILE`` is read the same way by every command that takes one.

A misspelt key of the file is named with the file it came from, by one function
(:func:`img2dmp.config.read_config_of`), in ``generate``, ``prepare``, ``import``,
``train`` and ``demo`` alike; a misspelt ``--set`` key is named alone (it is on the
command line).
"""

from __future__ import annotations

import pytest

from img2dmp import cli, config
from img2dmp.data.synthetic import SyntheticConfig


def _error_line(capsys, argv: list[str]) -> str:
    capsys.readouterr()
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"img2dmp {argv[0]}: error: ")
    return err[0]


# (command and its arguments before --config, the file's text, the misspelt key named)
CASES = {
    "generate": (["generate", "--per-digit", "1"], "noise_amont: 0.1\n", "noise_amont"),
    "generate-section": (
        ["generate", "--per-digit", "1"],
        "affine:\n  scael: [0.9, 1.0]\n",
        "affine.scael",
    ),
    "prepare": (["prepare"], "augmnt: 2\n", "augmnt"),
    "import": (["import", "SOURCE"], "min_on_inc: 0.5\n", "min_on_inc"),
    "train": (["train"], "model:\n  conv_chanels: [8]\n", "model.conv_chanels"),
    "demo": (["demo"], "model:\n  conv_chanels: [8]\n", "model.conv_chanels"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_misspelt_key_of_a_config_file_names_the_file_in_every_command(case, tmp_path, capsys):
    argv, text, key = CASES[case]
    mine = tmp_path / "mine.yaml"
    mine.write_text(text)
    (tmp_path / "source").mkdir()
    argv = [str(tmp_path / "source") if a == "SOURCE" else a for a in argv]
    out = {
        "train": ["--run-dir", str(tmp_path / "out")],
        "demo": ["--out", str(tmp_path / "out")],
    }.get(argv[0], ["--out", str(tmp_path / "out.safetensors")])
    line = _error_line(capsys, [*argv, *out, "--config", str(mine)])
    assert f"error: config file {mine}: unknown field(s) {key}; known: " in line
    assert not (tmp_path / "out.safetensors").exists()
    assert not (tmp_path / "out").exists()


def test_a_misspelt_set_key_is_named_alone(tmp_path, capsys):
    mine = tmp_path / "mine.yaml"
    mine.write_text("noise_amount: 0.1\n")
    argv = ["generate", "--per-digit", "1", "--out", str(tmp_path / "o.safetensors")]
    line = _error_line(capsys, [*argv, "--config", str(mine), "--set", "noise_amont=0.1"])
    assert "error: unknown field(s) noise_amont; known: " in line  # as train says it
    assert "config file" not in line


def test_read_config_of_checks_sections_and_gives_the_mapping(tmp_path):
    good = tmp_path / "good.yaml"
    good.write_text("noise_amount: 0.1\naffine:\n  scale: [0.9, 1.0]\n")
    assert config.read_config_of(SyntheticConfig, good) == {
        "noise_amount": 0.1,
        "affine": {"scale": [0.9, 1.0]},
    }
    bad = tmp_path / "bad.yaml"
    bad.write_text("affine:\n  scale: [0.9, 1.0]\n  shera: 1\n")
    said = r"^config file .*bad\.yaml: unknown field\(s\) affine\.shera; known: "
    with pytest.raises(config.ConfigError, match=said):
        config.read_config_of(SyntheticConfig, bad)
