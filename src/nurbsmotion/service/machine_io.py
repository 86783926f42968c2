"""The machine I/O the daemon drives through the ``io:`` node: e-stop, limit switches, coolant.

- ``estop`` input active (its polarity is the input's ``active_low``; unknown = pressed):
  every axis and the spindle get a quick stop, then are disabled (the master's quick stop
  ends in 'disabled'); a running job ends aborted; no job, MDI or reset starts while it is
  active. Hardware safety stays the STO chain's job: this is the controller's reaction.
- ``limit_<axis>_min`` / ``limit_<axis>_max`` / ``limit_<axis>`` (axis name in lower case,
  e.g. ``limit_x_min``), or any input with ``limit: AXIS`` (``AXIS-`` / ``AXIS+``) in YAML:
  becoming active while a job runs -> that job is aborted with one line naming the input and
  axis. While one is active nothing starts but a jog of that axis away from it (LinuxCNC's
  and grblHAL's way off a switch): away from the end the switch sits at (``_min``: -1,
  ``_max``: +1), or, for a switch whose end is not said, from the direction the axis moved
  when it tripped. A trip happens when the input becomes active, so the jog off is not
  tripped by it and the switch is armed again once it clears.
- M62-M65 P switch the output at bit P (0x6200) when playback reaches their row (M62/M63,
  'with the next motion' in LinuxCNC, and M64/M65, 'at once', alike: the program's order);
- M7 / M8 / M9 switch the coolant output(s) named in service.program_gate.COOLANT_OUTPUTS;
  job end, abort and faults switch every coolant output off.

The node's heartbeat is watched (fieldbus.node_heartbeat, the drives' consumer time): when
it is lost, its inputs are unknown, and an e-stop that cannot be read is an e-stop: the
same reaction, one line naming the node; nothing starts until ``reset`` brought it up again.

Inputs arrive on the network's receive thread (fieldbus.io.IoNode.on_change); the handler
only sends requests (quick stop, abort), never waits.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from nurbsmotion.config import MachineConfig
from nurbsmotion.fieldbus.io import IoNode
from nurbsmotion.config.io import IoSignal, limit_axis_side
from nurbsmotion.log import kv
from nurbsmotion.program import CoolantMode
from nurbsmotion.service.program_gate import COOLANT_OUTPUTS

log = logging.getLogger(__name__)

ESTOP = "estop"
HEARTBEAT = "heartbeat"  # SafetyTrip.input of a lost I/O node


def limit_inputs(config: MachineConfig) -> dict[str, str]:
    """{input name: axis name} of the io inputs that are limit switches of a configured axis."""
    return {name: switch.axis for name, switch in limit_switches(config).items()}


@dataclass(frozen=True)
class LimitSwitch:
    """A limit input of ``axis`` at its ``side`` end: -1 negative (``_min``, ``X-``), +1
    positive (``_max``, ``X+``), 0 not said (``limit_x``, ``limit: X``)."""

    input: str
    axis: str
    side: int


@dataclass(frozen=True)
class AxisMotion:
    """A motion of one axis in machine coordinates: ``direction`` +1 / -1 (a jog)."""

    axis: str
    direction: int

    def text(self) -> str:
        return f"{self.axis}{'+' if self.direction > 0 else '-'}"


def limit_switches(config: MachineConfig) -> dict[str, LimitSwitch]:
    """{input name: LimitSwitch} of the io inputs that are limit switches of a configured axis."""
    if config.io is None:
        return {}
    by_name = {f"limit_{a.name.lower()}{end}": (a.name, side) for a in config.axes
               for end, side in (("", 0), ("_min", -1), ("_max", 1))}
    switches = {}
    for s in config.io.inputs:
        if s.limit:
            switches[s.name] = LimitSwitch(s.name, *limit_axis_side(s.limit))
        elif s.name in by_name:
            switches[s.name] = LimitSwitch(s.name, *by_name[s.name])
    return switches


def coolant_outputs(config: MachineConfig) -> tuple[str, ...]:
    """Every configured output that M7/M8 may switch on (M9 and job end switch them off)."""
    names = {s.name for s in config.io.outputs} if config.io is not None else set()
    return tuple(sorted(names & {n for ns in COOLANT_OUTPUTS.values() for n in ns}))


@dataclass(frozen=True)
class SafetyTrip:
    """What an input asks for: ``estop`` (everything) or a limit of ``axis``; ``message`` is the line."""

    input: str
    axis: str | None
    message: str


class MachineIo:
    """The I/O node as the daemon uses it. ``on_trip(SafetyTrip)`` is called (receive thread)
    when the e-stop or a limit input becomes active; ``moving(axis)`` says which way an axis
    moves now (+1 / -1, 0 at rest or unknown): the end of a switch whose end is not said."""

    def __init__(self, config: MachineConfig, node: IoNode, on_trip: Callable[[SafetyTrip], None],
                 moving: Callable[[str], int] = lambda axis: 0) -> None:
        assert config.io is not None
        self.config = config
        self.node = node
        self.on_trip = on_trip
        self.moving = moving
        self.switches = limit_switches(config)
        self._tripped_side: dict[str, int] = {}  # a switch whose end is not said: the way its axis moved
        self.coolant = coolant_outputs(config)
        self._signals: dict[str, IoSignal] = {s.name: s for s in config.io.inputs}
        node.on_change = self._on_change
        node.on_lost = self._on_lost

    def _describe(self, name: str) -> str:
        signal = self._signals[name]
        low = ", active low" if signal.active_low else ""
        return f"io node {self.config.io.node_id} bit {signal.bit}{low}"  # type: ignore[union-attr]

    def _on_change(self, name: str, active: bool) -> None:
        if not active:
            if name in self.switches:  # cleared: the next activation trips again
                self._tripped_side.pop(name, None)
                log.info(kv("io.limit_armed", input=name, axis=self.switches[name].axis))
            return
        if name == ESTOP:
            self.on_trip(SafetyTrip(name, None, f"e-stop input {name} ({self._describe(name)}) is active: quick stop, "
                                               f"then every drive disabled"))
        elif name in self.switches:
            axis = self.switches[name].axis
            if self.switches[name].side == 0:
                self._tripped_side[name] = self.moving(axis)
            self.on_trip(SafetyTrip(name, axis, f"limit input {name} ({self._describe(name)}) is active: axis {axis}"))

    def _on_lost(self, message: str) -> None:
        """The node's heartbeat is lost: an e-stop that cannot be read is an e-stop."""
        self.on_trip(SafetyTrip(HEARTBEAT, None, f"{message}: its inputs are unknown: quick stop, then every "
                                                 f"drive disabled"))

    def lost_refusal(self) -> str | None:
        """While the node is lost: why nothing starts (reset brings it up again)."""
        if self.node.lost is None:
            return None
        return f"io node {self.node.io.node_id} lost ({self.node.lost}): its inputs are unknown; reset brings it up again"

    def has_estop(self) -> bool:
        return ESTOP in self._signals

    def estop_active(self) -> bool:
        """The e-stop input is active, or not known yet (unknown counts as pressed)."""
        return self.has_estop() and self.node.input(ESTOP) is not False

    def start_refusal(self, jog: AxisMotion | None = None, ignored_axes: frozenset[str] = frozenset()) -> str | None:
        """Why no motion may start now, else None: the e-stop is active, or a limit input is
        and the motion is not ``jog``, a jog of that axis away from the switch. Limit inputs
        of ``ignored_axes`` do not count (a homing with ignore_limits)."""
        if (lost := self.lost_refusal()) is not None:
            return lost
        if self.estop_active():
            return f"e-stop input {ESTOP} ({self._describe(ESTOP)}) is active: release it first"
        for name, switch in self.switches.items():
            if switch.axis not in ignored_axes and self.node.input(name):
                why = self._limit_refusal(switch, jog)
                if why is not None:
                    return why
        return None

    def _limit_refusal(self, switch: LimitSwitch, jog: AxisMotion | None) -> str | None:
        """None when ``jog`` moves ``switch``'s axis away from it; else the one line."""
        side = switch.side or self._tripped_side.get(switch.input, 0)
        on = f"limit input {switch.input} ({self._describe(switch.input)}) is active: axis {switch.axis} is on its " \
             f"limit switch"
        if side == 0:
            return f"{on}, and which end it is is not known (name the input limit_{switch.axis.lower()}_min / _max " \
                   f"or give limit: {switch.axis}- / {switch.axis}+): move the axis off it by hand"
        away = AxisMotion(switch.axis, -side)
        if jog is None or jog.axis != switch.axis:
            return f"{on}: only a jog {away.text()} (away from it) may move"
        if jog.direction == side:
            return f"{on}: jog {jog.text()} moves towards it; jog {away.text()} moves away"
        return None

    def set_coolant(self, mode: CoolantMode) -> dict[str, bool]:
        """M7 / M8 switch their output on (mist and flood add up), M9 every coolant output off;
        the outputs changed, by name."""
        if mode is CoolantMode.OFF:
            states = {name: False for name in self.coolant}
        else:
            name = next(n for n in COOLANT_OUTPUTS[mode] if n in self.coolant)
            states = {name: True}
        self.node.set_outputs(states)
        return states

    def set_output_bit(self, bit: int, on: bool) -> dict[str, bool]:
        """M62-M65 P: the output at ``bit`` on or off (the gate checked it exists)."""
        name = next(s.name for s in self.config.io.outputs if s.bit == bit)  # type: ignore[union-attr]
        self.node.set_outputs({name: on})
        return {name: on}

    def coolant_off(self) -> None:
        """Job end, abort, fault: every coolant output off (logged only if one was on)."""
        if any(self.node.outputs.get(n) for n in self.coolant):
            self.node.set_outputs({n: False for n in self.coolant})
            log.info(kv("io.coolant_off", node=self.config.io.node_id))  # type: ignore[union-attr]

    def coolant_state(self) -> dict[str, bool]:
        """Each coolant mode this machine has (``mist``, ``flood``) and whether its output is on
        now, as the node last reported its outputs (the web console's and ``status``' coolant)."""
        outputs = self.node.outputs
        return {mode.value: any(bool(outputs.get(n)) for n in names if n in self.coolant)
                for mode, names in COOLANT_OUTPUTS.items() if any(n in self.coolant for n in names)}

    def status(self) -> dict[str, object]:
        return {"node": self.config.io.node_id, "inputs": self.node.inputs,  # type: ignore[union-attr]
                "outputs": self.node.outputs, "estop_active": self.estop_active() if self.has_estop() else None,
                "lost": self.node.lost}
