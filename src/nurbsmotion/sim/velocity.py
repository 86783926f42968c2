"""Velocity modes of the simulated drive (a spindle): profile velocity (3) and cyclic
synchronous velocity (9), CiA 402-2, as pure per-cycle functions.

Profile velocity: the drive ramps towards the target velocity 0x60FF (0 while controlword
bit 8 'halt' is set) with the profile acceleration 0x6083 while |v| grows and the profile
deceleration 0x6084 while it shrinks (also when the sign changes):
    v_k = v_{k-1} + clamp(v_target - v_{k-1}, ±a·T),  x_k = x_{k-1} + (v_{k-1} + v_k)·T/2
Statusword bit 10 'target reached': |v - v_target| <= velocity window 0x606D for at least
the velocity window time 0x606E (ms) (CiA 402-2 6.3 / 0x606D, 0x606E).

Cyclic synchronous velocity: the master gives 0x60FF every SYNC and the drive follows it in
that cycle (its own velocity loop is not modelled): v_k = 0x60FF, same position integral.
Statusword bit 12 is 'target velocity used' while OPERATION ENABLED.

Velocities in counts/s (the packaged EDS has no factor group), accelerations in counts/s².
"""

from __future__ import annotations

from dataclasses import dataclass, replace

MODE_PROFILE_VELOCITY = 3
MODE_CYCLIC_SYNC_VELOCITY = 9
VELOCITY_MODES = (MODE_PROFILE_VELOCITY, MODE_CYCLIC_SYNC_VELOCITY)
TARGET_VELOCITY = 0x60FF
VELOCITY_ACTUAL = 0x606C
PROFILE_ACCELERATION = 0x6083
PROFILE_DECELERATION = 0x6084
VELOCITY_WINDOW = 0x606D
VELOCITY_WINDOW_TIME = 0x606E
# 0x6502 bits (CiA 402-2) and the objects a drive needs for each velocity mode
SUPPORTED_MODE_BITS = {MODE_PROFILE_VELOCITY: 2, MODE_CYCLIC_SYNC_VELOCITY: 8}
# (0x6084 missing: 0x6083 also decelerates, as Technosoft's EDS has it; 0x606D/0x606E
# missing: window 0 for 0 ms, 'reached' once v equals the target, as in Maxon's EPOS4 DCF)
REQUIRED_OBJECTS = {
    MODE_PROFILE_VELOCITY: (TARGET_VELOCITY, VELOCITY_ACTUAL, PROFILE_ACCELERATION),
    MODE_CYCLIC_SYNC_VELOCITY: (TARGET_VELOCITY, VELOCITY_ACTUAL),
}


@dataclass(frozen=True)
class VelocityProfile:
    """The drive's profile velocity objects (counts/s², counts/s, ms)."""

    accel_counts_s2: float  # 0x6083
    decel_counts_s2: float  # 0x6084
    window_counts_s: float  # 0x606D
    window_time_ms: float  # 0x606E


@dataclass(frozen=True)
class VelocityState:
    position: float  # counts (0x6064 before rounding)
    velocity_counts_s: float = 0.0  # 0x606C before rounding
    in_window_s: float = 0.0  # how long |v - target| has stayed within 0x606D

    def target_reached(self, profile: VelocityProfile) -> bool:
        """Statusword bit 10 in profile velocity mode."""
        return self.in_window_s * 1000.0 >= profile.window_time_ms - 1e-9


def profile_velocity_tick(state: VelocityState, target_counts_s: float, halt: bool, profile: VelocityProfile,
                          period_s: float) -> VelocityState:
    """One drive cycle of profile velocity mode (halt: ramp to 0 with 0x6084)."""
    target = 0.0 if halt else target_counts_s
    v = state.velocity_counts_s
    slowing = abs(target) < abs(v) or target * v < 0
    max_change = (profile.decel_counts_s2 if slowing else profile.accel_counts_s2) * period_s
    change = target - v
    new_v = target if abs(change) <= max_change else v + (max_change if change > 0 else -max_change)
    within = abs(new_v - target) <= profile.window_counts_s
    in_window = state.in_window_s + period_s if within else 0.0
    return _moved(state, new_v, period_s, in_window)


def cyclic_velocity_tick(state: VelocityState, target_counts_s: float, period_s: float) -> VelocityState:
    """One cycle of cyclic synchronous velocity mode: the new velocity is the set-point."""
    return _moved(state, float(target_counts_s), period_s, 0.0)


def _moved(state: VelocityState, new_v: float, period_s: float, in_window_s: float) -> VelocityState:
    position = state.position + (state.velocity_counts_s + new_v) * period_s / 2.0
    return replace(state, position=position, velocity_counts_s=new_v, in_window_s=in_window_s)
