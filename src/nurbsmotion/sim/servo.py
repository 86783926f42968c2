"""The servo model of a simulated drive: the motor follows the demand position with a lag.

Per SYNC cycle k (period T):
    delayed_k = demand_{k - lag_cycles}
    actual_k  = actual_{k-1} + clamp(delayed_k - actual_{k-1}, -v_max*T, +v_max*T)
    following error (0x60F4) e_k = demand_k - actual_k
A stalled motor (fault injection) keeps ``actual`` fixed. Quick stop ramps the velocity down
with the quick-stop deceleration a: v_k = sign(v_{k-1}) * max(|v_{k-1}| - a*T, 0).
"""

from __future__ import annotations

import collections
import math


class ServoModel:
    """Position loop of one axis, advanced once per SYNC."""

    def __init__(self, lag_cycles: int = 1, max_velocity_counts_s: float = math.inf) -> None:
        if lag_cycles < 0:
            raise ValueError("lag_cycles must be >= 0")
        if not max_velocity_counts_s > 0:
            raise ValueError("max_velocity_counts_s must be > 0")
        self.lag_cycles = lag_cycles
        self.max_velocity_counts_s = float(max_velocity_counts_s)
        self.actual = 0.0
        self.velocity_counts_s = 0.0
        self.stalled = False
        self._delay: collections.deque[float] = collections.deque(maxlen=lag_cycles + 1)
        self.hold(0.0)

    def hold(self, position: float) -> None:
        """Stand still at ``position`` (power-on, enable, disable): the lag line is refilled."""
        self.actual = float(position)
        self.velocity_counts_s = 0.0
        self._delay.clear()
        self._delay.extend([self.actual] * (self.lag_cycles + 1))

    def step(self, demand: float, period_s: float) -> float:
        """Advance one cycle towards ``demand``; returns the new actual position."""
        self._delay.append(demand)
        if self.stalled:
            self.velocity_counts_s = 0.0
            return self.actual
        max_step = self.max_velocity_counts_s * period_s
        delta = self._delay[0] - self.actual
        if delta > max_step:
            delta = max_step
        elif delta < -max_step:
            delta = -max_step
        self.actual += delta
        self.velocity_counts_s = delta / period_s if period_s > 0 else 0.0
        return self.actual

    def ramp_down(self, deceleration_counts_s2: float, period_s: float) -> bool:
        """One quick-stop cycle; True once the motor stands still (the lag line is refilled)."""
        speed = abs(self.velocity_counts_s) - deceleration_counts_s2 * period_s
        if speed <= 0 or self.stalled:
            self.hold(self.actual)
            return True
        self.velocity_counts_s = math.copysign(speed, self.velocity_counts_s)
        self.actual += self.velocity_counts_s * period_s
        return False
