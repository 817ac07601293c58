"""A page's robot job (``img2dmp.web.page_jobs``) estimates its length with the slowing
counted: a character too fast for a real iiwa's joints is written slower
(:mod:`img2dmp.robot.tempo`), and the progress's expected steps (and the video's frame
interval) must include that time, or the bar sits at its cap long before the end.

The page is the three characters of ``tests/test_robot_page.py`` with the "l" made 15
times as fast (a 67 ms stroke that the slowing stretches to more than twice that); no
simulation runs, only the planning.
"""

from __future__ import annotations

import pytest

from img2dmp.robot import available

pytest.importorskip("fastapi")

needs_pybullet = pytest.mark.skipif(
    not available(), reason="pybullet is not installed (pip install -e '/path/to/img2dmp[robot]')"
)


@needs_pybullet
def test_a_page_jobs_expected_steps_count_the_slowing():
    from img2dmp.robot import WritingScene
    from img2dmp.robot.page import slow_page_plan
    from img2dmp.web.page_jobs import expected_steps
    from test_robot_page import page_with_a_fast_l

    plan, options, params = page_with_a_fast_l()

    ready, steps = expected_steps(plan)
    factors = [cp.slowing.factor for cp in ready.characters]
    assert factors[0] == factors[2] == 1.0 and factors[1] > 2.0, factors
    # The slowed character's extra time, in control steps, is in the estimate ...
    extra = (float(ready.characters[1].params.tau) - float(params.tau)) / options.dt_s
    assert steps - plan.estimated_steps() == pytest.approx(extra, abs=1.0)
    # ... and the estimate covers every planned sample and travel of the slowed page.
    planned = sum(len(cp.plan.time_s) for cp in ready.characters) + ready.travel_steps()
    assert steps >= planned
    # Writing the readied plan does not slow it again: the same factors, the same DMPs.
    with WritingScene(options.scene_config, time_step_s=options.dt_s) as scene:
        again = slow_page_plan(scene, ready)
    assert [cp.params for cp in again.characters] == [cp.params for cp in ready.characters]
