"""The README (and docs/API.md, docs/INTEROP.md, docs/EXPORT.md) as a new user meets
them: every Python block runs as written, from a folder that holds only the sample images,
with the shipped model, after the commands the page's text runs first; the files its
commands name exist; the page stays short and its picture small."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_README_LINES = 200
MAX_PICTURE_BYTES = 200_000
#: The pages whose Python blocks run as written, from a clone's root.
PAGES = ["README.md", "docs/API.md", "docs/INTEROP.md", "docs/EXPORT.md"]
#: The commands a page's text has the reader run before its Python blocks (each one is on
#: the page, as written): EXPORT.md's read the graph its export writes and the DMP file
#: of its `predict --out pred`.
FIRST = {
    "docs/EXPORT.md": [
        "img2dmp export --model digits-real --onnx digits-real.onnx",
        "img2dmp predict examples/samples/digit_3.png --out pred",
    ],
}


def python_blocks(page: Path) -> list[str]:
    """The ```python blocks of a Markdown page, in order."""
    return re.findall(r"^```python\n(.*?)^```", page.read_text(encoding="utf-8"), re.S | re.M)


def shell_lines(page: Path) -> list[str]:
    """The commands of the ```bash blocks (comments cut off)."""
    blocks = re.findall(r"^```bash\n(.*?)^```", page.read_text(encoding="utf-8"), re.S | re.M)
    lines = [line.split("#")[0].strip() for block in blocks for line in block.splitlines()]
    return [line for line in lines if line]


@pytest.fixture
def fresh_folder(tmp_path, monkeypatch):
    """A working folder as a clone's root would be for these lines: the sample images
    only (no runs/, no data)."""
    (tmp_path / "examples").mkdir()
    (tmp_path / "examples" / "samples").symlink_to(ROOT / "examples" / "samples")
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("page", PAGES)
def test_every_python_block_runs_as_written(page, fresh_folder):
    from img2dmp.cli import main

    text = " ".join((ROOT / page).read_text(encoding="utf-8").split())
    for command in FIRST.get(page, []):
        assert command in text, f"{page} no longer says: {command}"
        assert main(shlex.split(command)[1:]) == 0, command
    blocks = python_blocks(ROOT / page)
    assert blocks, f"{page} has no Python block"
    for i, code in enumerate(blocks):
        namespace: dict = {"__name__": "__main__"}
        exec(compile(code, f"{page}, Python block {i + 1}", "exec"), namespace)
        if page == "docs/EXPORT.md" and i == 0:  # the graph's top DMP, as a vector
            assert namespace["v"].shape == (55,) and namespace["w"].shape == (25, 2)
    if page == "README.md":
        assert (fresh_folder / "digit_3_dmp.json").is_file()
        assert namespace["pred"].flags == [] and namespace["xy"].shape[1] == 2
    if page == "docs/INTEROP.md":
        assert namespace["out"].error_px < 0.05  # the peer's rollout within the target
    if page == "docs/EXPORT.md":  # the DMP file integrated with NumPy alone
        assert namespace["path"].shape == (1001, 2)


def test_the_readme_is_short_and_its_picture_small_and_made_by_a_script():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= MAX_README_LINES
    pictures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert pictures, "no picture at the top of the README"
    for picture in pictures:
        assert (ROOT / picture).stat().st_size < MAX_PICTURE_BYTES, picture
    assert "python examples/plot_readme.py" in text
    assert "runs/real/run" not in "".join(python_blocks(ROOT / "README.md"))


def test_every_file_the_readme_commands_read_is_in_the_repository():
    named = set()
    for line in shell_lines(ROOT / "README.md"):
        named |= {w for w in shlex.split(line) if w.startswith("examples/")}
    assert named, "the README's commands read no sample"
    for name in sorted(named):
        assert (ROOT / name).is_file(), name
    for page in PAGES:
        for name in re.findall(r'"(examples/[^"]+)"', "".join(python_blocks(ROOT / page))):
            assert (ROOT / name).is_file(), (page, name)


def test_the_samples_are_the_ones_the_script_draws(tmp_path):
    """examples/make_samples.py redraws the committed samples (the PNG pixel for pixel;
    the JPEGs, lossy, within a few grey levels): they are the project's, not copies."""
    import importlib.util

    import numpy as np
    from PIL import Image

    script = ROOT / "examples" / "make_samples.py"
    spec = importlib.util.spec_from_file_location("make_samples", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--out", str(tmp_path)]) == 0
    committed = ROOT / "examples" / "samples"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in committed.iterdir())
    for made in sorted(tmp_path.iterdir()):
        a = np.asarray(Image.open(made).convert("RGB"), dtype=np.int16)
        b = np.asarray(Image.open(committed / made.name).convert("RGB"), dtype=np.int16)
        assert a.shape == b.shape, made.name
        worst = int(np.abs(a - b).max())
        assert worst == 0 if made.suffix == ".png" else worst <= 8, (made.name, worst)
