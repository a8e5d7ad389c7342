"""scenelabel.train.divergence: when a run is diverged, what is kept, and when it stops."""

import pytest
import torch

from scenelabel import TrainingError
from scenelabel.train.divergence import (
    DIVERGENCE_CHECK_STEP,
    LEAVING_FALL,
    LEFT_FRACTION,
    MAX_ROLLBACKS,
    MSE_EMA,
    ROLLBACK_LR_FACTOR,
    SNAPSHOT_EVERY,
    Diverged,
    DivergenceGuard,
)

MEAN_COLOUR = 0.02


def run(guard: DivergenceGuard, mses, start: int = 0) -> int:
    """Feeds one MSE a step from ``start`` as the trainer does (keep, then observe), each step's
    state a tensor holding its step; returns the step reached."""
    step = start
    for mse in mses:
        guard.keep(step, lambda: {"w": torch.tensor([float(step)])})
        guard.observe(step, mse)
        step += 1
    return step


def kept_steps(guard: DivergenceGuard) -> list[int]:
    assert all(float(state["w"]) == step for step, _, state in guard.snapshots)  # copies of that step's state
    return [step for step, _, _ in guard.snapshots]


def test_the_smoothed_error_is_an_exponential_average_checked_from_its_step():
    guard = DivergenceGuard(MEAN_COLOUR)
    run(guard, [0.1] * DIVERGENCE_CHECK_STEP)  # far above the mean colour's, but before the check
    assert guard.mse_ema == pytest.approx(0.1)
    with pytest.raises(Diverged) as info:  # one perfect step: 0.9 x 0.1, still above the mean colour's
        guard.observe(DIVERGENCE_CHECK_STEP, 0.0)
    assert info.value.step == DIVERGENCE_CHECK_STEP
    assert info.value.mse_ema == pytest.approx((1 - MSE_EMA) * 0.1)


def test_a_run_below_the_mean_colour_is_never_diverged():
    guard = DivergenceGuard(MEAN_COLOUR)
    run(guard, [0.999 * MEAN_COLOUR] * 1000)
    assert guard.rollbacks == []


def test_the_two_newest_copies_are_kept_every_snapshot_every_steps_while_not_diverged():
    guard = DivergenceGuard(MEAN_COLOUR)
    run(guard, [2 * MEAN_COLOUR] * (SNAPSHOT_EVERY + 1))  # the initial state is copied whatever its error
    assert kept_steps(guard) == [0]
    step = run(guard, [0.5 * MEAN_COLOUR] * (3 * SNAPSHOT_EVERY - 1), start=SNAPSHOT_EVERY + 1)
    assert step == 4 * SNAPSHOT_EVERY and kept_steps(guard) == [2 * SNAPSHOT_EVERY, 3 * SNAPSHOT_EVERY]
    run(guard, [0.5 * MEAN_COLOUR] * SNAPSHOT_EVERY, start=step)
    assert kept_steps(guard) == [3 * SNAPSHOT_EVERY, 4 * SNAPSHOT_EVERY]
    guard.mse_ema = 1.01 * MEAN_COLOUR  # above the mean colour's: no copy
    guard.keep(5 * SNAPSHOT_EVERY, lambda: {"w": torch.tensor([5.0 * SNAPSHOT_EVERY])})
    assert kept_steps(guard) == [3 * SNAPSHOT_EVERY, 4 * SNAPSHOT_EVERY]


def test_a_rollback_resumes_from_the_older_copy_with_its_smoothed_error():
    guard = DivergenceGuard(MEAN_COLOUR)
    step = run(guard, [0.1 * MEAN_COLOUR] * (2 * SNAPSHOT_EVERY + 1))
    older = guard.snapshots[0]
    assert [older[0], guard.snapshots[1][0]] == [SNAPSHOT_EVERY, 2 * SNAPSHOT_EVERY]
    with pytest.raises(Diverged) as info:  # a climb within the newer copy's stretch
        run(guard, [10 * MEAN_COLOUR] * SNAPSHOT_EVERY, start=step)
    resumed, state = guard.roll_back(info.value)
    assert resumed == SNAPSHOT_EVERY and float(state["w"]) == SNAPSHOT_EVERY
    assert guard.mse_ema == older[1]  # not the first new step's error alone: the check stays smoothed
    assert kept_steps(guard) == [SNAPSHOT_EVERY]  # the newer copy belonged to the run that diverged
    guard.keep(SNAPSHOT_EVERY, lambda: {"w": torch.tensor([float(SNAPSHOT_EVERY)])})  # the resumed step: no twin
    assert kept_steps(guard) == [SNAPSHOT_EVERY]


def test_the_rate_falls_with_each_rollback_and_the_kept_copy_stays_untouched():
    live = {"w": torch.zeros(3)}
    guard = DivergenceGuard(MEAN_COLOUR)
    guard.keep(0, lambda: live)
    live["w"] += 5.0  # training goes on in place: the copy must not follow
    for k in range(1, MAX_ROLLBACKS + 1):
        step, state = guard.roll_back(Diverged(DIVERGENCE_CHECK_STEP + k, 2 * MEAN_COLOUR))
        assert step == 0 and torch.equal(state["w"], torch.zeros(3))
        state["w"] += 1.0  # the resumed run changes its state in place: the kept copy stays
        assert guard.rollbacks[-1] == {
            "diverged_at": DIVERGENCE_CHECK_STEP + k, "resumed_from": 0, "lr_factor": ROLLBACK_LR_FACTOR**k,
        }
    with pytest.raises(TrainingError, match=f"after {MAX_ROLLBACKS} rollbacks.*learning rate is probably too high"):
        guard.roll_back(Diverged(999, 2 * MEAN_COLOUR))


def test_without_a_copy_a_diverged_run_stops():
    guard = DivergenceGuard(MEAN_COLOUR)  # e.g. a build resumed from a checkpoint mid-run, not yet copied
    with pytest.raises(TrainingError, match="diverged at step 250: .*worse than predicting the mean colour"):
        guard.roll_back(Diverged(250, 2 * MEAN_COLOUR))


def test_below_compares_the_smoothed_error_with_a_fraction_of_the_mean_colours():
    guard = DivergenceGuard(MEAN_COLOUR)
    assert not guard.below(1.0)  # no error seen yet
    run(guard, [0.5 * MEAN_COLOUR])
    assert guard.below(0.5) and guard.below(1.0)
    assert not guard.below(0.49)


def test_a_run_still_leaving_the_mean_colour_is_not_diverged_until_it_stops_falling():
    """Never below the mean colour's error yet, but falling by more than LEAVING_FALL per SNAPSHOT_EVERY
    steps: still leaving the fog (a big room on a slow machine). Once it levels off above, it has diverged."""
    guard = DivergenceGuard(MEAN_COLOUR)
    rate = 0.5 ** (1 / SNAPSHOT_EVERY)  # the error halves every SNAPSHOT_EVERY steps
    falling = [8 * MEAN_COLOUR * rate**i for i in range(DIVERGENCE_CHECK_STEP + 50)]
    step = run(guard, falling)  # at the check the smoothed error is still about 2x the mean colour's
    assert guard.mse_ema > MEAN_COLOUR and not guard.left and guard.rollbacks == []
    with pytest.raises(Diverged) as info:  # it levels off above the mean colour's
        run(guard, [falling[-1]] * SNAPSHOT_EVERY, start=step)
    assert info.value.mse_ema > LEAVING_FALL * max(guard.recent)


def test_a_run_that_left_the_mean_colour_and_climbs_back_is_diverged_even_while_falling():
    guard = DivergenceGuard(MEAN_COLOUR)
    step = run(guard, [0.5 * MEAN_COLOUR] * 50 + [20 * MEAN_COLOUR] * 20)  # left, then a climb far above
    assert guard.left
    with pytest.raises(Diverged):  # falling back, but from above the mean colour's: the climb counts
        run(guard, [2 * MEAN_COLOUR] * DIVERGENCE_CHECK_STEP, start=step)


def test_a_wobble_about_the_mean_colour_on_the_way_down_is_no_climb_back():
    """Crossing the mean colour's error from above, the smoothed error wobbles about it: not left
    (LEFT_FRACTION) until well below it, so a falling run that dips under and back is not diverged."""
    guard = DivergenceGuard(MEAN_COLOUR)
    rate = 0.5 ** (1 / DIVERGENCE_CHECK_STEP)  # from 2x the mean colour's to it at the check
    step = run(guard, [2 * MEAN_COLOUR * rate**i for i in range(DIVERGENCE_CHECK_STEP + 1)])
    step = run(guard, [0.95 * MEAN_COLOUR] * 5 + [1.01 * MEAN_COLOUR] * 10, start=step)  # under and back
    assert guard.mse_ema > MEAN_COLOUR and not guard.left and guard.rollbacks == []
    run(guard, [0.5 * LEFT_FRACTION * MEAN_COLOUR] * 50, start=step)  # well below: left
    assert guard.left
