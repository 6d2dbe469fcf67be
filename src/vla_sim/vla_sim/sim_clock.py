"""Real-time pacing of the simulation (plain Python, no ROS).

The bridge's sim loop is a timer. On every tick `SimPacer.units_due` says how many whole state
periods ("units": 1 / state_rate of simulated time, each a fixed number of physics steps) to advance
so that simulated time follows `real_time_factor` x wall time. Advancing whole periods makes each
tick publish exactly one joint state at real time whatever the timer's jitter (the count is rounded,
so a tick early or late by less than half a period still advances one). A late tick catches up by
at most `max_burst` units at once (a burst of publications would overflow subscribers' queues); if
the simulation falls behind by more than `max_lag`, it re-anchors (simulated time slips) and counts
it. A factor of 0 runs as fast as possible: a fixed chunk of simulated time per tick.
"""
from __future__ import annotations

import math


class SimPacer:
    """How much simulated time each tick of the sim loop advances."""

    def __init__(self, unit: float, real_time_factor: float, *, max_lag: float = 0.1,
                 chunk: float = 0.01, min_period: float = 0.001):
        if not (unit > 0 and math.isfinite(unit)):
            raise ValueError(f"unit must be a positive period in seconds, got {unit!r}")
        if not (real_time_factor >= 0 and math.isfinite(real_time_factor)):
            raise ValueError(f"real_time_factor must be >= 0, got {real_time_factor!r}")
        self.unit = float(unit)
        self.rtf = float(real_time_factor)
        self.min_period = float(min_period)
        self.max_lag_units = max(1, round(max_lag / unit))     # behind by more: re-anchor
        self.chunk_units = max(1, round(chunk / unit))         # units per tick when rtf == 0
        nominal = 1 if self.rtf == 0 else max(1, round(self.timer_period() * self.rtf / unit))
        self.max_burst = 2 * nominal + 1                       # most units one tick may advance
        self._anchor_wall: float | None = None
        self._anchor_sim = 0.0
        self.lag_events = 0                                    # times the sim fell behind

    def timer_period(self) -> float:
        """Wall period of the tick timer: one unit of simulated time at the factor, not below
        min_period (ticks then advance several units); 0 (back to back) when as fast as possible."""
        if self.rtf == 0.0:
            return 0.0
        return max(self.unit / self.rtf, self.min_period)

    def start(self, wall_now: float, sim_now: float = 0.0) -> None:
        self._anchor_wall, self._anchor_sim = wall_now, sim_now

    def units_due(self, wall_now: float, sim_now: float) -> int:
        """Whole units to advance now, from wall time `wall_now` and simulated time `sim_now`."""
        if self.rtf == 0.0:
            return self.chunk_units
        if self._anchor_wall is None:
            self.start(wall_now, sim_now)
        target = self._anchor_sim + (wall_now - self._anchor_wall) * self.rtf
        behind = (target - sim_now) / self.unit
        if behind > self.max_lag_units:                        # cannot keep up: drop the backlog
            self.lag_events += 1
            self.start(wall_now, sim_now)
            return 1
        return min(self.max_burst, max(0, int(math.floor(behind + 0.5))))
