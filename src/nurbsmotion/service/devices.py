"""The machine's devices besides the axes: the spindle drive (``spindle:``) and the I/O node
(``io:``), brought up on the master's network after the axes (service.daemon).

Both are their own nodes, not part of the set-point rows. Their reactions the controller
must act on (an e-stop or limit input, a spindle that stops on its own) go to
``on_trip`` / ``on_spindle_fault``, which the controller sets.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus.io import IoNode
from nurbsmotion.fieldbus.spindle import SpindleDrive
from nurbsmotion.log import kv
from nurbsmotion.service.machine_io import AxisMotion, MachineIo, SafetyTrip
from nurbsmotion.service.motion import BusHost
from nurbsmotion.config.spindle import SpindleConfig

log = logging.getLogger(__name__)


class MachineDevices:
    def __init__(self, config: MachineConfig, link: BusHost) -> None:
        """``link``: the brought-up fieldbus.Master, the bus the devices join."""
        self.config = config
        self.link = link
        self.on_trip: Callable[[SafetyTrip], None] = lambda trip: None
        self.on_spindle_fault: Callable[[str], None] = lambda message: None
        self.axis_direction: Callable[[str], int] = lambda axis: 0  # the way an axis moves now (+1/-1/0)
        network = link.network
        if network is None:
            raise FieldbusError("devices: the master is not connected")
        self.spindle: SpindleDrive | None = None
        self.io: MachineIo | None = None
        if isinstance(config.spindle, SpindleConfig):
            link.receive_from(config.spindle.node_id)
            self.spindle = SpindleDrive(network, config.spindle, on_fault=lambda m: self.on_spindle_fault(m),
                                        master_heartbeat=self.master_heartbeat(),
                                        cycle_period_s=config.cycle_period_s,
                                        sdo_timeout_s=config.bus.sdo_timeout_ms / 1000.0,
                                        cyclic=link.cyclic_velocity, judging_time_s=link.judging_time_s)
        if config.io is not None:
            link.receive_from(config.io.node_id, (0x180 + config.io.node_id,))
            node = IoNode(network, config.io, sdo_timeout_s=config.bus.sdo_timeout_ms / 1000.0,
                          judging_time_s=link.judging_time_s)
            self.io = MachineIo(config, node, on_trip=lambda trip: self.on_trip(trip),
                                moving=lambda axis: self.axis_direction(axis))

    def master_heartbeat(self) -> tuple[int, int] | None:
        """(master node id, consumer ms) for a node's 0x1016:01; None without a master heartbeat."""
        mon = self.config.monitoring
        if not mon.master_heartbeat_ms:
            return None
        return self.config.master.node_id, mon.master_heartbeat_ms * mon.master_heartbeat_consumer_multiple

    def bring_up(self) -> None:
        """I/O node first (an e-stop pressed at start is known before anything turns), then the
        spindle; FieldbusError names node and step."""
        if self.io is not None:
            self._bring_up_io()
        if self.spindle is not None:
            self.spindle.bring_up()

    def _bring_up_io(self) -> None:
        """The io node with the drives' heartbeat times: it produces every heartbeat_producer_ms,
        the master consumes with heartbeat_consumer_ms, and it consumes the master's."""
        assert self.io is not None
        mon = self.config.monitoring
        self.io.node.bring_up(mon.heartbeat_producer_ms, mon.heartbeat_consumer_ms, self.master_heartbeat())
        if self.io.estop_active():
            log.warning(kv("io.estop_active_at_start", node=self.config.io.node_id))  # type: ignore[union-attr]

    def revive_io(self) -> str | None:
        """``reset`` after the io node was lost: bring it up again; the one line why not, or None."""
        if self.io is None or self.io.node.lost is None:
            return None
        try:
            self._bring_up_io()
        except FieldbusError as err:
            return str(err)
        log.info(kv("io.revived", node=self.config.io.node_id))  # type: ignore[union-attr]
        return None

    def start_refusal(self, jog: AxisMotion | None = None, ignored_axes: frozenset[str] = frozenset()) -> str | None:
        """Why motion may not start (e-stop, limit input unless ``jog`` moves off it or its
        axis is in ``ignored_axes``), else None."""
        return self.io.start_refusal(jog, ignored_axes) if self.io is not None else None

    def all_off(self, hard: bool) -> None:
        """Job end (``hard`` False: the spindle decelerates to 0 with its ramp) or abort, fault,
        e-stop (``hard``: quick stop, then disabled); coolant off either way."""
        if self.spindle is not None:
            if hard:
                self.spindle.quick_stop()
                self.spindle.disable()
            elif self.spindle.status().commanded_rpm != 0:
                self.spindle.command_rpm(0)
        if self.io is not None:
            self.io.coolant_off()

    def kept(self) -> dict[str, Any]:
        """What stays on after a job that keeps the devices (record line): spindle rpm, outputs on."""
        out: dict[str, Any] = {}
        if self.spindle is not None:
            out["spindle_rpm"] = self.spindle.status().commanded_rpm
        if self.io is not None:
            out["outputs_on"] = sorted(n for n, on in self.io.node.outputs.items() if on)
        return out

    def ready_for_job(self) -> None:
        """Enable the spindle again if an abort or fault disabled it (target 0)."""
        if self.spindle is not None and not self.spindle.enabled:
            self.spindle.enable()

    def status(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.spindle is not None:
            s = self.spindle.status()
            out["spindle"] = {"node": self.spindle.config.node_id, "commanded_rpm": s.commanded_rpm,
                              "actual_rpm": s.actual_rpm, "at_speed": s.at_speed, "drive_state": s.state,
                              "fault": s.fault}
        if self.io is not None:
            out["io"] = self.io.status()
            out["coolant"] = self.io.coolant_state()
        return out

    def close(self) -> None:
        """Spindle stopped and disabled, coolant off, threads ended (daemon shutdown)."""
        try:
            self.all_off(hard=True)
        except FieldbusError as err:
            log.warning(kv("devices_not_stopped", error=err))
        if self.spindle is not None:
            self.spindle.close()
        if self.io is not None:
            self.io.node.close()


def open_devices(config: MachineConfig, link: BusHost) -> MachineDevices | None:
    """The spindle and I/O node of ``config`` brought up on ``link``'s network (None: neither)."""
    if not isinstance(config.spindle, SpindleConfig) and config.io is None:
        return None
    devices = MachineDevices(config, link)
    try:
        devices.bring_up()
    except BaseException:
        devices.close()
        raise
    return devices
