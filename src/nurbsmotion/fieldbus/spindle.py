"""The master's side of the spindle drive: a CiA-402 drive in a velocity mode, by SDO.

The spindle is its own node, not part of the set-point rows: nothing about it is per cycle
in profile velocity mode (3), where the drive ramps to 0x60FF with 0x6083/0x6084 and sets
statusword bit 10 'target reached' (CiA 402-2 6.3). So everything here is canopen's SDO
client on a RemoteNode, as its authors intend, plus a monitor thread that reads 0x6041
and 0x606C every ``POLL_S`` (status, faults, 'at speed').

In cyclic synchronous velocity mode (9) the drive follows 0x60FF at once. With the master's
``cyclic`` slot (fieldbus.cyclic_velocity, the daemon's case) bring-up maps 0x60FF into the
drive's RPDO1 (synchronous, transmission type 1) and the master sends it with every SYNC,
ramped per cycle with ``accel_rpm_s``; without one (a SpindleDrive on its own) the monitor
ramps it by SDO in steps of ``POLL_S`` (the drive holds the last value between steps, as
CiA 402-2 'csv' drives do when no new set-point comes). At speed once the ramp has ended
and |0x606C - 0x60FF| <= ``CSV_WINDOW`` of the target (bit 10 has no meaning in csv).

Bring-up (NMT pre-operational): 0x6502 has the mode's bit (when the drive has 0x6502),
0x6060 = mode, 0x6083/0x6084 = accel (counts/s²), 0x60FF = 0, 0x60C2 / 0x1006 = the cycle
period (where the drive has them), 0x1016:01 = the master's
heartbeat (as for the axes: a dead daemon stops the spindle), NMT start, fault reset if
in FAULT, then SHUTDOWN, SWITCH ON, ENABLE OPERATION until 0x6041 says OPERATION ENABLED.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can
import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from nurbsmotion.can import cia402 as c
from nurbsmotion.can import drive_od
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus.bringup import sdo_failure
from nurbsmotion.fieldbus.cyclic_velocity import CyclicVelocity
from nurbsmotion.fieldbus.pdo import interpolation_period
from nurbsmotion.fieldbus.sdo_arrival import judge_on_arrival
from nurbsmotion.log import kv
from nurbsmotion.config.spindle import (MONITOR_POLL_S, PROFILE_ACCELERATION, PROFILE_DECELERATION, SUPPORTED_DRIVE_MODES,
                                        TARGET_VELOCITY, VELOCITY_ACTUAL, SpindleConfig, SpindleMode)

log = logging.getLogger(__name__)

POLL_S = MONITOR_POLL_S  # monitor period: 0x6041 / 0x606C reads, csv ramp steps
CSV_WINDOW = 0.02  # csv 'at speed': within 2 % of the target (or 1 count/s)
SDO_TIMEOUT_S = 0.5
LOST_AFTER = 3  # monitor polls in a row without an SDO answer before the spindle counts as lost
ENABLE_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class SpindleStatus:
    commanded_rpm: float  # signed: + = M3 (cw), - = M4 (ccw)
    actual_rpm: float | None  # from 0x606C (None before the first read)
    at_speed: bool
    state: str  # CiA 402 state of the last statusword
    statusword: int | None
    fault: str | None  # why the spindle stopped on its own (None: it did not)


def ramp_step(current: float, target: float, max_change: float) -> float:
    """The next csv set-point: ``current`` moved towards ``target`` by at most ``max_change``."""
    change = target - current
    return target if abs(change) <= max_change else current + (max_change if change > 0 else -max_change)


def csv_at_speed(actual_counts_s: float, target_counts_s: float) -> bool:
    """|v_actual - v_target| <= CSV_WINDOW · |v_target| (at least 1 count/s)."""
    return abs(actual_counts_s - target_counts_s) <= max(1.0, CSV_WINDOW * abs(target_counts_s))


class SpindleDrive:
    """The spindle on a connected ``canopen.Network`` (the master's).

    ``on_fault(message)`` is called from the monitor thread once when the drive leaves
    OPERATION ENABLED on its own (fault, quick stop, lost answers); keep it short.
    """

    def __init__(self, network: canopen.Network, config: SpindleConfig,
                 on_fault: Callable[[str], None] | None = None, master_heartbeat: tuple[int, int] | None = None,
                 cycle_period_s: float | None = None, sdo_timeout_s: float = SDO_TIMEOUT_S,
                 cyclic: CyclicVelocity | None = None,
                 judging_time_s: Callable[[], float] = time.perf_counter) -> None:
        """``master_heartbeat``: (master node id, consumer time ms) for 0x1016:01, so the drive
        stops on its own when the daemon dies (as the axes do); None writes nothing.
        ``cycle_period_s``: the SYNC period, written to 0x60C2 and 0x1006 where the drive has
        them (a csv drive steps by it; a drive that takes 0x60C2's default would ramp wrong).
        ``cyclic``: the master's per-SYNC 0x60FF slot (csv only; module docstring).
        ``judging_time_s``: now on the master's arrival timeline (``Master.judging_time_s``):
        SDO answers time out on it and are matched to their request, as the axes' are
        (fieldbus.sdo_arrival; the default, the process clock, still matches them)."""
        assert config.od is not None  # loaded with the configuration
        self.config = config
        self.cyclic = cyclic if config.mode is SpindleMode.CSV else None
        self.cycle_period_s = cycle_period_s
        self.master_heartbeat = master_heartbeat
        self.on_fault = on_fault
        self.node = canopen.RemoteNode(config.node_id, config.od)
        self.node.sdo.RESPONSE_TIMEOUT = sdo_timeout_s
        judge_on_arrival(self.node.sdo, judging_time_s)
        network.add_node(self.node)
        self._sdo_lock = threading.Lock()  # one SDO transfer at a time (monitor vs commands)
        self._lock = threading.Lock()
        self._target_counts_s = 0
        self._sent_counts_s = 0.0  # csv: the ramp's last 0x60FF
        self._statusword: int | None = None
        self._actual_counts_s: int | None = None
        self._fault: str | None = None
        self._off = False  # quick stop / disable asked for: leaving OPERATION ENABLED is no fault
        self._stop = threading.Event()
        self._monitor: threading.Thread | None = None

    # ------------------------------------------------------------------ bring-up
    def bring_up(self) -> None:
        """Configure and enable the drive (module docstring); FieldbusError names node and step."""
        cfg = self.config
        self.node.nmt.send_command(c.NmtCommand.PRE_OPERATIONAL)
        if drive_od.find(cfg.od, SUPPORTED_DRIVE_MODES) is not None:  # type: ignore[arg-type]
            modes = int(self._sdo("read 0x6502", lambda: self.node.sdo[SUPPORTED_DRIVE_MODES].raw))
            if not modes >> cfg.mode.supported_bit & 1:
                raise self._error("check mode", f"0x6502 = 0x{modes:08X}: the drive has no {cfg.mode.value} "
                                  f"(mode {cfg.mode.number})")
        self._write("set mode 0x6060", c.MODES_OF_OPERATION, cfg.mode.number)
        if cfg.mode is SpindleMode.PROFILE_VELOCITY:
            self._write("set acceleration 0x6083", PROFILE_ACCELERATION, cfg.accel_counts_s2)
            if drive_od.find(cfg.od, PROFILE_DECELERATION) is not None:  # type: ignore[arg-type]
                self._write("set deceleration 0x6084", PROFILE_DECELERATION, cfg.accel_counts_s2)
        self._write("zero target velocity", TARGET_VELOCITY, 0)
        if self.cycle_period_s:
            self._write_cycle_period(self.cycle_period_s)
        if self.cyclic is not None:
            self._map_cyclic_rpdo(self.cyclic)
        if self.master_heartbeat is not None and drive_od.find(cfg.od, c.CONSUMER_HEARTBEAT_TIME, 1) is not None:  # type: ignore[arg-type]
            master, consumer_ms = self.master_heartbeat
            self._sdo("watch the master's heartbeat",  # 0x1016:01 = node << 16 | ms (CiA 301 §7.5.2.29)
                      lambda: setattr(self.node.sdo[c.CONSUMER_HEARTBEAT_TIME][1], "raw", master << 16 | consumer_ms))
        self.node.nmt.send_command(c.NmtCommand.START)
        self._enable()
        self._stop.clear()
        self._monitor = threading.Thread(target=self._watch, name=f"spindle-node{cfg.node_id}", daemon=True)
        self._monitor.start()
        log.info(kv("spindle.ready", node=cfg.node_id, mode=cfg.mode.value, accel_counts_s2=cfg.accel_counts_s2))

    def _write_cycle_period(self, period_s: float) -> None:
        """0x60C2:01/02 = period as value·10^exponent s (the axes' scaling), 0x1006 = period µs."""
        od = self.config.od
        exponent_var = drive_od.find(od, c.IP_TIME_PERIOD, 2)  # type: ignore[arg-type]
        if exponent_var is not None:
            value, exponent = interpolation_period(period_s, None if exponent_var.writable else exponent_var.default)
            self._write("set cycle period 0x60C2", c.IP_TIME_PERIOD, value, 1)
            if exponent_var.writable:
                self._write("set cycle period 0x60C2", c.IP_TIME_PERIOD, exponent, 2)
        if drive_od.find(od, c.COMM_CYCLE_PERIOD) is not None:  # type: ignore[arg-type]
            self._write("set cycle period 0x1006", c.COMM_CYCLE_PERIOD, round(period_s * 1e6))

    def _map_cyclic_rpdo(self, cyclic: CyclicVelocity) -> None:
        """RPDO1 = 0x60FF, COB-ID of the master's slot, transmission type 1 (acted on at the next
        SYNC), through canopen's PdoMap from the drive's EDS (disable, count 0, entry, count,
        enable: CiA 301 §7.5.2.36); the slot carries 0 until the first command."""
        cyclic.request(0, at_once=True)
        try:
            rpdo = self.node.rpdo[1]
            rpdo.clear()
            rpdo.cob_id = cyclic.cob_id
            rpdo.trans_type = 1
            rpdo.add_variable(TARGET_VELOCITY)
            rpdo.enabled = True
        except (KeyError, ValueError) as err:
            raise self._error("map 0x60FF into RPDO1", f"the EDS has no RPDO1 for it ({err})") from None
        self._sdo("map 0x60FF into RPDO1", rpdo.save)

    def _enable(self) -> None:
        """Fault reset if needed, then SHUTDOWN -> SWITCH ON -> ENABLE OPERATION (CiA 402 state machine)."""
        state = c.state_of_statusword(self._read_statusword("read statusword"))
        if state in (c.State.FAULT, c.State.FAULT_REACTION_ACTIVE):
            self._write("fault reset", c.CONTROLWORD, c.Controlword.FAULT_RESET)
        steps = ((c.Controlword.SHUTDOWN, c.State.READY_TO_SWITCH_ON), (c.Controlword.SWITCH_ON, c.State.SWITCHED_ON),
                 (c.Controlword.ENABLE_OPERATION, c.State.OPERATION_ENABLED))
        for command, wanted in steps:
            self._write(f"controlword {command.name}", c.CONTROLWORD, int(command))
            deadline = time.monotonic() + ENABLE_TIMEOUT_S
            while (state := c.state_of_statusword(self._read_statusword("enable"))) is not wanted:
                if time.monotonic() > deadline:
                    raise self._error("enable", f"{command.name} did not reach {wanted.value} within "
                                      f"{ENABLE_TIMEOUT_S:g} s (state {state.value if state else '?'})")
                time.sleep(POLL_S / 4)
        with self._lock:
            self._fault, self._off = None, False

    # ------------------------------------------------------------------ commands
    def command_rpm(self, rpm: float) -> None:
        """Run at ``rpm`` (signed: + cw / M3, - ccw / M4; 0 stops with the deceleration)."""
        counts_s = self.config.counts_s(rpm)
        with self._lock:
            self._target_counts_s = counts_s
        if self.config.mode is SpindleMode.PROFILE_VELOCITY:
            self._write("target velocity 0x60FF", TARGET_VELOCITY, counts_s)
        elif self.cyclic is not None:
            self.cyclic.request(counts_s)
        log.info(kv("spindle.command", node=self.config.node_id, rpm=rpm, counts_s=counts_s))

    def quick_stop(self) -> None:
        """Controlword QUICK STOP (the drive's own quick-stop ramp 0x6085), target 0."""
        with self._lock:
            self._target_counts_s = 0
            self._sent_counts_s = 0.0
            self._off = True
        if self.cyclic is not None:
            self.cyclic.request(0, at_once=True)
        self._write_quietly(c.CONTROLWORD, int(c.Controlword.QUICK_STOP))
        self._write_quietly(TARGET_VELOCITY, 0)

    def disable(self, settle_s: float = 2.0) -> None:
        """Once 0x606C reads 0 (the quick-stop ramp ended) or after ``settle_s``: controlword
        DISABLE VOLTAGE, the one command that leaves every state, QUICK STOP ACTIVE included,
        for SWITCH ON DISABLED (CiA 402 transitions 7, 9, 10, 12: no torque)."""
        with self._lock:
            self._off = True
        deadline = time.monotonic() + settle_s
        while time.monotonic() < deadline and self._read_actual_quietly() not in (0, None):
            time.sleep(POLL_S / 2)
        self._write_quietly(c.CONTROLWORD, int(c.Controlword.DISABLE_VOLTAGE))

    @property
    def enabled(self) -> bool:
        """Not quick-stopped or disabled by :meth:`quick_stop` / :meth:`disable`, and no fault."""
        with self._lock:
            return not self._off and self._fault is None

    def enable(self) -> None:
        """Enable again after a quick stop, disable or fault (target 0)."""
        with self._lock:
            self._target_counts_s = 0
            self._sent_counts_s = 0.0
        if self.cyclic is not None:
            self.cyclic.request(0, at_once=True)
        self._write("zero target velocity", TARGET_VELOCITY, 0)
        self._enable()

    # ------------------------------------------------------------------ state
    def at_speed(self) -> bool:
        """Mode 3: OPERATION ENABLED and statusword bit 10; mode 9: ramp ended and 0x606C
        within CSV_WINDOW of the target."""
        with self._lock:
            sw, actual, target, sent = self._statusword, self._actual_counts_s, self._target_counts_s, self._sent_counts_s
        if sw is None or c.state_of_statusword(sw) is not c.State.OPERATION_ENABLED:
            return False
        if self.config.mode is SpindleMode.PROFILE_VELOCITY:
            return bool(sw & c.SW_TARGET_REACHED) and actual is not None and csv_at_speed(actual, target)
        ramped = self.cyclic.ramp_done() and self.cyclic.target_counts_s == target if self.cyclic is not None \
            else sent == target
        return ramped and actual is not None and csv_at_speed(actual, target)

    def status(self) -> SpindleStatus:
        with self._lock:
            sw, actual, target, fault = self._statusword, self._actual_counts_s, self._target_counts_s, self._fault
        state = c.state_of_statusword(sw) if sw is not None else None
        return SpindleStatus(round(self.config.rpm(target), 3), None if actual is None else round(self.config.rpm(actual), 3),
                             self.at_speed(), state.value if state else "unknown", sw, fault)

    def wait_at_speed(self, timeout_s: float, cancelled: Callable[[], bool] = lambda: False) -> bool:
        """Wait for :meth:`at_speed` (True) or the timeout / a fault / ``cancelled()`` (False)."""
        deadline = time.monotonic() + timeout_s
        time.sleep(2 * POLL_S)  # the monitor's reads after the command, not a bit 10 from before it
        while time.monotonic() < deadline and not cancelled():
            if self.at_speed():
                return True
            if self.status().fault is not None:
                return False
            time.sleep(POLL_S / 2)
        return False

    def close(self) -> None:
        self._stop.set()
        if self._monitor is not None:
            self._monitor.join(1.0)
            self._monitor = None

    # ------------------------------------------------------------------ monitor thread
    def _watch(self) -> None:
        """Poll 0x6041 / 0x606C; LOST_AFTER unanswered polls in a row (a late answer is not a
        lost drive: a drive process inside UML lags by hundreds of ms) report the spindle lost."""
        missed = 0
        while not self._stop.wait(POLL_S):
            try:
                sw = int(self._sdo("monitor", lambda: self.node.sdo[c.STATUSWORD].raw))
                actual = int(self._sdo("monitor", lambda: self.node.sdo[VELOCITY_ACTUAL].raw))
            except FieldbusError as err:
                missed += 1
                if missed >= LOST_AFTER:
                    self._lost(f"no answer from the spindle drive in {missed} polls ({err})")
                continue
            missed = 0
            with self._lock:
                self._statusword, self._actual_counts_s = sw, actual
            state = c.state_of_statusword(sw)
            if state is not c.State.OPERATION_ENABLED:
                self._lost(f"spindle drive left OPERATION ENABLED: {state.value if state else '?'} "
                           f"(statusword 0x{sw:04X})")
            elif self.config.mode is SpindleMode.CSV and self.cyclic is None:
                self._csv_step()

    def _csv_step(self) -> None:
        with self._lock:
            target, sent = self._target_counts_s, self._sent_counts_s
        if sent == target:
            return
        step = ramp_step(sent, target, self.config.accel_counts_s2 * POLL_S)
        self._write_quietly(TARGET_VELOCITY, int(round(step)))
        with self._lock:
            self._sent_counts_s = step if step != target else float(target)

    def _lost(self, message: str) -> None:
        with self._lock:
            if self._fault is not None or self._off:
                return
            self._fault = message
        log.warning(kv("spindle.fault", node=self.config.node_id, reason=message))
        if self.on_fault is not None:
            self.on_fault(message)

    # ------------------------------------------------------------------ SDO
    def _read_statusword(self, step: str) -> int:
        sw = int(self._sdo(step, lambda: self.node.sdo[c.STATUSWORD].raw))
        with self._lock:
            self._statusword = sw
        return sw

    def _read_actual_quietly(self) -> int | None:
        try:
            return int(self._sdo("read 0x606C", lambda: self.node.sdo[VELOCITY_ACTUAL].raw))
        except FieldbusError:
            return None

    def _write(self, step: str, index: int, value: int, subindex: int | None = None) -> None:
        if subindex is None:
            self._sdo(step, lambda: setattr(self.node.sdo[index], "raw", value))
        else:
            self._sdo(step, lambda: setattr(self.node.sdo[index][subindex], "raw", value))

    def _write_quietly(self, index: int, value: int) -> None:
        """A write on the way down (stop, disable): a failure is logged, not raised."""
        try:
            self._write(f"write 0x{index:04X}", index, value)
        except FieldbusError as err:
            log.warning(kv("spindle.write_failed", node=self.config.node_id, index=f"0x{index:04X}", error=err))

    def _error(self, step: str, message: str) -> FieldbusError:
        return FieldbusError(f"node {self.config.node_id}: spindle step '{step}': {message}")

    def _sdo(self, step: str, action: Callable[[], Any]) -> Any:
        try:
            with self._sdo_lock:
                return action()
        except (SdoAbortedError, SdoCommunicationError) as err:
            raise self._error(step, sdo_failure(err)) from None
        except (can.CanError, OSError) as err:  # the bus is closed or refuses the frame
            raise self._error(step, f"cannot send ({err})") from None
