"""A script the stroke model never saw: Chinese characters, drawn from the stroke medians
of ``hanzi-writer-data`` (the npm package of Make Me a Hanzi's data, Arphic Public
License; not in ``../shared``, not committed), read by a stroke model as ``img2dmp
evaluate`` reads Omniglot's test drawers.

The package holds one drawing per character: each stroke's median line, in order, in a
1024-unit box (y up, the top at 900). ``--n`` characters (CJK unified ideographs of at
most ``--max-strokes`` strokes, chosen with ``--seed``) are written as an Omniglot tree
(``images_hanzi/Hanzi/characterNNNN/NNNN_01.png``: 105 x 105, the medians drawn with a
round pen of ``--pen`` px, black on white as Omniglot's; ``strokes_hanzi/...txt``: the
medians in Omniglot's coordinates, one point a pixel at 10 ms a point), imported with
``img2dmp import`` (``--split-by character``) and evaluated on all drawings with the
model card's settings (``--split all``). Printed: the date, revision and command, the
evaluation's summary, and the measures per true stroke count (also in
``OUT/by_count.md``). A font's medians are not a person's hand: the strokes are clean
and their order is the standard one.

Run from the repository's root::

    npm pack hanzi-writer-data@2.0.1 && tar xzf hanzi-writer-data-2.0.1.tgz   # -> package/
    python experiments/hanzi_script.py --hanzi package --out runs/hanzi \\
        [--model omniglot-strokes] [--n 300] [--max-strokes 8] [--seed 0] [--pen 5]

About 20 seconds for 300 characters.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record

#: The command line's start: this Python's img2dmp, whatever is on PATH.
IMG2DMP = (sys.executable, "-m", "img2dmp")
#: Omniglot's image side (px) and the medians' box (units; the top of the box at TOP).
SIDE, BOX, TOP = 105, 1024.0, 900.0
#: Buckets of the true stroke count the measures are given for.
BUCKETS = ((1, 2), (3, 4), (5, 6), (7, 8), (9, 64))


def characters(folder: Path, max_strokes: int) -> dict[str, list[np.ndarray]]:
    """The package's CJK unified ideographs of 1 to ``max_strokes`` strokes: character ->
    its strokes' medians ``[P, 2]`` (image px of a SIDE-px square, x right, y down)."""
    out = {}
    scale = SIDE / BOX
    for path in sorted(folder.glob("*.json")):
        char = path.stem
        if len(char) != 1 or not 0x4E00 <= ord(char) <= 0x9FFF:
            continue
        medians = json.loads(path.read_text(encoding="utf-8")).get("medians") or []
        if 1 <= len(medians) <= max_strokes:
            out[char] = [np.array([[x * scale, (TOP - y) * scale] for x, y in m], float)
                         for m in medians]  # fmt: skip
    if not out:
        raise SystemExit(f"{folder}: no character files (*.json with 'medians'); give the "
                         "unpacked hanzi-writer-data package folder")  # fmt: skip
    return out


def densify(line: np.ndarray) -> np.ndarray:
    """A polyline with a point about every pixel along it (its ends kept)."""
    seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
    s = np.r_[0.0, np.cumsum(seg)]
    if s[-1] == 0:
        return line[:1]
    at = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1])) + 1))
    return np.stack([np.interp(at, s, line[:, 0]), np.interp(at, s, line[:, 1])], 1)


def draw(strokes: list[np.ndarray], pen: float):
    """The strokes drawn with a round pen of ``pen`` px: a 1-bit SIDE x SIDE image, ink
    black (0) as Omniglot's."""
    from PIL import Image, ImageDraw

    img = Image.new("L", (SIDE, SIDE), 255)
    d, r = ImageDraw.Draw(img), pen / 2
    for line in strokes:
        pts = [tuple(p) for p in densify(line)]
        if len(pts) > 1:
            d.line(pts, fill=0, width=int(round(pen)), joint="curve")
        for x, y in (pts[0], pts[-1]):
            d.ellipse((x - r, y - r, x + r, y + r), fill=0)
    return img.point(lambda v: 255 if v >= 128 else 0).convert("1")


def stroke_text(strokes: list[np.ndarray]) -> str:
    """Omniglot's stroke file: START, per stroke its points ``x,-y,t_ms`` and BREAK."""
    lines, t = ["START"], 0
    for line in strokes:
        for x, y in densify(line):
            lines.append(f"{x:.3f},{-y:.3f},{t}")
            t += 10
        lines.append("BREAK")
        t += 200
    return "\n".join(lines) + "\n"


def write_tree(chars: dict[str, list[np.ndarray]], out: Path, pen: float) -> dict[str, str]:
    """The characters as an Omniglot tree under ``out`` (a tree written before is
    replaced, so that no character of another run is imported with these);
    ``characterNNNN`` -> character."""
    shutil.rmtree(out, ignore_errors=True)
    names = {}
    for i, (char, strokes) in enumerate(chars.items(), 1):
        name = f"character{i:04d}"
        names[name] = char
        for kind, suffix in (("images", ".png"), ("strokes", ".txt")):
            folder = out / f"{kind}_hanzi" / "Hanzi" / name
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{i:04d}_01{suffix}"
            if kind == "images":
                draw(strokes, pen).save(path)
            else:
                path.write_text(stroke_text(strokes))
    return names


def run(cmd: list[str]) -> None:
    print("$ img2dmp", " ".join(cmd[len(IMG2DMP) :]), flush=True)
    subprocess.run(cmd, check=True)


def by_count(ev: dict) -> str:
    """The measures per bucket of the true stroke count, as a markdown table."""
    st = ev["strokes"]
    true, said = np.asarray(st["true_counts"]), np.asarray(st["predicted_counts"])
    ink, cham = np.asarray(ev["on_ink_shares"], float), np.asarray(ev["chamfer_px"], float)
    head = "| true strokes | characters | Chamfer (px) | on ink | count right | too few / many |"
    table = [head, "|---|---|---|---|---|---|"]
    for lo, hi in BUCKETS:
        sel = (true >= lo) & (true <= hi)
        if not sel.any():
            continue
        t, s = true[sel], said[sel]
        table.append(
            f"| {lo}-{hi} | {sel.sum()} | {cham[sel].mean():.3f} | {100 * ink[sel].mean():.1f} % "
            f"| {100 * np.mean(s == t):.1f} % "
            f"| {100 * np.mean(s < t):.1f} / {100 * np.mean(s > t):.1f} % |"
        )
    return "\n".join(table)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--hanzi", required=True, type=Path, help="the unpacked package folder")
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--model", default="omniglot-strokes")
    p.add_argument("--n", type=int, default=300)
    p.add_argument("--max-strokes", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--pen", type=float, default=5.0, help="pen width, px of the 105-px image")
    args = p.parse_args(argv)
    if args.n < 10 or args.max_strokes < 1 or not 1 <= args.pen <= 20:
        p.error("--n must be at least 10, --max-strokes at least 1, --pen from 1 to 20")
    record = format_record(run_record(__file__, argv))
    print(record, flush=True)
    chars = characters(args.hanzi, args.max_strokes)
    pick = np.random.default_rng(args.seed).permutation(sorted(chars))[: args.n]
    chosen = {str(c): chars[c] for c in pick}
    print(f"{len(chars)} characters of 1-{args.max_strokes} strokes; {len(chosen)} chosen "
          f"(seed {args.seed}): {''.join(list(chosen)[:40])}...", flush=True)  # fmt: skip
    tree, data = args.out / "tree", args.out / "data.safetensors"
    names = write_tree(chosen, tree, args.pen)
    (args.out / "characters.json").write_text(json.dumps(names, ensure_ascii=False, indent=1))
    run([*IMG2DMP, "import", str(tree), "--n-times", "300", "--split-by", "character",
         "--out", str(data), "--force", "--no-progress"])  # fmt: skip
    run([*IMG2DMP, "evaluate", "--model", args.model, "--data", str(data), "--split", "all",
         "--figures", "8", "--out", str(args.out / "evaluation"), "--force"])  # fmt: skip
    ev = json.loads((args.out / "evaluation" / "evaluation.json").read_text())
    table = by_count(ev)
    print(table)
    (args.out / "by_count.md").write_text(f"{record}\n\n{table}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
