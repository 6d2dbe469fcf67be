"""Contact slowing (issue 20 item 5): measured external torque -> speed factor per joint, no ROS.

A held stick drove the hand into a loaf until the robot's reflex (87-249 Nm on joint 2). The real arm
estimates the external torque on each joint (libfranka's tau_ext_hat_filtered); MuJoCo gives it as
the constraint forces on the arm's joints (`PandaSim.external_torque`). The thresholds are fractions
of `reflex`, the per-joint torque at which the robot's own reflex fires (the safety filter's reflex
table: tau_max for the simulated arm, whose reflex fires there; on a real arm the collision
thresholds libfranka configures, `upper_torque_thresholds`, 12-20 Nm, far below tau_max). From
`slow` x reflex on, a joint commanded further into the torque is slowed linearly, and it stops at
`stop` x reflex, well before the reflex at 1 x. A command that eases the torque is never slowed, so
the operator can always back out. The safety filter (`safety.py`) applies the factors to its target;
this module only judges.

The torque on one joint also rises when other joints push the hand into something: the demo's box
push loaded joint 6 (wrist) to its reflex while joints 2 and 4 drove the hand against the table. For
one contact point the external torque is J_c^T F, so the contact point moves into the obstacle
exactly when the external power sum(tau_i v_i) = F . (J_c v) is negative. So, past `slow` on any
joint, a command with negative external power is slowed as a whole by that joint's factor; one that
backs out of the contact (power >= 0) is not.

A contact bounces: a full stick into a loaf made the measured torque swing between 2 and 20 Nm at
about 50 Hz (the hand hitting, rebounding, hitting again). Judged on each sample, the slowing let go
between the hits, the speed came back, and the next hit was harder: with a real arm's collision
thresholds as the simulated reflex, 5 of 10 held-stick holds on bread and the soda can ended in a
reflex. So the rule judges `ContactMemory`'s torque: the peak of each joint's recent torque, which
follows a rise at once and lets go with a time constant of `CONTACT_RELEASE` (0 reflexes in the same
10 holds).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

CONTACT_SLOW = 0.3  # external torque / reflex torque from which motion into it slows
CONTACT_STOP = 0.7  # ... and at which it stops (the robot's reflex is at 1.0)
CONTACT_RELEASE = 0.25  # s: time constant with which the judged torque falls after a peak


class ContactMemory:
    """The torque the contact rule judges: per joint, the measured torque when it is at least the
    decayed peak, else that peak decaying by exp(-dt / release). A rise counts at once; a fall only
    gradually, so a bouncing contact keeps the arm slowed between its hits."""

    def __init__(self, release: float = CONTACT_RELEASE):
        if not (math.isfinite(release) and release > 0.0):
            raise ValueError(f"contact memory: release={release!r} must be a finite time > 0")
        self.release = float(release)
        self._held: list[float] | None = None
        self._dt, self._k = math.nan, 1.0       # the last dt and its decay factor

    def update(self, tau_ext, dt: float) -> list[float] | None:
        """Feed one measurement (Nm per joint) taken `dt` s after the last; returns the judged torques,
        or None when `tau_ext` is unusable (nothing is remembered from it)."""
        try:   # a non-finite value is not a measurement: unknown (NaN)
            tau = [t if math.isfinite(t) else math.nan for t in map(float, tau_ext)]
        except (TypeError, ValueError):
            return None
        held = self._held
        if held is None or len(held) != len(tau):
            self._held = tau
            return tau
        if dt != self._dt:                  # the filter's period: the same every call
            self._dt, self._k = dt, math.exp(-max(dt, 0.0) / self.release)
        k = self._k
        # NaN on either side fails the comparison: a fresh measurement replaces an unknown one.
        self._held = [t if not abs(t) < abs(h) * k else h * k for t, h in zip(tau, held)]
        return self._held

    def clear(self) -> None:
        self._held = None


def contact_scales(target: Sequence[float], tau_ext, reflex: Sequence[float],
                   slow: float = CONTACT_SLOW, stop: float = CONTACT_STOP) -> dict[int, float]:
    """{joint: speed factor in [0, 1)} for the joints whose `target` velocity pushes against an external
    torque past `slow` x `reflex` (the joint's reflex torque, Nm; 0 from `stop` x reflex on); {} when
    none does, or when `tau_ext` is unusable (not a finite number per joint): a missing measurement
    changes nothing."""
    try:
        tau = [float(x) for x in tau_ext]
    except (TypeError, ValueError):
        return {}
    if len(tau) != len(reflex) or len(target) != len(reflex):
        return {}
    out: dict[int, float] = {}
    power, worst = 0.0, 0.0
    for i, (v, t, tm) in enumerate(zip(target, tau, reflex)):
        ratio = abs(t) / tm
        if not ratio == ratio:                                # NaN: no measurement for this joint
            continue
        power += v * t
        worst = max(worst, ratio)
        if ratio > slow and v * t < 0.0:                     # moving against what pushes back
            out[i] = _factor(ratio, slow, stop)
    if worst > slow and power < 0.0:                         # the hand as a whole pushed into it
        whole = _factor(worst, slow, stop)
        for i, v in enumerate(target):
            if v != 0.0:
                out[i] = min(out.get(i, 1.0), whole)
    return out


def _factor(ratio: float, slow: float, stop: float) -> float:
    return 0.0 if ratio >= stop else (stop - ratio) / (stop - slow)
