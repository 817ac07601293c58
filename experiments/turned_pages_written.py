"""How the robot would lay a page taken askew on the paper: level, in reading order?

Each page document given (``img2dmp predict PHOTO --page``'s ``NAME_page.json``) is
planned by :func:`img2dmp.robot.plan_page` (the layout and every character's path at the
control rate; no simulation) twice: as the document says (a page read turned level is
written turned so, by its ``turned_deg``) and as the photo stands (``turned_deg`` 0, as
``write --page`` wrote every page before). Per document and way:

- *slope*: the angle of the lines on the paper, degrees rising to the writer's right (one
  slope fitted through the centres of each line's characters, every line its own offset);
- *to the right*: the share of steps from a character to the next in its line that go to
  the writer's right;
- *downwards*: the share of steps from a line to the next that go towards the robot
  (down the page as the writer reads it).

    python experiments/turned_pages_written.py OUT/*_page.json
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def layout(doc: dict, name: str) -> tuple[float, float, float]:
    """``(slope_deg, to_the_right, downwards)`` of the document planned on the paper."""
    from img2dmp.robot import check_page_document, plan_page

    plan = plan_page(check_page_document(doc, name))
    # world +x points away from the robot (up the page), -y to the writer's right
    centre = {cp.character.index: cp.plan.xy_m.mean(axis=0) for cp in plan.characters}
    lines = [[centre[i] for i in line if i in centre] for line in plan.page.lines]
    lines = [np.array(line) for line in lines if line]
    xs = np.concatenate([-p[:, 1] + p[:, 1].mean() for p in lines])
    ys = np.concatenate([p[:, 0] - p[:, 0].mean() for p in lines])
    slope = float(np.degrees(np.arctan2((xs * ys).sum(), (xs * xs).sum())))
    right = [b[1] < a[1] for p in lines for a, b in zip(p[:-1], p[1:], strict=True)]
    tops = [p[:, 0].mean() for p in lines]
    down = [b < a for a, b in zip(tops[:-1], tops[1:], strict=True)]
    return (
        slope,
        float(np.mean(right)) if right else np.nan,
        float(np.mean(down)) if down else np.nan,
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("documents", nargs="+", help="page documents (NAME_page.json)")
    args = p.parse_args(argv)
    print("document | turned_deg | slope, to the right, downwards: as the photo stands | as read")
    for path in args.documents:
        with open(path) as f:
            doc = json.load(f)
        stands = layout({**doc, "turned_deg": 0.0}, path)
        read = layout(doc, path)
        print(f"{path} | {doc.get('turned_deg', 0.0)} | {stands[0]:.2f} deg, {stands[1]:.2f}, "
              f"{stands[2]:.2f} | {read[0]:.2f} deg, {read[1]:.2f}, {read[2]:.2f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
