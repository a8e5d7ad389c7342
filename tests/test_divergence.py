"""scenelabel.train.divergence: when a run is diverged, what is kept, and when it stops."""

import pytest
import torch

from scenelabel import TrainingError
from scenelabel.train.divergence import (
    DIVERGENCE_CHECK_STEP,
    HEALTHY_RATIO,
    MAX_ROLLBACKS,
    MSE_EMA,
    ROLLBACK_LR_FACTOR,
    SNAPSHOT_EVERY,
    Diverged,
    DivergenceGuard,
)

MEAN_COLOUR = 0.02


def run(guard: DivergenceGuard, mses, start: int = 0, state=None) -> int:
    """Feeds one MSE a step from ``start`` as the trainer does (keep, then observe); the step reached."""
    step = start
    for mse in mses:
        guard.keep(step, lambda: {"w": torch.tensor([float(step)]) if state is None else state})
        guard.observe(step, mse)
        step += 1
    return step


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


def test_copies_are_taken_every_snapshot_every_steps_only_while_clearly_learning():
    guard = DivergenceGuard(MEAN_COLOUR)
    # the initial state is copied whatever its error; then only while the smoothed error is at
    # most HEALTHY_RATIO of the mean colour's
    run(guard, [0.9 * MEAN_COLOUR] * (SNAPSHOT_EVERY + 1))
    assert guard.snapshot[0] == 0
    step = run(guard, [0.99 * HEALTHY_RATIO * MEAN_COLOUR] * (2 * SNAPSHOT_EVERY - 1), start=SNAPSHOT_EVERY + 1)
    assert guard.snapshot[0] == 2 * SNAPSHOT_EVERY
    assert float(guard.snapshot[2]["w"]) == 2 * SNAPSHOT_EVERY
    # the error climbs from step 3 x SNAPSHOT_EVERY on: the copy made before that step is the last
    run(guard, [0.9 * MEAN_COLOUR] * (2 * SNAPSHOT_EVERY), start=step)
    assert step == 3 * SNAPSHOT_EVERY and guard.snapshot[0] == 3 * SNAPSHOT_EVERY


def test_a_rollback_hands_back_an_untouched_copy_and_lowers_the_rate_each_time():
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
        assert guard.mse_ema is None  # the smoothed error as it was at the copy (none yet at step 0)
    with pytest.raises(TrainingError, match=f"after {MAX_ROLLBACKS} rollbacks.*learning rate is probably too high"):
        guard.roll_back(Diverged(999, 2 * MEAN_COLOUR))


def test_the_smoothed_error_goes_back_with_the_state():
    guard = DivergenceGuard(MEAN_COLOUR)
    run(guard, [0.1 * MEAN_COLOUR] * (SNAPSHOT_EVERY + 1))
    kept = guard.snapshot[1]
    assert guard.snapshot[0] == SNAPSHOT_EVERY and kept == pytest.approx(0.1 * MEAN_COLOUR)
    with pytest.raises(Diverged) as info:
        run(guard, [10 * MEAN_COLOUR] * DIVERGENCE_CHECK_STEP, start=SNAPSHOT_EVERY + 1)
    guard.roll_back(info.value)
    assert guard.mse_ema == kept  # not the first new step's error alone: the check stays smoothed


def test_without_a_copy_a_diverged_run_stops():
    guard = DivergenceGuard(MEAN_COLOUR)  # e.g. a build resumed from a checkpoint mid-run, not yet copied
    with pytest.raises(TrainingError, match="diverged at step 250: .*worse than predicting the mean colour"):
        guard.roll_back(Diverged(250, 2 * MEAN_COLOUR))
