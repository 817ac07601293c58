"""``img2dmp generate`` fits its digits' DMPs with the constants asked for, so that its
data can fine-tune a model trained with other ones (``train --init-from``)."""

from __future__ import annotations

from img2dmp import cli
from img2dmp.data.store import load_dataset


def test_generate_fits_with_the_scaling_and_kernels_given(tmp_path, capsys):
    """generate had no --scaling: its data were always goal-start, and the shipped
    digits-real (scaling none) could not be fine-tuned on them."""
    out = tmp_path / "d.safetensors"
    argv = ["generate", "--out", str(out), "--per-digit", "2", "--digits", "2", "--no-progress"]
    assert cli.main([*argv, "--scaling", "none", "--n-kernels", "20", "--workers", "1"]) == 0
    data = load_dataset(out)
    assert (data.dmp_config.scaling, data.dmp_config.n_kernels) == ("none", 20)
    assert data.params.shape[1] == data.dmp_config.n_params
    assert cli.main([*argv, "--force", "--workers", "1"]) == 0  # the defaults as before
    data = load_dataset(out)
    assert (data.dmp_config.scaling, data.dmp_config.n_kernels) == ("goal-start", 25)
