"""Writing a whole page: every character of a page document at its place on the paper.

A page document (:mod:`img2dmp.robot.pagefile`, from ``img2dmp predict PHOTO --page``)
gives each character's box in the photo and its DMP. :func:`write_page` writes them
all, in reading order, in **one** simulation session, so that the log, the joint
trajectory and the video are continuous:

1. **Layout** (:func:`page_mapping`): the page's written area, the union of all its
   characters' boxes (flagged ones included, so that ``skip_flagged`` moves nothing),
   is written ``width_mm`` wide with its aspect kept (one scale for x and y) and its
   centre on the paper's centre; by default ``DEFAULT_WIDTH_MM``, or the widest width
   that fits the sheet when that is narrower (:func:`plan_page`). Each character's DMP
   is its top hypothesis in the photo's pixels, mapped to the paper by this one
   :class:`PaperMapping`; the blank margins of the photo play no part.
2. **Plan and check, before anything moves** (:func:`plan_page`, then
   :func:`write_page_plan`): every character's exact path at the control rate must lie
   on the sheet (``ValueError`` naming the character, by how many mm it sticks out and
   the widest page that fits), the arm must reach it with the pen vertical on the paper
   and at the lift height (:func:`img2dmp.robot.writing.check_path`), and the travels
   between characters at ``travel_height_m`` (between two strokes of one character of a
   stroke model's page, lower: :meth:`PagePlan.travel_heights_m`).
3. **Write** (:class:`PageRun`, a :class:`WritingRun`): for each character the stages of
   one DMP (approach, write with the stroke gate, lift), then a **travel** to the next
   character's first point: the pen rises to its travel's height above the paper, moves
   in a straight line (minimum-jerk, at most ``TRAVEL_SPEED_M_S``), comes down to the
   lift height and waits ``TRAVEL_SETTLE_S``, so that every approach starts as the first
   one does. The DMP runs online, one step per control period, as in :func:`write_dmp`.
4. **Measure** (:func:`character_metrics`): per character, what :func:`write_dmp`
   measures for one DMP (tracking error, contact force, per-stroke ink) on its own steps,
   plus the share of its commanded path that has ink (``ink_share``), the share of its
   ink that lies on its commanded path (``ink_on_path_share``) and where its ink's centre
   is against its commanded path's (``placement_error_mm``); and the page's totals.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field

import numpy as np

from ..dmp import DMPConfig, DMPIntegrator, DMPParams
from .animation import PaperInset
from .controller import WritingController, axis_move_s
from .pagefile import Page, PageCharacter, read_page
from .scene import WritingScene
from .strokes import ink_on_path_share, ink_trace, min_jerk_along, stroke_report
from .tempo import Slowing, joint_acceleration_metrics, joint_speed_metrics
from .writing import (
    IK_TOLERANCE_M,
    PEN_DOWN_ROTATION,
    PHASES,
    SHEET_MARGIN_M,
    PaperMapping,
    PlannedPath,
    WritingLog,
    WritingOptions,
    WritingResult,
    WritingRun,
    check_path,
    checked_dmp,
    level_box_px,
    move_towards,
    plan_path,
    sheet_bounds_m,
    slow_for_joint_limits,
    writing_metrics,
)

DEFAULT_WIDTH_MM = 160.0
#: The flags a page's character may carry (docs/PAGE.md, "Fit scores and flags").
CHARACTER_FLAGS = ("off_ink", "unexplained_ink", "several_characters", "cut_by_border",
                   "unfamiliar")  # fmt: skip
# The pen travels between characters this high above the paper: clear of the ink and of
# the 6 mm lift height it writes with, reachable everywhere on the sheet.
TRAVEL_HEIGHT_M = 0.02
#: A stroke model's pen between two strokes of one character: this far above the
#: controller's lift height (``img2dmp write`` and the web server's robot jobs).
STROKE_LIFT_M = 0.004
# Top speed of a travel in the plane (its minimum-jerk profile peaks at 1.875 times the
# mean speed).
TRAVEL_SPEED_M_S = 0.1
MIN_JERK_PEAK = 1.875
# Back at the lift height above the next character, the arm rests this long before the
# approach, which then starts as the first character's does (from rest).
TRAVEL_SETTLE_S = 0.1


@dataclass(frozen=True)
class CharacterPlan:
    """One character to write: its entry in the page and its checked plan.

    Attributes
    ----------
    character : PageCharacter
    params : DMPParams
        Its top hypothesis in the photo's pixels (NumPy float64), what runs online.
    config : DMPConfig
    plan : PlannedPath
        The exact path at the control rate, mapped to the paper.
    slowing : Slowing or None
        How much ``params`` was slowed for the iiwa's joint speed limits
        (:func:`slow_page_plan`; None: not looked at yet).
    """

    character: PageCharacter
    params: DMPParams
    config: DMPConfig
    plan: PlannedPath
    slowing: Slowing | None = None

    @property
    def label(self) -> str:
        c = self.character
        return f"character {c.index} (line {c.line})"


@dataclass(frozen=True)
class PagePlan:
    """A page laid out on the paper and planned, ready to write.

    Attributes
    ----------
    page : Page
    mapping : PaperMapping
        The photo's pixels to the paper (:func:`page_mapping`).
    characters : tuple of CharacterPlan
        The characters to write, in reading order.
    skipped : tuple of PageCharacter
        The flagged characters left out (``skip_flagged``).
    width_mm : float
    travel_height_m : float
    options : WritingOptions
        The settings it was planned at (control rate, scene, controller), which the
        run uses.
    start_joints_rad : ndarray [7] or None
        The start posture, once :func:`ready_page_plan` has checked the arm's reach
        (:func:`write_page_plan` then does not check it again); None: not checked yet.
    """

    page: Page
    mapping: PaperMapping
    characters: tuple
    skipped: tuple
    width_mm: float
    travel_height_m: float
    options: WritingOptions
    start_joints_rad: np.ndarray | None = field(default=None, compare=False)

    def travels(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(from, to)`` world ``(x, y)`` of each travel: from the end of one character's
        path to the first point of the next."""
        chars = self.characters
        return [
            (a.plan.xy_m[-1], b.plan.xy_m[0]) for a, b in zip(chars[:-1], chars[1:], strict=True)
        ]

    def _stroke_entries(self) -> list | None:
        """The raw entries (notes included) of a stroke model's page (``"entries":
        "strokes"``, docs/PAGE.md), in entry order; None for a page of characters."""
        doc = self.page.document
        raw = doc.get("characters")
        return raw if doc.get("entries") == "strokes" and isinstance(raw, list) else None

    def travel_heights_m(self) -> list[float]:
        """The height of each travel above the paper: ``travel_height_m``, but between
        two strokes of one character on a stroke model's page (``"entries": "strokes"``,
        the entries' ``character`` notes) the controller's lift height plus
        :data:`STROKE_LIFT_M`, as ``img2dmp write`` lifts the pen within one character."""
        raw = self._stroke_entries()
        low = min(self.travel_height_m,
                  self.options.controller_config.lift_height_m + STROKE_LIFT_M)  # fmt: skip

        def owner(cp):
            entry = raw[cp.character.index] if raw and cp.character.index < len(raw) else {}
            return entry.get("character") if isinstance(entry, dict) else None

        chars = self.characters
        return [low if owner(a) is not None and owner(a) == owner(b) else self.travel_height_m
                for a, b in zip(chars[:-1], chars[1:], strict=True)]  # fmt: skip

    def words(self) -> tuple[str, str]:
        """``(what, noun)`` for the figure's title and the summary: ``("a page",
        "character")``, or for a stroke model's page ``("a page of N characters in M
        strokes", "stroke")`` (M the strokes planned)."""
        if self._stroke_entries() is None:
            return "a page", "character"
        n, m = self.page.document.get("n_characters", "?"), len(self.characters)
        return f"a page of {n} characters in {m} strokes", "stroke"

    def entry_owners(self) -> dict[int, tuple[int, int, int]]:
        """On a stroke model's page, each entry's ``(character, stroke, n_strokes)`` (its
        stroke, from 1, of the character's n, from its notes), by entry index; empty for a
        page of characters."""
        out = {}
        for i, e in enumerate(self._stroke_entries() or []):
            if not isinstance(e, dict):
                continue
            notes = tuple(e.get(k) for k in ("character", "stroke", "n_strokes"))
            # whole numbers only: an edited document's odd note leaves its entry unnamed
            if all(isinstance(v, int) and not isinstance(v, bool) for v in notes):
                out[i] = notes
        return out

    def entry_labels(self) -> dict[int, str]:
        """On a stroke model's page, each entry's ``"character C: S of N"``
        (:meth:`entry_owners`), by entry index; empty for a page of characters."""
        return {i: f"character {c}: {s} of {n}" for i, (c, s, n) in self.entry_owners().items()}

    def travel_steps(self) -> int:
        """Control steps of all the travels (up, across, down, rest)."""
        dt_s, cfg = self.options.dt_s, self.options.controller_config
        moving = sum(len(travel_targets(a, b, dt_s)) for a, b in self.travels())
        ups = sum(2 * _rise_steps(h, cfg, dt_s) for h in self.travel_heights_m())
        return moving + ups + _settle_steps(dt_s) * len(self.travels())

    def estimated_steps(self) -> int:
        """About how many control steps the page takes (for a progress bar): each DMP's
        duration plus a second for its approach, holds and lift, plus the travels."""
        writing_s = sum(float(cp.params.tau) + 1.0 for cp in self.characters)
        return int(writing_s / self.options.dt_s) + self.travel_steps()

    def joined(self) -> PlannedPath:
        """The characters' plans one after another, joined by their pen-up travels: the
        commanded path of the page, for the figure and the video. ``time_s`` counts the
        samples at the control period (the simulated time also holds the approaches and
        the held steps)."""
        dt_s, parts = self.options.dt_s, []
        for k, cp in enumerate(self.characters):
            if k:
                xy_m = travel_targets(self.characters[k - 1].plan.xy_m[-1], cp.plan.xy_m[0], dt_s)
                parts.append((self.mapping.to_pixels(xy_m), np.zeros(len(xy_m), bool), xy_m))
            parts.append((cp.plan.xy_px, cp.plan.pen_down, cp.plan.xy_m))
        xy_px, pen, xy_m = (np.concatenate([p[i] for p in parts]) for i in range(3))
        return PlannedPath(np.arange(len(pen)) * dt_s, xy_px, pen, xy_m)


def page_mapping(page: Page, width_mm: float, center_m) -> PaperMapping:
    """The layout rule: the page's written area (the union of its characters' boxes,
    :attr:`Page.written_area_px`) ``width_mm`` wide, aspect kept, centred on
    ``center_m``. A page read turned level (:attr:`Page.turned_deg`) is written level:
    its written area is then the box around its characters' boxes turned the same way."""
    w, h = page.image_size_px
    if not page.turned_deg or not page.characters:
        return PaperMapping.for_width((h, w), page.written_area_px, width_mm, center_m)
    boxes = [level_box_px(c.box_image_px, (h, w), page.turned_deg) for c in page.characters]
    x0, y0 = (min(b[i] for b in boxes) for i in (0, 1))
    x1, y1 = (max(b[i] for b in boxes) for i in (2, 3))
    return PaperMapping.for_width((h, w), (x0, y0, x1, y1), width_mm, center_m,
                                  page.turned_deg)  # fmt: skip


def travel_targets(from_xy_m, to_xy_m, dt_s: float) -> np.ndarray:
    """``[n, 2]`` in-plane targets of a travel, one per control step after the start:
    a minimum-jerk straight line whose top speed is ``TRAVEL_SPEED_M_S``."""
    a, b = np.asarray(from_xy_m, dtype=float), np.asarray(to_xy_m, dtype=float)
    duration_s = MIN_JERK_PEAK * float(np.linalg.norm(b - a)) / TRAVEL_SPEED_M_S
    n = max(1, math.ceil(duration_s / dt_s))
    return min_jerk_along(np.array([a, b]), n + 1)[1:]


def _rise_steps(travel_height_m: float, cfg, dt_s: float) -> int:
    """Steps for the pen to go between the lift height and the travel height."""
    return math.ceil(axis_move_s(cfg, travel_height_m - cfg.lift_height_m) / dt_s)


def _settle_steps(dt_s: float) -> int:
    return math.ceil(TRAVEL_SETTLE_S / dt_s)


def plan_page(
    page: Page,
    options: WritingOptions | None = None,
    *,
    width_mm: float | None = None,
    skip_flagged: bool | Collection[str] = False,
    travel_height_m: float = TRAVEL_HEIGHT_M,
) -> PagePlan:
    """Lay out a page on the paper and plan every character to write (no simulation).

    Parameters
    ----------
    page : Page
        From :func:`img2dmp.robot.pagefile.read_page` or ``check_page_document``.
    options : WritingOptions
        The control rate, the scene (where the paper is) and the controller; its
        ``writing_height_mm`` is not used (``width_mm`` sets the scale).
    width_mm : float or None
        Width of the page's written area on paper. None: ``DEFAULT_WIDTH_MM`` (160 mm),
        or the widest width that fits the sheet, to 0.1 mm below, when that is narrower
        (:attr:`PagePlan.width_mm` says which). A width given is written as given, or
        refused.
    skip_flagged : bool or collection of str
        Leave out the characters with flags (True), or with any of these flags (e.g.
        ``{"off_ink", "unexplained_ink"}``, keeping those only ``"unfamiliar"``); they
        keep their place in the layout. A name neither in ``CHARACTER_FLAGS`` nor on a
        character of the page is refused (a misspelt one would skip nothing).
    travel_height_m : float
        Height of the pen above the paper while it travels between characters; above
        the controller's ``lift_height_m``.

    Raises
    ------
    ValueError
        Nothing to write, a character's DMP that cannot be written, or a page that does
        not fit the sheet (naming the character, by how much, and the widest page that
        fits).
    """
    options = options or WritingOptions()
    if not isinstance(page, Page):
        raise ValueError(f"page must be a Page (read_page), got {type(page).__name__}")
    skip = _skipped_flags(page, skip_flagged)
    lift_m = options.controller_config.lift_height_m
    if not (isinstance(travel_height_m, (int, float)) and lift_m < travel_height_m <= 0.2):
        raise ValueError(
            f"travel_height_m must be in ({lift_m:g}, 0.2] m (above the lift height), "
            f"got {travel_height_m!r}"
        )
    chosen = [c for c in page.characters if not skip(c.flags)]
    skipped = tuple(c for c in page.characters if skip(c.flags))
    if not chosen:
        why = "all of them are flagged (skip_flagged)" if page.characters else "it has none"
        raise ValueError(f"{page.path}: no characters to write: {why}")

    def laid_out(width: float) -> PagePlan:
        mapping = page_mapping(page, width, options.scene_config.paper_center_m)
        plans = tuple(_plan_character(page, c, mapping, options.dt_s) for c in chosen)
        return PagePlan(page, mapping, plans, skipped, float(width), float(travel_height_m),
                        options)  # fmt: skip

    plan = laid_out(DEFAULT_WIDTH_MM if width_mm is None else width_mm)
    if width_mm is None:  # the default: narrower if the sheet asks for it
        widest = math.floor(widest_width_mm(plan, options.scene_config) * 10) / 10
        if widest < DEFAULT_WIDTH_MM:
            plan = laid_out(widest)
    check_page_fits(plan, options.scene_config)
    options.check_video(_duration_bound_s(plan, options))
    return plan


def _skipped_flags(page: Page, skip_flagged) -> Callable[[tuple], bool]:
    """Whether a character of these flags is left out, as ``skip_flagged`` says
    (:func:`plan_page`); ``ValueError`` naming a value that is no flag."""
    if isinstance(skip_flagged, bool):
        return lambda flags: skip_flagged and bool(flags)
    names = [skip_flagged] if isinstance(skip_flagged, str) else skip_flagged
    try:
        names = frozenset(names)
    except TypeError:
        raise ValueError(f"skip_flagged must be True, False or flag names, got "
                         f"{skip_flagged!r}") from None  # fmt: skip
    on_page = {f for c in page.characters for f in c.flags}
    for name in sorted(names, key=str):
        if not isinstance(name, str) or name not in set(CHARACTER_FLAGS) | on_page:
            here = ", ".join(sorted(on_page)) or "none"
            raise ValueError(
                f"skip_flagged (--skip-flags): {name!r} is no character flag (the flags: "
                f"{', '.join(CHARACTER_FLAGS)}; on this page: {here})"
            )
    return lambda flags: bool(names.intersection(flags))


def _plan_character(page: Page, c: PageCharacter, mapping, dt_s: float) -> CharacterPlan:
    where = f"{page.path}: character {c.index} (line {c.line})"
    try:
        plan = plan_path(c.params_image, c.config, mapping, dt_s)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
    return CharacterPlan(c, checked_dmp(c.params_image, c.config), c.config, plan)


def _duration_bound_s(plan: PagePlan, options: WritingOptions) -> float:
    """The longest the page can take, as the duration of one DMP for
    :meth:`WritingOptions.check_video` (which adds one approach and one lift)."""
    cfg = options.controller_config
    per_extra = options.approach_timeout_s + axis_move_s(cfg, cfg.lift_height_m) + 0.4
    taus = sum(float(cp.params.tau) for cp in plan.characters)
    travels_s = plan.travel_steps() * options.dt_s
    return taus + (len(plan.characters) - 1) * per_extra + travels_s


_EDGES = ("bottom", "right", "top", "left")  # world -x, -y, +x, +y as the writer sees it


def widest_width_mm(plan: PagePlan, scene_config) -> float:
    """The widest width (mm) at which every planned path of ``plan`` lies on the sheet
    less its margin: the layout scales about the paper's centre, so each point's offset
    from it grows in proportion to the width (``inf`` for a page of one point there)."""
    lo, hi = sheet_bounds_m(scene_config)
    center = np.array(plan.mapping.center_m)
    widest = math.inf
    for cp in plan.characters:
        u = (cp.plan.xy_m - center) / plan.width_mm  # [T, 2] metres per mm of width
        with np.errstate(divide="ignore"):
            limit = np.where(u > 0, (hi - center) / u, np.where(u < 0, (lo - center) / u, np.inf))
        widest = min(widest, float(limit.min()))
    return widest


def check_page_fits(plan: PagePlan, scene_config) -> None:
    """``ValueError`` if a character's path leaves the sheet (less its margin): naming
    the first such character in reading order, how many mm it sticks out past which
    edge, and the widest page that fits (:func:`widest_width_mm`)."""
    lo, hi = sheet_bounds_m(scene_config)
    for cp in plan.characters:
        over = np.concatenate([lo - cp.plan.xy_m, cp.plan.xy_m - hi], axis=1)  # [T, 4] > 0: out
        if over.max() > 0:
            t, edge = np.unravel_index(int(np.argmax(over)), over.shape)
            raise ValueError(
                f"{plan.page.path}: the page does not fit the sheet at a width of "
                f"{plan.width_mm:g} mm: {cp.label} reaches {over[t, edge] * 1e3:.1f} mm past "
                f"the sheet's {_EDGES[edge]} edge (less its {SHEET_MARGIN_M * 1e3:g} mm "
                f"margin); the page fits at a width of at most "
                f"{widest_width_mm(plan, scene_config):.1f} mm (width_mm, --width-mm)"
            )


def check_page_reach(scene: WritingScene, plan: PagePlan, controller_config) -> np.ndarray:
    """``ValueError`` naming the character (or the travel) if the arm cannot reach a
    character's path (:func:`check_path`) or a travel at its height, the
    pen vertical; returns the start posture (the tip above the first point)."""
    q_start = None
    for cp in plan.characters:
        try:
            q = check_path(scene, cp.plan, controller_config)
        except ValueError as e:
            raise ValueError(f"{plan.page.path}: {cp.label}: {e}") from None
        q_start = q if q_start is None else q_start
    q = q_start
    heights = plan.travel_heights_m()
    for k, (a, b) in enumerate(plan.travels(), start=1):
        z_m = scene.config.paper_top_z + heights[k - 1]
        n = max(2, math.ceil(float(np.linalg.norm(b - a)) / 1e-3) + 1)  # 1 mm apart
        for xy in np.linspace(a, b, n):
            q, residual = scene.solve_ik([*xy, z_m], PEN_DOWN_ROTATION, q, max_iterations=100)
            if not residual <= IK_TOLERANCE_M:  # NaN too (a point far off)
                prev, nxt = plan.characters[k - 1].label, plan.characters[k].label
                raise ValueError(
                    f"{plan.page.path}: the arm cannot reach the travel from {prev} to {nxt} "
                    f"{heights[k - 1] * 1e3:g} mm above the paper: at world "
                    f"({xy[0]:.3f}, {xy[1]:.3f}) m the pen tip misses by "
                    f"{residual * 1e3:.1f} mm with the pen vertical; "
                    f"{move_towards(xy)} or lower the travel height"
                )
    return q_start


def slow_page_plan(scene: WritingScene, plan: PagePlan) -> PagePlan:
    """``plan`` with each character's DMP slowed, where it needs it, so that the joint
    speeds planned along it stay within ``plan.options.joint_speed_share`` of the iiwa's
    limits (:func:`img2dmp.robot.writing.slow_for_joint_limits`; only the characters that
    need it are slowed, each by its own factor, in :attr:`CharacterPlan.slowing`; one
    that has its slowing already, :func:`ready_page_plan`, is kept as it is)."""
    out = []
    for cp in plan.characters:
        if cp.slowing is not None:
            out.append(cp)
            continue
        try:
            params, path, slowing = slow_for_joint_limits(
                scene, cp.params, cp.config, cp.plan, plan.mapping, plan.options
            )
        except ValueError as e:  # slowed beyond the longest writing
            raise ValueError(f"{plan.page.path}: {cp.label}: {e}") from None
        out.append(dataclasses.replace(cp, params=params, plan=path, slowing=slowing))
    slowed = dataclasses.replace(plan, characters=tuple(out))
    plan.options.check_video(_duration_bound_s(slowed, plan.options))
    return slowed


def ready_page_plan(plan: PagePlan) -> PagePlan:
    """``plan`` as :func:`write_page_plan` will write it, without simulating: the arm's
    reach checked (:func:`check_page_reach`) and the characters that need it slowed
    (:func:`slow_page_plan`), in a scene of its own; so that its
    :meth:`PagePlan.estimated_steps` counts the slowing. :func:`write_page_plan` does not
    slow it again."""
    if not isinstance(plan, PagePlan):
        raise ValueError(f"plan must be a PagePlan (plan_page), got {type(plan).__name__}")
    options = plan.options
    with WritingScene(options.scene_config, time_step_s=options.dt_s) as scene:
        q_start = check_page_reach(scene, plan, options.controller_config)
        return dataclasses.replace(slow_page_plan(scene, plan), start_joints_rad=q_start)


def write_page_plan(
    plan: PagePlan,
    *,
    progress: Callable[[int], object] | None = None,
    on_character: Callable[[CharacterPlan], object] | None = None,
) -> PageResult:
    """Write a planned page (:func:`plan_page`) in one simulation session.

    The arm's reach along every character and travel is checked first
    (:func:`check_page_reach`), and the characters that need it are slowed for the
    iiwa's joint speed and acceleration limits (:func:`slow_page_plan`), unless
    :func:`ready_page_plan` has done both; then the arm starts at rest above
    the first character's first point and :class:`PageRun` writes them all.
    ``progress(n_steps)`` is called after each batch of simulated steps,
    ``on_character(character_plan)`` as each character starts. ``RuntimeError`` if the
    pen does not settle or land.
    """
    if not isinstance(plan, PagePlan):
        raise ValueError(f"plan must be a PagePlan (plan_page), got {type(plan).__name__}")
    options = plan.options
    scene_cfg, ctl_cfg = options.scene_config, options.controller_config
    scene = WritingScene(scene_cfg, time_step_s=options.dt_s)
    try:
        q_start = plan.start_joints_rad
        if q_start is None:
            q_start = check_page_reach(scene, plan, ctl_cfg)
        plan = slow_page_plan(scene, plan)
        scene.reset_joints(q_start)
        lift_z_m = scene_cfg.paper_top_z + ctl_cfg.lift_height_m
        controller = WritingController(scene, ctl_cfg, PEN_DOWN_ROTATION, q_start, lift_z_m)
        run = PageRun(scene, plan, controller, progress=progress, on_character=on_character)
        return run.execute()
    finally:
        scene.close()


def write_page(
    page,
    options: WritingOptions | None = None,
    *,
    width_mm: float | None = None,
    skip_flagged: bool | Collection[str] = False,
    travel_height_m: float = TRAVEL_HEIGHT_M,
    progress: Callable[[int], object] | None = None,
    on_character: Callable[[CharacterPlan], object] | None = None,
) -> PageResult:
    """Write every character of a page with the simulated arm (module docstring).

    Parameters
    ----------
    page : Page or path
        A checked page, or the path of a page document (:func:`read_page`).
    options : WritingOptions
        Control rate, scene, controller, timeouts, video; ``writing_height_mm`` is not
        used (``width_mm`` sets the scale).
    width_mm, skip_flagged, travel_height_m
        See :func:`plan_page`.
    progress, on_character
        See :func:`write_page_plan`.

    Returns
    -------
    PageResult
        One log for the whole page; per-character runs and the page's totals.

    Raises
    ------
    ValueError
        A bad document, or a page that does not fit the sheet or the arm's reach
        (before anything moves).
    RuntimeError
        The pen did not settle or land within the approach timeout.
    """
    if not isinstance(page, Page):
        page = read_page(page)
    plan = plan_page(
        page, options, width_mm=width_mm, skip_flagged=skip_flagged, travel_height_m=travel_height_m
    )
    return write_page_plan(plan, progress=progress, on_character=on_character)


@dataclass
class CharacterRun:
    """What became of one character of a page.

    Attributes
    ----------
    character : PageCharacter
    written : bool
        False for a character left out (``skip_flagged``).
    steps : (first, end) or None
        Its steps of the page's log, ``log.time_s[first:end]``: approach, writing, lift.
    plan : PlannedPath or None
    metrics : dict
        :func:`character_metrics` (empty if not written).
    """

    character: PageCharacter
    written: bool
    steps: tuple[int, int] | None = None
    plan: PlannedPath | None = None
    metrics: dict = field(default_factory=dict)


@dataclass
class PageResult(WritingResult):
    """A :class:`WritingResult` for the whole page, plus what each character got.

    ``log`` covers the page from the first step to the last lift (travels included, as
    phase ``"travel"``); ``plan`` is :meth:`PagePlan.joined`; ``metrics`` the page's
    totals (:func:`page_metrics`). The joint trajectory, the render, the video and the
    CSV log are made from it as from one DMP's result.

    Attributes
    ----------
    page_plan : PagePlan
    characters : list of CharacterRun
        One per character of the page, in reading order (skipped ones included).
    step_character : ndarray [S] int
        The index of the character each log step belongs to; -1 on the travels.
    """

    page_plan: PagePlan | None = None
    characters: list = field(default_factory=list)
    step_character: np.ndarray | None = None

    def extra_log_columns(self) -> dict[str, np.ndarray]:
        return {"character": self.step_character}


class PageRun(WritingRun):
    """All the characters of a planned page in one run: for each, the stages of one DMP
    (:meth:`WritingRun.approach`, :meth:`~WritingRun.write`, :meth:`~WritingRun.lift`)
    on its plan and a fresh :class:`DMPIntegrator`, then :meth:`travel` to the next.

    The scene must hold the arm at rest above the first character's first point.

    Parameters
    ----------
    scene : WritingScene
    page_plan : PagePlan
        Checked (:func:`check_page_reach`).
    controller : WritingController
    progress : callable or None
        ``progress(n_steps)``, as for :class:`WritingRun`.
    on_character : callable or None
        ``on_character(character_plan)`` as each character starts.
    """

    def __init__(self, scene, page_plan: PagePlan, controller, *, progress=None, on_character=None):
        first = page_plan.characters[0]
        dmp = DMPIntegrator(first.params, first.config)
        options = page_plan.options
        super().__init__(
            scene, first.plan, controller, options, dmp, page_plan.mapping, progress=progress
        )
        self.page_plan = page_plan
        self.on_character = on_character
        self.spans: list[tuple[int, int]] = []  # [first, end) steps per written character
        self.approach_times_s: list[float] = []
        if options.frame_interval_s is not None:
            # The video's paper shows the whole page's commanded path from the start.
            joined = page_plan.joined()
            self._inset = PaperInset(options.frame_size_px, joined.xy_m, joined.pen_down)

    def execute(self) -> PageResult:
        """Write every character, travelling between them; return the page's result."""
        wall0 = time.perf_counter()
        chars = self.page_plan.characters
        heights = self.page_plan.travel_heights_m()
        for k, cp in enumerate(chars):
            if k:
                self.travel(cp.plan.xy_m[0], heights[k - 1])
            self.write_character(cp, last=k == len(chars) - 1)
        self._report_progress()
        return self.result(time.perf_counter() - wall0)

    def write_character(self, cp: CharacterPlan, *, last: bool) -> None:
        """Approach, write and lift one character (the arm above its first point)."""
        if self.on_character is not None:
            self.on_character(cp)
        self.plan, self.dmp = cp.plan, DMPIntegrator(cp.params, cp.config)
        self.approach_s = 0.0  # the approach timeout is per character
        first = self.n_steps
        self.approach()
        self.write()
        self.lift(last=last)
        self.spans.append((first, self.n_steps))
        self.approach_times_s.append(self.approach_s)

    def travel(self, to_xy_m, up_m: float) -> None:
        """From the lifted pen at the current DMP's end point to rest ``lift_height_m``
        above ``to_xy_m``: up to ``up_m`` above the paper, a straight line, down, a short
        rest."""
        cfg, dt_s = self.options.controller_config, self.dt_s
        here = self.mapping.to_table(self.dmp.y[:2])
        rise = _rise_steps(up_m, cfg, dt_s)
        for _ in range(rise):
            self.control_step("travel", here, False, 0.0, up_height_m=up_m)
        for xy_m in travel_targets(here, to_xy_m, dt_s):
            self.control_step("travel", xy_m, False, 0.0, up_height_m=up_m)
        for _ in range(rise + _settle_steps(dt_s)):
            self.control_step("travel", to_xy_m, False, 0.0)

    @property
    def n_steps(self) -> int:
        """Control steps so far."""
        return len(self._columns["time_s"])

    def result(self, wall_s: float) -> PageResult:
        """The page's log, per-character runs and totals, the render and the frames."""
        log = self.log()
        ctl_cfg = self.options.controller_config
        runs, step_character = self._character_runs(log)
        metrics = page_metrics(log, runs, ctl_cfg.force_set_n)
        metrics.update(self.run_figures(wall_s, float(sum(self.approach_times_s))))
        metrics.update(
            {
                "width_mm": self.mapping.area_size_mm[0],
                "height_mm": self.mapping.area_size_mm[1],
                "mm_per_px": self.mapping.metres_per_px * 1e3,
            }
        )
        self.flush_ink()
        return PageResult(
            log=log,
            metrics=metrics,
            plan=self.page_plan.joined(),
            mapping=self.mapping,
            scene_config=self.scene.config,
            controller_config=ctl_cfg,
            frames=self.frames,
            render=self.final_render(),
            start_joints_rad=self.start_joints_rad,
            page_plan=self.page_plan,
            characters=runs,
            step_character=step_character,
        )

    def _character_runs(self, log: WritingLog) -> tuple[list[CharacterRun], np.ndarray]:
        """A :class:`CharacterRun` per character of the page (reading order) and the
        character of every log step."""
        f_set = self.options.controller_config.force_set_n
        step_character = np.full(log.n_steps, -1, dtype=int)
        done = {}
        for cp, (a, b), approach_s in zip(
            self.page_plan.characters, self.spans, self.approach_times_s, strict=True
        ):
            step_character[a:b] = cp.character.index
            m = character_metrics(cp.plan, log_steps(log, a, b), f_set)
            m["approach_s"] = float(approach_s)
            if cp.slowing is not None:
                m.update(cp.slowing.to_dict())
            done[cp.character.index] = CharacterRun(cp.character, True, (a, b), cp.plan, m)
        runs = [done.get(c.index, CharacterRun(c, False)) for c in self.page_plan.page.characters]
        return runs, step_character


def log_steps(log: WritingLog, first: int, end: int) -> WritingLog:
    """The steps ``first:end`` of a log, as a log."""
    return WritingLog(**{name: log[name][first:end] for name in log})


def _centroid(points: np.ndarray, length_m: np.ndarray) -> np.ndarray:
    """The centre ``[2]`` of a trace by length (the points' mean if it has none): a pen
    resting at a touch-down leaves a dot, not ink to weigh."""
    if len(points) == 0:
        return np.full(2, np.nan)
    if length_m.sum() <= 0.0:
        return points.mean(axis=0)
    return (points * length_m[:, None]).sum(axis=0) / length_m.sum()


def character_metrics(plan: PlannedPath, log: WritingLog, force_set_n: float) -> dict:
    """What :func:`write_dmp` measures for one DMP, on one character's steps of a page.

    Returns
    -------
    dict with
        :func:`writing_metrics` (tracking error, force, contact over the pen-down time
        with the DMP running), :func:`stroke_report` (per stroke) and
        :func:`img2dmp.robot.tempo.joint_speed_metrics` (its steps); ``length_mm`` -
        the commanded pen-down length; ``ink_share`` - the share of it with ink within
        ``INK_TOLERANCE_M`` (the strokes' ink shares weighted by length);
        ``ink_on_path_share`` - the share of the ink (by length) within that distance
        of the commanded pen-down path; ``ink_length_mm``; ``ink_centroid_m`` and
        ``path_centroid_m`` - world (x, y) of the centres by length of the ink and of the
        commanded pen-down path; ``placement_error_mm`` - the distance between them;
        ``start_s``, ``end_s`` - the page time of its first and last step.
    """
    m = writing_metrics(log, force_set_n)
    m.update(stroke_report(plan, log, force_set_n))
    m.update(joint_speed_metrics(log))
    lengths = np.array([s["length_mm"] for s in m["strokes"]])
    shares = np.array([s["ink_share"] for s in m["strokes"]])
    length_mm = float(lengths.sum())
    ink, ink_w = ink_trace(log.tip_m[:, :2], log.force_n > 0.0)  # [m, 2], [m]
    path, path_w = ink_trace(plan.xy_m, plan.pen_down)  # the commanded strokes, dense
    ink_c, path_c = _centroid(ink, ink_w), _centroid(path, path_w)
    dt_s = float(np.median(np.diff(log.time_s))) if log.n_steps > 1 else 0.0
    m.update(
        {
            "length_mm": length_mm,
            "ink_share": float((shares * lengths).sum() / length_mm)
            if length_mm > 0
            else float(shares.mean())
            if len(shares)
            else float("nan"),
            "ink_on_path_share": ink_on_path_share(plan.xy_m, plan.pen_down, ink, ink_w),
            "ink_length_mm": float(ink_w.sum() * 1e3),
            "ink_centroid_m": ink_c.tolist(),
            "path_centroid_m": path_c.tolist(),
            "placement_error_mm": float(np.linalg.norm(ink_c - path_c) * 1e3),
            "start_s": float(log.time_s[0] - dt_s) if log.n_steps else float("nan"),
            "end_s": float(log.time_s[-1]) if log.n_steps else float("nan"),
        }
    )
    return m


def _weighted(values, weights) -> float:
    v, w = np.asarray(values, dtype=float), np.asarray(weights, dtype=float)
    ok = np.isfinite(v) & (w > 0)
    return float((v[ok] * w[ok]).sum() / w[ok].sum()) if ok.any() else float("nan")


def page_metrics(log: WritingLog, runs: list[CharacterRun], force_set_n: float) -> dict:
    """The page's totals.

    Returns
    -------
    dict with
        :func:`writing_metrics` over every character's pen-down time with its DMP
        running; ``strokes`` (every character's, each with its ``character``),
        ``stroke_ink_share_min``, ``dwell_s``, ``force_in_band_share_with_dwell`` as for
        one DMP; ``ink_share`` (weighted by commanded length) and ``ink_on_path_share``
        (weighted by ink length) over the written characters, their ``length_mm`` and
        ``ink_length_mm`` summed; ``placement_error_max_mm``;
        ``travel_contact_s`` - time the pen touched the paper while travelling between
        characters (0: no ink between them); ``characters``, ``characters_written``,
        ``characters_skipped``; :func:`img2dmp.robot.tempo.joint_speed_metrics` and
        :func:`~img2dmp.robot.tempo.joint_acceleration_metrics` over the whole log
        (travels included); ``characters_slowed`` and ``slowdown_max`` (1: none slowed for
        the iiwa's joint limits); ``planned_joint_speed_share`` and
        ``planned_joint_acceleration_share``, the largest of the written characters'
        (their DMPs at the tempo written), with ``planned_joint_acceleration_joint`` and
        ``planned_joint_acceleration_character`` (which character's; absent if no
        character was planned).
    """
    m = writing_metrics(log, force_set_n)
    m.update(joint_speed_metrics(log))
    m.update(joint_acceleration_metrics(log))
    written = [r.metrics for r in runs if r.written]
    strokes = [
        {"character": r.character.index, **s}
        for r in runs
        if r.written
        for s in r.metrics["strokes"]
    ]
    dt_s = float(np.median(np.diff(log.time_s))) if log.n_steps > 1 else 0.0
    down = log.in_phase("write") & log.pen_down
    in_band = np.abs(log.force_n[down] - force_set_n) <= 0.2 * force_set_n
    travel = log.phase == PHASES.index("travel")
    m.update(
        {
            "strokes": strokes,
            "stroke_ink_share_min": min((s["ink_share"] for s in strokes), default=float("nan")),
            "dwell_s": float(log.dwell.sum() * dt_s),
            "force_in_band_share_with_dwell": float(in_band.mean()) if in_band.size else math.nan,
            "ink_share": _weighted(
                [c["ink_share"] for c in written], [c["length_mm"] for c in written]
            ),
            "ink_on_path_share": _weighted(
                [c["ink_on_path_share"] for c in written], [c["ink_length_mm"] for c in written]
            ),
            "length_mm": float(sum(c["length_mm"] for c in written)),
            "ink_length_mm": float(sum(c["ink_length_mm"] for c in written)),
            "placement_error_max_mm": max((c["placement_error_mm"] for c in written), default=0.0),
            "travel_contact_s": float((travel & (log.force_n > 0.0)).sum() * dt_s),
            "characters": len(runs),
            "characters_written": len(written),
            "characters_skipped": len(runs) - len(written),
            "characters_slowed": sum(c.get("slowdown", 1.0) > 1.0 for c in written),
            "slowdown_max": max((c.get("slowdown", 1.0) for c in written), default=1.0),
        }
    )
    planned = [r for r in runs if r.written and "planned_joint_acceleration_share" in r.metrics]
    if planned:
        top = max(planned, key=lambda r: r.metrics["planned_joint_acceleration_share"])
        m.update(
            {
                "planned_joint_speed_share": max(
                    r.metrics["planned_joint_speed_share"] for r in planned
                ),
                "planned_joint_acceleration_share": top.metrics["planned_joint_acceleration_share"],
                "planned_joint_acceleration_joint": top.metrics["planned_joint_acceleration_joint"],
                "planned_joint_acceleration_character": top.character.index,
            }
        )
    return m


__all__ = [
    "CHARACTER_FLAGS",
    "DEFAULT_WIDTH_MM",
    "TRAVEL_HEIGHT_M",
    "CharacterPlan",
    "CharacterRun",
    "PagePlan",
    "PageResult",
    "PageRun",
    "character_metrics",
    "check_page_fits",
    "check_page_reach",
    "log_steps",
    "page_mapping",
    "page_metrics",
    "plan_page",
    "ready_page_plan",
    "slow_page_plan",
    "read_page",
    "travel_targets",
    "widest_width_mm",
    "write_page",
    "write_page_plan",
]
