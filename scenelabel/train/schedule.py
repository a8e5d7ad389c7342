"""How far a training run has gone: the fraction its schedules follow (the learning rate's decay,
the terms that start or end at a fraction of the run).

A run ends at ``train.steps`` or at ``train.time_budget`` seconds, whichever comes first. The
fraction follows the step count, so that a run that ends on its step count gives the same build
for the same seed however fast its steps ran, until the budget is going to end the run first; from
then on it also follows the clock, in a straight line to 1 at the budget's end, so a run the
budget stops still ends its schedules.

The first steps run slower than the rest (the density grid is still full), so the time budget's
fraction spent leads the step fraction early even in runs that end on their step count: a schedule
that always took the larger of the two followed the wall clock there, and the same seeded build did
not repeat (docs/models.md). Hence the budget is judged only from JUDGE_FROM of the run on, on the
rate of the last RATE_WINDOW steps, and found short only when the steps left need SHORT_BY times the
time left at that rate: the rate goes on rising long after the warm-up.

Orchestration only: plain numbers in and out; nothing here knows what a step does.
"""

from __future__ import annotations

from collections import deque

__all__ = ["JUDGE_FROM", "RATE_WINDOW", "SHORT_BY", "RunSchedule", "fraction_of_run"]

JUDGE_FROM = 0.2
"""The budget is judged once the step fraction or the budget's fraction spent reaches this. A
default build's first steps (the grid's warm-up, every cell occupied, then a grid still mostly full)
run several times slower than its later ones (a probe of studio-3x3 outside the repo's scripts): a
rate measured in the first tenth of the run would take builds that end well inside their budget for
ones the budget ends."""

RATE_WINDOW = 100
"""Steps over which the rate that the judgement projects is measured."""

SHORT_BY = 1.5
"""The budget is found short when the steps left, at the last RATE_WINDOW steps' rate, would take
more than this many times the time left. A default build's steps keep speeding up as its density
grid empties: in docs/suite_8d7c844.md, 10 of the 12 builds without depth were found short (at 11-30 %
of the run, 30-49 s in) and still ended their 2000 steps in 123-137 s of their 150 s; at 1 they
followed the clock though their steps ended them. A run at a steady rate that needs 1.2 times its
budget is found short at 60 % of it, one that needs 1.4 times or more from JUDGE_FROM on."""


def fraction_of_run(step: int, steps: int, elapsed: float, budget: float | None, anchor: tuple[float, float] | None) -> float:
    """The run's fraction done, in [0, 1].

    ``step / steps`` while ``anchor`` is None; with ``anchor = (start, then)`` (the fraction and the
    elapsed seconds when the budget was found to end the run first) the larger of that and
    ``start + (1 - start) * (elapsed - then) / (budget - then)``, which reaches 1 at the budget's
    end. ``budget - then`` is floored at 1e-9 s, so an anchor at the budget's end gives a finite
    fraction (1 from any later time on), not a division by 0.
    """
    by_steps = step / max(steps, 1)
    if anchor is None or not budget:
        return min(by_steps, 1.0)
    start, then = anchor
    by_time = start + (1.0 - start) * (elapsed - then) / max(budget - then, 1e-9)
    return min(max(by_steps, by_time), 1.0)


class RunSchedule:
    """The run's fraction done (:func:`fraction_of_run`) and the record it needs: the anchor, set once
    the budget is going to end the run first (saved with the training state), and the elapsed time of
    the last RATE_WINDOW steps (not saved: a resumed run measures its rate afresh)."""

    def __init__(self, anchor: tuple[float, float] | None = None):
        self.anchor = None if anchor is None else (float(anchor[0]), float(anchor[1]))
        self.recent: deque[tuple[int, float]] = deque(maxlen=RATE_WINDOW + 1)

    def fraction(self, step: int, steps: int, elapsed: float, budget: float | None) -> float:
        return fraction_of_run(step, steps, elapsed, budget, self.anchor)

    def observe(self, step: int, steps: int, elapsed: float, budget: float | None) -> bool:
        """After each step: anchor the schedules to the clock once ``steps - step`` more steps at the
        rate of the last RATE_WINDOW ones would take more than SHORT_BY times the budget's time left.
        Judged only from JUDGE_FROM of the run on. Returns whether this call set the anchor."""
        self.recent.append((step, elapsed))
        if self.anchor is not None or not budget or len(self.recent) < 2:
            return False
        if max(step / max(steps, 1), elapsed / budget) < JUDGE_FROM:
            return False
        first_step, first_time = self.recent[0]
        rate = (step - first_step) / max(elapsed - first_time, 1e-9)  # steps/s; 1e-9 s: a clock that did not move
        if (steps - step) / max(rate, 1e-9) <= SHORT_BY * (budget - elapsed):
            return False
        self.anchor = (self.fraction(step, steps, elapsed, budget), elapsed)
        return True

    def resume(self, snapshot: dict, elapsed: float) -> None:
        """After a rollback to ``snapshot`` (:meth:`snapshot`'s output) at ``elapsed`` seconds: the
        time spent stays spent. A run that was following the clock goes on from the fraction resumed, in
        a straight line to 1 at the budget's end; one that was not follows the steps again, and is judged
        afresh."""
        self.anchor = None if snapshot["anchor"] is None else (snapshot["fraction"], elapsed)
        self.recent.clear()

    def snapshot(self, step: int, steps: int, elapsed: float, budget: float | None) -> dict:
        """What :meth:`resume` needs of the state a rollback may go back to."""
        return {"anchor": self.anchor, "fraction": self.fraction(step, steps, elapsed, budget)}
