"""Writing with a robot arm: a simulated KUKA LBR iiwa executes a DMP with a pen.

Needs the optional dependency pybullet (``pip install -e '/path/to/img2dmp[robot]'``); importing a
name that needs it without pybullet raises ``ImportError`` saying how to install it.
The DMP file format (:mod:`.dmpfile`) works without pybullet. See ``docs/ROBOT.md``.

- :func:`write_dmp` - plan, check, simulate, measure one DMP (:mod:`.writing`);
  :func:`write_with_options` - the same with its settings in one :class:`WritingOptions`
- :class:`WritingRun` - one run of the arm (approach, write, lift), logged step by step
  in a :class:`WritingLog`; :class:`WritingResult` - what a run produced
- :class:`PaperMapping` - image pixels to metres on the paper
- :class:`SceneConfig`, :class:`WritingScene` - the cell (:mod:`.scene`)
- :class:`ControllerConfig`, :class:`WritingController` - admittance + IK + computed
  torque (:mod:`.controller`)
- :func:`load_dmp_json`, :func:`save_dmp_json`, :func:`read_dmp_file` - the one DMP
  file (:mod:`img2dmp.data.dmpfile`, re-exported by :mod:`.dmpfile`)
- :func:`save_log_csv`, :func:`plot_writing`, :func:`save_render`, :func:`save_video`,
  :func:`save_mp4`, :func:`save_videos`, :func:`summary_lines` - the outputs
  (:mod:`.outputs`; the video's paper panel and encoders in :mod:`.animation`)
- :func:`stroke_report` - ink and force per pen-down stroke; :class:`StrokeGate` holds
  the DMP clock while the pen lands and lifts (:mod:`.strokes`)
- :class:`JointTrajectory`, :func:`save_joint_trajectory`, :func:`load_joint_trajectory`,
  :func:`replay_joint_trajectory` - the joint trajectory for a real iiwa (:mod:`.joints`);
  a DMP too fast for its joint speed or acceleration limits is slowed before anything
  moves, and every run measures its joint speeds and accelerations (:mod:`.tempo`)
- :func:`write_page` - every character of a page document in one run (:mod:`.page`:
  :func:`plan_page`, :func:`ready_page_plan`, :func:`write_page_plan`, :class:`PageRun`,
  :class:`PageResult`);
  :func:`read_page`, :func:`check_page_document`, :class:`Page` - the page document
  (:mod:`.pagefile`); :func:`plot_page`, :func:`save_characters_csv`,
  :func:`page_summary_lines` - its outputs
"""

from __future__ import annotations

import importlib

from ._pybullet import INSTALL_HINT, available
from .dmpfile import load_dmp_json, read_dmp_file, save_dmp_json

_LAZY = {
    "write_dmp": ".writing",
    "write_with_options": ".writing",
    "WritingOptions": ".writing",
    "WritingRun": ".writing",
    "WritingLog": ".writing",
    "PaperMapping": ".writing",
    "WritingResult": ".writing",
    "writing_metrics": ".writing",
    "plan_path": ".writing",
    "check_path": ".writing",
    "SceneConfig": ".scene",
    "WritingScene": ".scene",
    "ControllerConfig": ".controller",
    "WritingController": ".controller",
    "save_log_csv": ".outputs",
    "plot_writing": ".outputs",
    "save_render": ".outputs",
    "save_video": ".outputs",
    "save_mp4": ".outputs",
    "save_videos": ".outputs",
    "summary_lines": ".outputs",
    "stroke_report": ".strokes",
    "StrokeGate": ".strokes",
    "JointTrajectory": ".joints",
    "save_joint_trajectory": ".joints",
    "load_joint_trajectory": ".joints",
    "replay_joint_trajectory": ".joints",
    "write_page": ".page",
    "plan_page": ".page",
    "write_page_plan": ".page",
    "ready_page_plan": ".page",
    "page_mapping": ".page",
    "PagePlan": ".page",
    "PageRun": ".page",
    "PageResult": ".page",
    "CharacterRun": ".page",
    "read_page": ".pagefile",
    "check_page_document": ".pagefile",
    "Page": ".pagefile",
    "PageCharacter": ".pagefile",
    "plot_page": ".outputs",
    "save_characters_csv": ".outputs",
    "page_summary_lines": ".outputs",
}

__all__ = [
    "INSTALL_HINT",
    "available",
    "load_dmp_json",
    "read_dmp_file",
    "save_dmp_json",
    *_LAZY,
]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
