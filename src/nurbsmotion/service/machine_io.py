"""The machine I/O the daemon drives through the ``io:`` node: e-stop, limit switches, coolant.

- ``estop`` input active (its polarity is the input's ``active_low``; unknown = pressed):
  every axis and the spindle get a quick stop, then are disabled (the master's quick stop
  ends in 'disabled'); a running job ends aborted; no job, MDI or reset starts while it is
  active. Hardware safety stays the STO chain's job: this is the controller's reaction.
- ``limit_<axis>_min`` / ``limit_<axis>_max`` / ``limit_<axis>`` (axis name in lower case,
  e.g. ``limit_x_min``), or any input with ``limit: AXIS`` in YAML: active while a job runs -> that job is aborted with one line naming
  the input and axis; no job starts while one is active.
- M62-M65 P switch the output at bit P (0x6200) when playback reaches their row (M62/M63,
  'with the next motion' in LinuxCNC, and M64/M65, 'at once', alike: the program's order);
- M7 / M8 / M9 switch the coolant output(s) named in service.program_gate.COOLANT_OUTPUTS;
  job end, abort and faults switch every coolant output off.

Inputs arrive on the network's receive thread (fieldbus.io.IoNode.on_change); the handler
only sends requests (quick stop, abort), never waits.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from nurbsmotion.config import MachineConfig
from nurbsmotion.fieldbus.io import IoNode
from nurbsmotion.io_config import IoSignal
from nurbsmotion.log import kv
from nurbsmotion.program import CoolantMode
from nurbsmotion.service.program_gate import COOLANT_OUTPUTS

log = logging.getLogger(__name__)

ESTOP = "estop"


def limit_inputs(config: MachineConfig) -> dict[str, str]:
    """{input name: axis name} of the io inputs that are limit switches of a configured axis."""
    if config.io is None:
        return {}
    by_name = {f"limit_{a.name.lower()}{end}": a.name for a in config.axes for end in ("", "_min", "_max")}
    return {s.name: s.limit or by_name[s.name] for s in config.io.inputs if s.limit or s.name in by_name}


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
    when the e-stop or a limit input becomes active."""

    def __init__(self, config: MachineConfig, node: IoNode, on_trip: Callable[[SafetyTrip], None]) -> None:
        assert config.io is not None
        self.config = config
        self.node = node
        self.on_trip = on_trip
        self.limits = limit_inputs(config)
        self.coolant = coolant_outputs(config)
        self._signals: dict[str, IoSignal] = {s.name: s for s in config.io.inputs}
        node.on_change = self._on_change

    def _describe(self, name: str) -> str:
        signal = self._signals[name]
        low = ", active low" if signal.active_low else ""
        return f"io node {self.config.io.node_id} bit {signal.bit}{low}"  # type: ignore[union-attr]

    def _on_change(self, name: str, active: bool) -> None:
        if not active:
            return
        if name == ESTOP:
            self.on_trip(SafetyTrip(name, None, f"e-stop input {name} ({self._describe(name)}) is active: quick stop, "
                                               f"then every drive disabled"))
        elif name in self.limits:
            axis = self.limits[name]
            self.on_trip(SafetyTrip(name, axis, f"limit input {name} ({self._describe(name)}) is active: axis {axis}"))

    def has_estop(self) -> bool:
        return ESTOP in self._signals

    def estop_active(self) -> bool:
        """The e-stop input is active, or not known yet (unknown counts as pressed)."""
        return self.has_estop() and self.node.input(ESTOP) is not False

    def start_refusal(self) -> str | None:
        """Why no motion may start now (e-stop or a limit input active), else None."""
        if self.estop_active():
            return f"e-stop input {ESTOP} ({self._describe(ESTOP)}) is active: release it first"
        for name, axis in self.limits.items():
            if self.node.input(name):
                return f"limit input {name} ({self._describe(name)}) is active: axis {axis} is on its limit switch"
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

    def status(self) -> dict[str, object]:
        return {"node": self.config.io.node_id, "inputs": self.node.inputs,  # type: ignore[union-attr]
                "outputs": self.node.outputs, "estop_active": self.estop_active() if self.has_estop() else None}
