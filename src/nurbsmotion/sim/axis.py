"""The application of a simulated CiA-402 position drive, without any bus.

It holds the power drive system state, the controlword and mode, the IP / CSP set-points,
the servo model, the following-error monitor and the error state, and advances once per
SYNC. The drive (``drive.py``) feeds it from SDO and PDO and publishes what it reports.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.cia402 import EmcyCode, Mode, State
from nurbsmotion.log import kv
from nurbsmotion.sim import homing, velocity
from nurbsmotion.sim.eds import STANDARD_MODES
from nurbsmotion.sim.recording import SetpointRecorder, SetpointSource, SyncRecorder
from nurbsmotion.sim.servo import ServoModel
from nurbsmotion.sim.statemachine import apply_controlword, quick_stop_stays_active
from nurbsmotion.sim.stats import DriveStats
from nurbsmotion.sim.timing import MissingSetpoint, SyncTiming

log = logging.getLogger("nurbsmotion.sim.drive")

CYCLIC_MODES = (int(Mode.INTERPOLATED_POSITION), int(Mode.CYCLIC_SYNC_POSITION), velocity.MODE_CYCLIC_SYNC_VELOCITY)
SW_SYNCHRONIZED = 1 << 8  # manufacturer specific in CiA 402; sync status as Nanotec's
EMCY_PARAMETER_ERROR = 0x6320  # CiA 301 'parameter error': IP/CSP enabled without a cycle period
EMCY_SYNC_LOSS = 0x8700  # CiA 402 'sync controller'
FE_WINDOW_DISABLED = 0xFFFF_FFFF
ERROR_HISTORY_LENGTH = 8
DEFAULT_CYCLE_S = 1e-3  # servo cycle outside IP/CSP when no cycle period is configured
MAX_EXTRAPOLATED_TICKS = 10_000  # a drive extrapolating longer has long tripped its following error
STATES_WITH_VOLTAGE = (State.SWITCHED_ON, State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE, State.FAULT_REACTION_ACTIVE)


class UnsupportedMode(ValueError):
    """0x6060 written with a mode this drive does not have (not in 0x6502)."""


@dataclass
class AxisParameters:
    """The object-dictionary parameters the per-SYNC step uses (cached by the drive)."""

    cycle_period_s: float = 1e-3  # 0x60C2 (else 0x1006): the IP/CSP cycle; 0 = not configured
    fe_window_counts: int = 10000  # 0x6065; 0xFFFFFFFF disables the monitor
    fe_timeout_ms: int = 20  # 0x6066
    quick_stop_option: int = 2  # 0x605A
    quick_stop_decel_counts_s2: float = 1e7  # 0x6085
    limit_min_counts: int = 0  # 0x607D sub 1; min >= max disables the limits
    limit_max_counts: int = 0  # 0x607D sub 2
    modes: frozenset[int] = STANDARD_MODES  # 0x6502: what 0x6060 accepts
    missing_setpoint: MissingSetpoint = MissingSetpoint.HOLD
    velocity_profile: velocity.VelocityProfile = velocity.VelocityProfile(0.0, 0.0, 0.0, 0.0)  # 0x6083/4, 0x606D/E
    homing_period_s: float = 1e-3  # 0x1006 (else the SYNC interval): the drive's own cycle in homing mode

    def servo_cycle_s(self) -> float:
        """The cycle the servo steps by: the IP/CSP cycle period (never 0 while IP/CSP runs),
        1 ms in other modes when none is configured."""
        return self.cycle_period_s if self.cycle_period_s > 0 else DEFAULT_CYCLE_S

    def within_limits(self, setpoint: int) -> bool:
        """0x607D: min <= set-point <= max (limits disabled while min >= max)."""
        low, high = self.limit_min_counts, self.limit_max_counts
        return low >= high or low <= setpoint <= high


def ticks_to_simulate(missed: int, missing_setpoint: MissingSetpoint, lag_cycles: int) -> int:
    """Of ``missed`` cycles without a SYNC, how many to simulate. Holding, the motor rests
    after the lag line has drained: simulating more changes nothing (a long pause between
    jobs costs no time). Extrapolating moves every tick."""
    if missing_setpoint is MissingSetpoint.HOLD:
        return min(missed, lag_cycles + 2)
    return min(missed, MAX_EXTRAPOLATED_TICKS)


def error_register_bits(code: int) -> int:
    """0x1001 bits for an EMCY code (CiA 301: bit 0 generic, 1 current, 2 voltage,
    3 temperature, 4 communication, 5 device profile, 7 manufacturer)."""
    bits = 0x01
    group = code >> 12
    if group == 0x2:
        bits |= 0x02
    elif group == 0x3:
        bits |= 0x04
    elif group == 0x4:
        bits |= 0x08
    elif code >> 8 in (0x81, 0x82):
        bits |= 0x10
    elif code >> 8 == 0x86:
        bits |= 0x20
    elif code >> 8 == 0xFF:
        bits |= 0x80
    return bits


class Cia402Axis:
    """One CiA-402 axis: state machine, set-points, servo, following error, faults.

    ``emit_emcy(code, error_register)`` is called for every EMCY the drive must send.
    """

    def __init__(
        self,
        servo: ServoModel,
        recorder: SetpointRecorder,
        stats: DriveStats,
        emit_emcy: Callable[[int, int], None],
        name: str,
        mode: int,
        timeline: SyncRecorder | None = None,
    ) -> None:
        self.servo = servo
        self.recorder = recorder
        self.timeline = timeline if timeline is not None else SyncRecorder(enabled=False)
        self.sync_locked = False  # statusword bit 8, set by the drive's SYNC monitor
        self.stats = stats
        self.params = AxisParameters()
        self._emit_emcy = emit_emcy
        self.name = name
        self.home_sensors = homing.HomeSensors()
        self.homing_setup: Callable[[], homing.HomingSetup] = lambda: homing.HomingSetup(0, 0.0, 0.0, 0.0, 0)
        self.home_shift = 0.0  # position actual = raw + home_shift (kept across resets: the motor stays)
        self.reset(mode)

    def reset(self, mode: int) -> None:
        """Power-on / reset node: transitions 0 and 1 to SWITCH ON DISABLED; the motor
        stays where it is."""
        self.state = State.SWITCH_ON_DISABLED
        self.transitions: list[int] = [0, 1]
        self.controlword = 0
        self.mode = self.mode_display = mode
        self.target_position = 0
        self.ip_setpoint = 0
        self.target_velocity = 0
        self._in_window_s = 0.0
        self.error_code = 0
        self.error_register = 0
        self.error_history: list[int] = []
        self._fe_flag = False
        self._fresh_target = self._fresh_ip = False
        self._hold_position()
        self._homing = homing.idle(self.servo.actual, self.home_shift)
        self.position_actual = int(round(self.servo.actual))
        self.refresh_statusword()

    # ------------------------------------------------------------------ written objects
    def set_controlword(self, controlword: int) -> None:
        previous, self.controlword = self.controlword, controlword
        new_state, taken = apply_controlword(self.state, controlword, previous, self.params.quick_stop_option)
        if taken:
            self._change_state(new_state, taken)
        self.refuse_cyclic_without_period()
        self.refresh_statusword()

    def set_mode(self, mode: int) -> None:
        """0x6060; 0x6061 follows at once. Raises UnsupportedMode for a mode not in 0x6502."""
        if mode not in self.params.modes:
            raise UnsupportedMode(mode)
        if mode != self.mode_display:
            self._hold_position()
            self._reset_homing()
            log.info(kv("sim.mode", node=self.name, mode=mode))
        self.mode = self.mode_display = mode
        self.refuse_cyclic_without_period()
        self.refresh_statusword()

    def cycle_period_missing(self) -> bool:
        """IP/CSP needs the cycle period (0x60C2, else 0x1006): without it a real drive cannot
        interpolate between set-points, so it must not run."""
        return self.mode_display in CYCLIC_MODES and self.params.cycle_period_s <= 0

    def refuse_cyclic_without_period(self) -> None:
        """OPERATION ENABLED in IP/CSP with no cycle period configured: fault 0x6320."""
        if self.state is State.OPERATION_ENABLED and self.cycle_period_missing():
            log.warning(kv("sim.no_cycle_period", node=self.name, mode=self.mode_display))
            self.raise_fault(EMCY_PARAMETER_ERROR)

    def set_target_position(self, value: int) -> None:
        """0x607A, the CSP set-point."""
        self.target_position = value
        self._fresh_target = True

    def set_target_velocity(self, value: int) -> None:
        """0x60FF, the PV target / CSV set-point (counts/s)."""
        self.target_velocity = value

    @property
    def velocity_actual(self) -> int:
        """0x606C, counts/s."""
        return int(round(self.servo.velocity_counts_s))

    def set_ip_setpoint(self, value: int) -> None:
        """0x60C1 sub 1, the IP set-point."""
        self.ip_setpoint = value
        self._fresh_ip = True

    # ------------------------------------------------------------------ state machine
    def _change_state(self, new_state: State, taken: list[int]) -> None:
        old = self.state
        self.state = new_state
        self.transitions.extend(taken)
        if old is State.OPERATION_ENABLED or new_state is State.OPERATION_ENABLED:
            self._reset_homing()  # leaving OPERATION ENABLED ends homing; entering needs a new edge
        if new_state is State.OPERATION_ENABLED and old is not State.OPERATION_ENABLED:
            self._hold_position()
        elif new_state is State.QUICK_STOP_ACTIVE and self.params.quick_stop_option == 0:
            self.state = State.SWITCH_ON_DISABLED  # option 0: disable drive function at once
            self.transitions.append(12)
            self._hold_position()
        elif new_state not in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE):
            self._hold_position()
        if 15 in taken:
            self.error_code = 0
            self.error_register = 0
            self._fe_flag = False
            self._emit_emcy(EmcyCode.NO_ERROR, 0)
        log.info(kv("sim.state", node=self.name, state=self.state.name, transitions=taken))

    def _hold_position(self) -> None:
        """Stand still where the motor is until a new set-point comes (one received since
        the last SYNC, whatever its order in the RPDO relative to the controlword)."""
        self.servo.hold(self.servo.actual)
        self._demand = self.servo.actual
        self._demand_step = 0.0  # last set-point step, continued when extrapolating
        self.following_error = 0
        self._fe_cycles = 0

    def _reset_homing(self) -> None:
        """Homing back to 'not started' where the motor is; bit 4 as it is now (only a rising
        edge while OPERATION ENABLED in mode 6 starts homing, CiA 402-2)."""
        self._homing = replace(homing.idle(self.servo.actual, self.home_shift),
                               start_bit=bool(self.controlword & homing.CW_START_HOMING))

    @property
    def homing_state(self) -> homing.HomingState:
        return self._homing

    def setpoint_active(self) -> bool:
        """Statusword bit 12: CSP 'target used' / IP 'interpolation active'."""
        if self.state is not State.OPERATION_ENABLED:
            return False
        if self.mode_display in (Mode.CYCLIC_SYNC_POSITION, velocity.MODE_CYCLIC_SYNC_VELOCITY):
            return True  # CSV: 'target velocity used'
        return self.mode_display == Mode.INTERPOLATED_POSITION and bool(self.controlword & c.CW_ENABLE_IP)

    # ------------------------------------------------------------------ per SYNC
    def run_missed_cycles(self, timing: SyncTiming) -> None:
        """The cycles that ran without a SYNC before this one (``timing.missed_ticks``), each
        holding or extrapolating; called before the SYNC's RPDO data takes effect."""
        if self.state is not State.OPERATION_ENABLED:  # the quick-stop ramp advances per SYNC only
            return
        for _ in range(ticks_to_simulate(timing.missed_ticks, self.params.missing_setpoint, self.servo.lag_cycles)):
            self._run_cycle(False)

    def step(self, sync_index: int, sync_counter: int, timing: SyncTiming | None = None) -> None:
        """This SYNC's cycle (after ``run_missed_cycles``): take the new set-point (recorded),
        move one cycle, check the following error."""
        if timing is None:
            timing = SyncTiming(0.0, self.params.cycle_period_s, 0)
        csp = self.mode_display == Mode.CYCLIC_SYNC_POSITION
        fresh = self._fresh_target if csp else self._fresh_ip
        self._fresh_target = self._fresh_ip = False
        source, demand = self._run_cycle(fresh)
        if source is SetpointSource.FRESH:  # recorded even if this cycle's following error faults the drive
            self.recorder.append(sync_index, self.mode_display, demand, self.position_actual, sync_counter,
                                 _ns(timing.time_s))
        self.timeline.append(sync_index, _ns(timing.time_s), _ns(timing.interval_s), timing.missed_ticks, int(source),
                             demand, self.position_actual, self.following_error, sync_counter)
        self.refresh_statusword()

    def _run_cycle(self, fresh: bool) -> tuple[SetpointSource, int]:
        """One cycle of the drive's position loop (one cycle period: the drive interpolates
        each set-point step over its cycle, however late the next SYNC comes); returns where
        its set-point came from and the demand it followed (counts)."""
        inactive = SetpointSource.INACTIVE
        if self.state is State.OPERATION_ENABLED and self.mode_display == homing.MODE_HOMING:
            self.stats.setpoints_ignored += fresh
            self._homing_cycle()
            return inactive, int(round(self._demand))
        if self.state is State.OPERATION_ENABLED and self.mode_display in velocity.VELOCITY_MODES:
            self.stats.setpoints_ignored += fresh
            if self.cycle_period_missing():
                self.raise_fault(EMCY_PARAMETER_ERROR)
            else:
                self._velocity_cycle()
            return inactive, int(round(self._demand))
        if self.state is State.OPERATION_ENABLED:
            if self.cycle_period_missing():
                self.raise_fault(EMCY_PARAMETER_ERROR)
                return inactive, int(round(self._demand))
            if not self.setpoint_active():
                self.stats.setpoints_ignored += fresh
                self._move(self._demand)
                self._check_following_error()
                return inactive, int(round(self._demand))
            source, demand = self._cycle_demand(fresh)
            if not self.params.within_limits(int(round(demand))):
                self.stats.setpoints_refused += 1
                self.raise_fault(EmcyCode.SOFTWARE_LIMIT)
                return inactive, int(round(self._demand))
            self._demand_step = demand - self._demand if source is SetpointSource.FRESH else self._demand_step
            self._demand = demand
            self._move(demand)
            if source is SetpointSource.FRESH:
                self.stats.setpoints_applied += 1
            else:
                self.stats.setpoints_missing += 1
            self._check_following_error()
            return source, int(round(demand))
        if self.state is State.QUICK_STOP_ACTIVE:  # the ramp advances per SYNC only (docs/sim.md)
            stopped = self.servo.ramp_down(self.params.quick_stop_decel_counts_s2, self.params.servo_cycle_s())
            self._demand = self.servo.actual
            self.position_actual = int(round(self.servo.actual))
            if stopped and not quick_stop_stays_active(self.params.quick_stop_option):
                self._change_state(State.SWITCH_ON_DISABLED, [12])
        else:
            self.stats.setpoints_ignored += fresh
        return inactive, int(round(self._demand))

    def _velocity_cycle(self) -> None:
        """One cycle of profile velocity (3) or cyclic synchronous velocity (9), ``sim.velocity``."""
        state = velocity.VelocityState(self.servo.actual, self.servo.velocity_counts_s, self._in_window_s)
        if self.mode_display == velocity.MODE_PROFILE_VELOCITY:
            state = velocity.profile_velocity_tick(state, self.target_velocity, bool(self.controlword & c.CW_HALT),
                                                   self.params.velocity_profile, self.params.servo_cycle_s())
        else:
            state = velocity.cyclic_velocity_tick(state, self.target_velocity, self.params.servo_cycle_s())
        self._in_window_s = state.in_window_s
        self.servo.hold(state.position)
        self.servo.velocity_counts_s = state.velocity_counts_s
        self._demand = self.servo.actual
        self.following_error = 0
        self.position_actual = int(round(self.servo.actual))

    def _homing_cycle(self) -> None:
        """One drive cycle of homing mode (``sim.homing.homing_tick``): the motor stands where
        homing puts it (no lag, following error 0), at the homing speed for a quick stop."""
        self._homing = homing.homing_tick(self._homing, self.homing_setup(), self.home_sensors,
                                          bool(self.controlword & homing.CW_START_HOMING),
                                          self.params.homing_period_s)
        self.home_shift = self._homing.shift
        self.servo.hold(self._homing.position)
        self.servo.velocity_counts_s = self._homing.speed_counts_s
        self._demand = self.servo.actual
        self.following_error = 0
        self.position_actual = int(round(self.servo.actual))

    def _cycle_demand(self, fresh: bool) -> tuple[SetpointSource, float]:
        """The new set-point, else the last one held or its step continued (drive setting)."""
        if fresh:
            csp = self.mode_display == Mode.CYCLIC_SYNC_POSITION
            return SetpointSource.FRESH, float(self.target_position if csp else self.ip_setpoint)
        if self.params.missing_setpoint is MissingSetpoint.EXTRAPOLATE:
            return SetpointSource.EXTRAPOLATED, self._demand + self._demand_step
        return SetpointSource.HELD, self._demand

    def _move(self, demand: float) -> None:
        self.position_actual = int(round(self.servo.step(demand, self.params.servo_cycle_s())))

    def _check_following_error(self) -> None:
        """0x60F4 = demand - actual; fault 0x8611 when |e| > 0x6065 for longer than 0x6066 ms
        (the drive counts its own cycles: each one outside the window counts one period)."""
        error = int(round(self._demand - self.servo.actual))
        self.following_error = error
        window = self.params.fe_window_counts
        if window == FE_WINDOW_DISABLED or abs(error) <= window:
            self._fe_cycles = 0
            return
        self._fe_cycles += 1
        if self._fe_cycles * self.params.cycle_period_s * 1000.0 > self.params.fe_timeout_ms:
            self.raise_fault(EmcyCode.FOLLOWING_ERROR, following_error=True)

    def refresh_statusword(self) -> None:
        """Recompute the statusword (after every change; the drive calls it after one it
        made, e.g. sync lock)."""
        word = c.STATUSWORD_OF_STATE[self.state] | c.SW_REMOTE
        if self.state in STATES_WITH_VOLTAGE:
            word |= c.SW_VOLTAGE_ENABLED
        if self.setpoint_active():
            word |= c.SW_IP_ACTIVE
        if self.state is State.OPERATION_ENABLED and self.mode_display == homing.MODE_HOMING:
            word |= self._homing.statusword_bits  # bits 10, 12, 13: CiA 402-2 homing table
        if self.state is State.OPERATION_ENABLED and self.mode_display == velocity.MODE_PROFILE_VELOCITY:
            state = velocity.VelocityState(self.servo.actual, self.servo.velocity_counts_s, self._in_window_s)
            word |= c.SW_TARGET_REACHED if state.target_reached(self.params.velocity_profile) else 0
        if self._fe_flag:
            word |= c.SW_FOLLOWING_ERROR
        if self.sync_locked:
            word |= SW_SYNCHRONIZED
        self.statusword = word

    # ------------------------------------------------------------------ faults
    def raise_fault(self, code: int, following_error: bool = False) -> None:
        """Transitions 13 and 14: fault reaction (motor held where it is), then FAULT; EMCY.
        ``following_error`` also sets statusword bit 13."""
        self.error_code = code
        self.error_register |= error_register_bits(code)
        self.error_history.insert(0, code)
        del self.error_history[ERROR_HISTORY_LENGTH:]
        self._fe_flag = self._fe_flag or following_error
        if self.state is not State.FAULT:
            error_at_fault = self.following_error
            self.state = State.FAULT
            self.transitions.extend([13, 14])
            self._hold_position()
            self._reset_homing()
            self.following_error = error_at_fault  # 0x60F4 keeps the error that caused the fault
        self.refresh_statusword()
        self._emit_emcy(code, self.error_register)
        log.warning(kv("sim.fault", node=self.name, code=f"0x{code:04X}"))


def _ns(time_s: float) -> int:
    """Seconds -> integer ns for the recordings (-1 for 'none', e.g. no interval yet)."""
    return int(round(time_s * 1e9)) if time_s == time_s else -1
