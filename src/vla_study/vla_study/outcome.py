"""How a trial's outcome is counted, in one place for the scorer (trial.trial_row) and the analysis.

- Time: a success's time is its time to success; a failure's is the time limit, whatever made the trial
  end (the participant giving up early is no faster failure).
- Thrown: an object that ended THROWN_M or more from its start was flung, not pushed: the longest push
  the study asks for is 0.15 m, so 0.5 m is more than three times it (the paper protocol's graph run had
  four, 0.60-2.90 m; the next largest 0.49 m). A thrown object is a failure and is also reported apart.
"""
from __future__ import annotations

THROWN_M = 0.5


def trial_time(success: bool, t_success: float | None, time_limit: float) -> float:
    """The row's time: to success, or the time limit for a failure (or a success with no time seen)."""
    return float(t_success) if success and t_success is not None else float(time_limit)


def thrown(displacement_m: float | None) -> bool:
    """Whether an object's displacement (m; None: not measured) means it was thrown."""
    return displacement_m is not None and displacement_m >= THROWN_M
