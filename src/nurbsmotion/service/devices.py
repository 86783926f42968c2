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
from nurbsmotion.service.machine_io import MachineIo, SafetyTrip
from nurbsmotion.spindle_config import SpindleConfig

log = logging.getLogger(__name__)


class MachineDevices:
    def __init__(self, config: MachineConfig, link: Any) -> None:
        """``link``: the brought-up fieldbus.Master (its ``network``, ``receive_from``, ``quick_stop``)."""
        self.config = config
        self.link = link
        self.on_trip: Callable[[SafetyTrip], None] = lambda trip: None
        self.on_spindle_fault: Callable[[str], None] = lambda message: None
        network = getattr(link, "network", None)
        if network is None:
            raise FieldbusError("devices: the master is not connected")
        self.spindle: SpindleDrive | None = None
        self.io: MachineIo | None = None
        if isinstance(config.spindle, SpindleConfig):
            link.receive_from(config.spindle.node_id)
            mon = config.monitoring
            watch = (config.master.node_id, mon.master_heartbeat_ms * mon.master_heartbeat_consumer_multiple) \
                if mon.master_heartbeat_ms else None
            self.spindle = SpindleDrive(network, config.spindle, on_fault=lambda m: self.on_spindle_fault(m),
                                        master_heartbeat=watch, cycle_period_s=config.cycle_period_s,
                                        sdo_timeout_s=config.bus.sdo_timeout_ms / 1000.0)
        if config.io is not None:
            link.receive_from(config.io.node_id, (0x180 + config.io.node_id,))
            node = IoNode(network, config.io, sdo_timeout_s=config.bus.sdo_timeout_ms / 1000.0)
            self.io = MachineIo(config, node, on_trip=lambda trip: self.on_trip(trip))

    def bring_up(self) -> None:
        """I/O node first (an e-stop pressed at start is known before anything turns), then the
        spindle; FieldbusError names node and step."""
        if self.io is not None:
            self.io.node.bring_up(self.config.monitoring.heartbeat_producer_ms)
            if self.io.estop_active():
                log.warning(kv("io.estop_active_at_start", node=self.config.io.node_id))  # type: ignore[union-attr]
        if self.spindle is not None:
            self.spindle.bring_up()

    def start_refusal(self) -> str | None:
        """Why motion may not start (e-stop, limit input), else None."""
        return self.io.start_refusal() if self.io is not None else None

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


def open_devices(config: MachineConfig, link: Any) -> MachineDevices | None:
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
