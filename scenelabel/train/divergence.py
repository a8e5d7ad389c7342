"""What a training run does when its photometric error climbs back to the mean colour's.

Early in a build the field turns from fog into surfaces, and in some runs the photometric error
climbs back to about the colour variance of the targets on the way, before it falls for good
(probes with the check off: office-5x4 around step 200, with and without
``sampling.grid_open_rays``). Which runs do so is chance: repeated runs of one build differ. A
check that stops such a run can stop a build that would have finished (docs/suite_open.md: two
builds stopped); one that never stops lets a learning rate 1000 times too high
run to its end. So :class:`DivergenceGuard` keeps copies of the state from before the climb and,
when the run diverges, hands one back to be resumed at a lower learning rate; only when that has
not helped MAX_ROLLBACKS times does the build stop.
Orchestration only: no maths here, and nothing here knows what a state holds.
"""

from __future__ import annotations

import copy
from collections import deque
from typing import Callable

from scenelabel.errors import TrainingError

__all__ = [
    "DIVERGENCE_CHECK_STEP",
    "Diverged",
    "DivergenceGuard",
    "LEAVING_FALL",
    "LEFT_FRACTION",
    "MAX_ROLLBACKS",
    "MSE_EMA",
    "ROLLBACK_LR_FACTOR",
    "SNAPSHOT_EVERY",
]

DIVERGENCE_CHECK_STEP = 200
"""From this step on, a run whose smoothed photometric MSE is worse than predicting every pixel
as the mean training colour (the colour variance) has diverged. A room of plain walls
(the mean colour already a good guess) trained on sensor depth can still sit there at step 100
(gallery-8x5 with phone depth: 1.01 times it, 0.14 times at step 200). A learning rate 100 times
too high sat just above it on the toy scene on one machine (1.14 times at step 200) and was not
caught on another (2026-11-27, the same code): the check catches runs that fail
clearly, and tests/test_train.py checks a learning rate 1000 times too high."""

LEFT_FRACTION = 0.8
"""A run has left the mean colour once its smoothed error has been at most this fraction of the mean
colour's; only such a run can climb back. One that crosses the mean colour's error on its way down
wobbles about it for a few steps (a probe of hall-10x6 with phone depth on a slow machine, outside the
repo's scripts: 0.01194 against 0.01189 at step 215, just after it first crossed; docs/models.md)."""

LEAVING_FALL = 0.8
"""A run that has not left the mean colour (LEFT_FRACTION) is still leaving it, not diverged, while
its smoothed error is at most this times what it was SNAPSHOT_EVERY steps before: a big room on a slow
machine, its schedules compressed into a few hundred steps of its time budget, sits above the mean
colour at step 200 and falls through it later (the same probe: 0.0181 at step 100, 0.0119 at 200, the
mean colour's 0.0119), and a rollback to the initial state at half the rate spends the budget."""

MSE_EMA = 0.1
"""Weight of the newest step in the smoothed MSE used by the divergence check."""

SNAPSHOT_EVERY = 100
"""Steps between copies of the training state, taken while the run is not diverged; the two newest
are kept (each costs one state dict's memory), and a rollback resumes from the older one: a climb
to the mean colour's error takes tens of steps, so the newer copy may already be on its way up."""

ROLLBACK_LR_FACTOR = 0.5
"""Each rollback multiplies the learning rate by this, for the rest of the run."""

MAX_ROLLBACKS = 3
"""Rollbacks before a diverging run stops with :class:`~scenelabel.errors.TrainingError`."""


class Diverged(Exception):
    """Raised by :meth:`DivergenceGuard.observe`: the run has diverged at ``step``."""

    def __init__(self, step: int, mse_ema: float):
        super().__init__(f"diverged at step {step}")
        self.step = step
        self.mse_ema = mse_ema


class DivergenceGuard:
    """Watches the smoothed photometric MSE of a run against the mean colour's, keeps copies of
    the state from before, and decides between a rollback and a stop.

    Args:
        mean_colour_mse: the MSE of predicting every training pixel as the mean training colour.
    """

    def __init__(self, mean_colour_mse: float):
        self.mean_colour_mse = mean_colour_mse
        self.mse_ema: float | None = None
        # (step, mse_ema then, a deep copy of the state), oldest first
        self.snapshots: deque[tuple[int, float | None, dict]] = deque(maxlen=2)
        self.rollbacks: list[dict] = []  # {"diverged_at", "resumed_from", "lr_factor"} per rollback
        self.left = False  # whether the smoothed error has been at most LEFT_FRACTION of the mean colour's
        self.recent: deque[float] = deque(maxlen=SNAPSHOT_EVERY)  # the smoothed error of the last steps

    def keep(self, step: int, state_dict: Callable[[], dict]) -> None:
        """Called before each step: every SNAPSHOT_EVERY steps, copies ``state_dict()`` if the
        smoothed error is known and not worse than the mean colour's (the initial state: always)."""
        if step % SNAPSHOT_EVERY or (self.snapshots and self.snapshots[-1][0] == step):  # (resumed from it)
            return
        initial = step == 0 and not self.snapshots
        if initial or self.below(1.0):
            self.snapshots.append((step, self.mse_ema, copy.deepcopy(state_dict())))

    def below(self, fraction: float) -> bool:
        """Whether the smoothed error is known and at most ``fraction`` of the mean colour's."""
        return self.mse_ema is not None and self.mse_ema <= fraction * self.mean_colour_mse

    def observe(self, step: int, mse: float) -> None:
        """Adds one step's MSE (the mean over data-parallel ranks: every rank decides alike) to
        the smoothed error; raises :class:`Diverged` from DIVERGENCE_CHECK_STEP on where it is
        worse than the mean colour's, unless the run has not left it (LEFT_FRACTION) and is still
        falling (LEAVING_FALL)."""
        self.mse_ema = mse if self.mse_ema is None else (1 - MSE_EMA) * self.mse_ema + MSE_EMA * mse
        self.left = self.left or self.below(LEFT_FRACTION)
        before = self.recent[0] if len(self.recent) == self.recent.maxlen else None
        self.recent.append(self.mse_ema)
        if step < DIVERGENCE_CHECK_STEP or self.below(1.0):
            return
        if not self.left and before is not None and self.mse_ema <= LEAVING_FALL * before:
            return
        raise Diverged(step, self.mse_ema)

    def roll_back(self, diverged: Diverged) -> tuple[int, dict]:
        """(the step of the older kept copy, the copy) to resume from at ROLLBACK_LR_FACTOR times
        the learning rate, the smoothed error set back to what it was then (the newer copy is
        dropped: it belongs to the run that diverged); raises TrainingError when MAX_ROLLBACKS have
        not helped or no copy exists."""
        if not self.snapshots or len(self.rollbacks) >= MAX_ROLLBACKS:
            tried = f" after {len(self.rollbacks)} rollbacks at lower learning rates" if self.rollbacks else ""
            raise TrainingError(
                f"training diverged at step {diverged.step}{tried}: the photometric error ({diverged.mse_ema:.4g}) is "
                f"worse than predicting the mean colour ({self.mean_colour_mse:.4g}); the learning rate is probably too high"
            )
        while len(self.snapshots) > 1:
            self.snapshots.pop()
        step, self.mse_ema, state = self.snapshots[0]
        self.left = self.below(LEFT_FRACTION)
        self.recent = deque(maxlen=SNAPSHOT_EVERY)
        self.rollbacks.append(
            {"diverged_at": diverged.step, "resumed_from": step, "lr_factor": ROLLBACK_LR_FACTOR ** (len(self.rollbacks) + 1)}
        )
        return step, copy.deepcopy(state)
