"""The run's fraction done follows the steps, and the clock only once the time budget is going to
end the run first."""

import itertools

import numpy as np
import pytest

from scenelabel.train.schedule import JUDGE_FROM, RunSchedule, fraction_of_run


def _fraction_reference(step, steps, elapsed, budget, anchor):
    """The definition, in float64, one case at a time."""
    by_steps = np.float64(step) / max(steps, 1)
    if anchor is None or not budget:
        return float(min(by_steps, 1.0))
    start, then = np.float64(anchor[0]), np.float64(anchor[1])
    by_time = start + (1 - start) * (np.float64(elapsed) - then) / max(np.float64(budget) - then, 1e-9)
    return float(min(max(by_steps, by_time), 1.0))


def test_fraction_of_run_against_the_reference():
    cases = itertools.product([0, 1, 250, 999, 1000, 5000], [1, 1000], [0.0, 10.0, 99.0, 150.0, 1e6],
                              [None, 150.0, 1e-3], [None, (0.1, 10.0), (0.0, 0.0), (0.9, 150.0)])
    for step, steps, elapsed, budget, anchor in cases:
        got = fraction_of_run(step, steps, elapsed, budget, anchor)
        assert got == pytest.approx(_fraction_reference(step, steps, elapsed, budget, anchor), abs=1e-12)
        assert np.isfinite(got) and 0.0 <= got <= 1.0


def test_without_an_anchor_the_clock_is_not_read():
    for elapsed in [0.0, 1.0, 149.0, 1e9]:
        assert fraction_of_run(300, 2000, elapsed, 150.0, None) == 0.15


def test_an_anchor_runs_the_fraction_in_a_straight_line_to_1_at_the_budget():
    anchor = (0.3, 60.0)  # 30 % of the steps done when the budget was found to bind, 60 s in
    assert fraction_of_run(600, 2000, 60.0, 150.0, anchor) == pytest.approx(0.3)  # no jump at the anchor
    assert fraction_of_run(650, 2000, 105.0, 150.0, anchor) == pytest.approx(0.65)  # half way in time
    assert fraction_of_run(700, 2000, 150.0, 150.0, anchor) == 1.0
    assert fraction_of_run(1990, 2000, 100.0, 150.0, anchor) == pytest.approx(0.995)  # steps ahead: they lead
    assert fraction_of_run(5, 2000, 150.0 + 1e-6, 150.0, (0.0, 150.0)) == 1.0  # anchored at the budget's end: finite


def _run(schedule, seconds_per_step, steps, budget):
    """Feed ``schedule`` a run of ``steps`` steps whose step i takes seconds_per_step(i); returns the
    fractions after each step, the step it anchored at (or None) and the elapsed seconds."""
    elapsed, fractions, anchored_at = 0.0, [], None
    schedule.observe(0, steps, 0.0, budget)
    for step in range(1, steps + 1):
        elapsed += seconds_per_step(step)
        if budget is not None and elapsed >= budget:
            break
        if schedule.observe(step, steps, elapsed, budget):
            anchored_at = step
        fractions.append(schedule.fraction(step, steps, elapsed, budget))
    return np.array(fractions), anchored_at, elapsed


def test_a_run_that_ends_on_its_steps_follows_the_steps_however_slow_its_start():
    """The default build's pattern (a probe of studio-3x3): the grid's warm-up steps run several times
    slower than the later ones, so the budget's fraction spent leads the steps' early on, and the run
    still ends well inside the budget. Two clocks, one schedule."""
    steps, budget = 2000, 150.0
    runs = [
        _run(RunSchedule(), lambda i: 0.5 if i <= 16 else 0.06, steps, budget),
        _run(RunSchedule(), lambda i: 0.05, steps, budget),
    ]
    for fractions, anchored_at, elapsed in runs:
        assert anchored_at is None and elapsed < budget
        np.testing.assert_array_equal(fractions, np.arange(1, steps + 1) / steps)
    assert 16 * 0.5 / budget > 16 / steps  # the slow start: the time fraction did lead


def test_a_run_the_budget_ends_anchors_once_judged_and_ends_its_schedules_at_the_budget():
    steps, budget = 2000, 60.0
    schedule = RunSchedule()
    fractions, anchored_at, elapsed = _run(schedule, lambda i: 0.1, steps, budget)  # 200 s of steps in 60 s
    assert anchored_at is not None and schedule.anchor is not None
    assert schedule.anchor[1] == pytest.approx(JUDGE_FROM * budget, abs=0.11)  # judged at JUDGE_FROM of the budget
    np.testing.assert_allclose(fractions[: anchored_at - 1], np.arange(1, anchored_at) / steps)  # steps until then
    assert np.all(np.diff(fractions) >= 0) and np.max(np.diff(fractions)) < 3e-3  # no jump
    assert fractions[-1] == pytest.approx(1.0, abs=3e-3)  # the last step before the budget: the schedules ended
    assert schedule.fraction(len(fractions), steps, budget, budget) == 1.0


def test_the_rate_judged_is_the_last_window_s():
    """A run slow at first and fast later is not anchored on its first steps' rate."""
    steps, budget = 2000, 100.0
    slow = int(JUDGE_FROM * budget / 1.0) - 2  # slow steps up to just short of JUDGE_FROM of the budget
    _, anchored_at, elapsed = _run(RunSchedule(), lambda i: 1.0 if i <= slow else 0.02, steps, budget)
    assert slow * 1.0 + (steps - slow) * 0.02 < budget  # it fits ...
    assert anchored_at is None and elapsed < budget  # ... and was judged so


def test_a_run_whose_steps_keep_speeding_up_is_not_found_short(monkeypatch):
    """A default build's pattern: its steps speed up all through the run (the density grid empties),
    so the rate at JUDGE_FROM projects a run longer than the budget (by less than SHORT_BY), and the
    run still ends on its steps inside the budget."""
    from scenelabel.train import schedule as schedule_module

    steps, budget = 2000, 150.0
    speeding_up = lambda i: 0.1 - 0.06 * i / steps  # noqa: E731  0.1 s a step down to 0.04 s: 140 s in all
    fractions, anchored_at, elapsed = _run(RunSchedule(), speeding_up, steps, budget)
    assert anchored_at is None and elapsed < budget
    np.testing.assert_array_equal(fractions, np.arange(1, steps + 1) / steps)
    monkeypatch.setattr(schedule_module, "SHORT_BY", 1.0)  # judged on the rate alone, it was found short
    assert _run(RunSchedule(), speeding_up, steps, budget)[1] is not None


def test_a_steady_run_a_little_over_its_budget_is_found_short_later_and_still_ends_its_schedules():
    steps, budget = 2000, 100.0
    schedule = RunSchedule()
    fractions, anchored_at, _ = _run(schedule, lambda i: 1.2 * budget / steps, steps, budget)  # needs 1.2 x the budget
    assert anchored_at is not None
    assert schedule.anchor[1] == pytest.approx(0.6 * budget, abs=0.2)  # (1.2 B - t) > SHORT_BY (B - t) from t = 0.6 B
    assert fractions[-1] == pytest.approx(1.0, abs=3e-3)


def test_no_budget_never_anchors():
    schedule = RunSchedule()
    fractions, anchored_at, _ = _run(schedule, lambda i: 100.0, 50, None)
    assert anchored_at is None and schedule.anchor is None
    np.testing.assert_array_equal(fractions, np.arange(1, 51) / 50)


def test_a_rollback_resumes_the_schedules_of_the_state_it_goes_back_to():
    steps, budget = 1000, 100.0
    stepping = RunSchedule()
    snapshot = stepping.snapshot(100, steps, 10.0, budget)
    stepping.resume(snapshot, 50.0)  # it followed the steps: it does again, judged afresh
    assert stepping.anchor is None and not stepping.recent
    assert stepping.fraction(100, steps, 50.0, budget) == 0.1
    clocked = RunSchedule((0.05, 20.0))
    snapshot = clocked.snapshot(100, steps, 40.0, budget)  # 0.05 + 0.95 * 20 / 80
    assert snapshot["fraction"] == pytest.approx(0.2875)
    clocked.resume(snapshot, 60.0)  # the time thrown away stays spent: from 0.2875 at 60 s to 1 at 100 s
    assert clocked.fraction(100, steps, 60.0, budget) == pytest.approx(0.2875)
    assert clocked.fraction(100, steps, 80.0, budget) == pytest.approx(0.2875 + 0.7125 / 2)
