"""The master's connection: the CAN bus, canopen's Network on it, the receive thread and the
traffic record.

On SocketCAN the bus is the batched one (nurbsmotion.can.socketcan_batch: fewer system calls
per cycle) and canopen's notifier reads a batch of frames per wake-up; the drives' answers
(TPDOs, EMCY, heartbeats) go straight into the master's Feedback arrays. With the kernel
queue (fieldbus.bcm_queue) a receive filter keeps our own SYNC and RPDOs off the raw socket.
"""

from __future__ import annotations

import logging
from pathlib import Path
import can
from can.interfaces.socketcan import SocketcanBus
import canopen

from nurbsmotion.can import cia402 as c
from nurbsmotion.can.arrival_clock import socket_pending
from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError
from nurbsmotion.fieldbus import bringup
from nurbsmotion.fieldbus.bringup_plan import DrivePlan, Field, PdoFrame
from nurbsmotion.fieldbus.drive_state import CW_QUICK_STOP
from nurbsmotion.fieldbus.feedback import Callback, Feedback
from nurbsmotion.fieldbus.traffic import TrafficLog
from nurbsmotion.fieldbus.writer import RpdoSlot
from nurbsmotion.log import kv
from nurbsmotion.runtime import set_thread_realtime
from nurbsmotion.can.socketcan_batch import BatchedSocketcanBus, BatchNotifier

log = logging.getLogger(__name__)

# The receive thread sleeps this share of a cycle after each batch, so the drives' answers to
# one SYNC are read in one wake-up instead of one each (socketcan_batch.BatchNotifier).
RECEIVE_HOLDOFF_SHARE = 0.5


def uses_kernel_queue(sync_source: str, bus: object) -> bool:
    """'auto': any SocketCAN bus, python-can's or a subclass (the master's own is the
    batched one, nurbsmotion.can.socketcan_batch; comparing the class name sent the daemon on
    socketcan to the loop writer)."""
    if sync_source == "auto":
        return isinstance(bus, SocketcanBus)
    return sync_source == "kernel"


def tpdo_callback(fb: Feedback, i: int, frame: PdoFrame) -> Callback:
    """The decoder of one TPDO of axis i's layout (statusword + position, or split)."""
    if frame.fields == (Field.STATUSWORD, Field.POSITION):
        return fb.tpdo1_callback(i)
    if frame.fields == (Field.FOLLOWING_ERROR,):
        return fb.tpdo2_callback(i)
    return fb.split_tpdo_callback(i, frame.dlc, frame.fmt.unpack_from, frame.fields == (Field.STATUSWORD,))


def log_sent_frames(network: canopen.Network, traffic: TrafficLog) -> None:
    """Also log the frames canopen sends (NMT, SDO) in the traffic record."""
    plain = network.send_message

    def send_message(can_id: int, data: bytes, remote: bool = False) -> None:
        plain(can_id, data, remote)
        traffic.sent(can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False))

    network.send_message = send_message  # type: ignore[method-assign]


class BusConnection:
    """Bus, Network and traffic record of one master (module docstring). ``bus``: an open bus
    to use (not closed here), None opens ``config.bus``."""

    def __init__(self, config: MachineConfig, plans: list[DrivePlan], fb: Feedback, bootup: bringup.BootupWatch,
                 bus: can.BusABC | None, sync_source: str, traffic_path: str | None, sdo_timeout_s: float,
                 rt_priority: int | None) -> None:
        self.config = config
        self.plans = plans
        self.fb = fb
        self.bootup = bootup
        self.bus = bus
        self.own_bus = bus is None
        self.sync_source = sync_source
        self.node_ids = [a.node_id for a in config.axes]
        self.network: canopen.Network | None = None
        self.trails: list[bringup.SdoTrail] = []  # per axis after open(): its SDO access, named in errors
        self.traffic: TrafficLog | None = None  # the log while it records (the cycle loop's fast check)
        self._traffic_path = traffic_path
        self._traffic_log: TrafficLog | None = None
        self._sdo_timeout_s = sdo_timeout_s
        self._rt_priority = rt_priority
        self._extra_receive_ids: list[int] = []  # receive_from(): the spindle's and I/O node's frames

    def kernel_queue(self) -> bool:
        return uses_kernel_queue(self.sync_source, self.bus)

    def open(self) -> None:
        """Open the bus (if not given), start canopen's notifier and the feedback callbacks."""
        if self.network is not None:
            return
        if self.bus is None:
            bus_cfg = self.config.bus
            try:
                self.bus = BatchedSocketcanBus(channel=bus_cfg.channel) if bus_cfg.interface == "socketcan" else \
                    can.Bus(interface=bus_cfg.interface, channel=bus_cfg.channel, bitrate=bus_cfg.bitrate)
            except (can.CanError, OSError, ValueError, ImportError) as err:
                raise FieldbusError(f"bus {bus_cfg.interface}:{bus_cfg.channel}: cannot open ({err})") from None
        bus = self.bus
        network = canopen.Network(bus)
        self._traffic_log = TrafficLog(self._traffic_path)  # paused without a path
        read_time = (lambda: bus.read_perf_s) if isinstance(bus, BatchedSocketcanBus) else None
        listeners: list[can.Listener] = [*network.listeners, self._traffic_log,
                                         self.fb.watch_reception(socket_pending(bus), read_time)]
        network.listeners = listeners  # type: ignore[assignment]  # canopen annotates its own listener only
        log_sent_frames(network, self._traffic_log)
        self.traffic = self._traffic_log if self._traffic_path else None
        # canopen's connect() with the bus given only starts python-can's Notifier; ours reads
        # a batch of frames per wake-up on SocketCAN (socketcan_batch: the per-cycle TPDOs)
        network.notifier = BatchNotifier(bus, listeners, network.NOTIFIER_CYCLE,
                                         on_thread_start=self._raise_receive_thread_priority,
                                         holdoff_s=RECEIVE_HOLDOFF_SHARE * self.config.cycle_period_s)
        self.trails = []
        for i, (axis, plan) in enumerate(zip(self.config.axes, self.plans)):
            assert axis.od is not None  # loaded with the configuration
            node, trail = bringup.open_node(network, axis.node_id, axis.od, self._sdo_timeout_s, self.fb.judging_time_s)
            self.trails.append(trail)
            for frame in plan.layout.tpdos:
                network.subscribe(frame.cob_id, tpdo_callback(self.fb, i, frame))
            node.emcy.add_callback(self.fb.emcy_callback(i))
            network.subscribe(c.COB_HEARTBEAT + axis.node_id, self._heartbeat_callback(i))
        self.network = network

    def _heartbeat_callback(self, i: int) -> Callback:
        node_id = self.node_ids[i]
        return self.fb.heartbeat_callback(i, lambda state: self.bootup.heard(node_id, state))

    def _raise_receive_thread_priority(self) -> None:
        """Run canopen's receive thread SCHED_FIFO just below the cycle thread: a normal-priority
        thread preempted while it holds the GIL would stall the cycle thread (priority inversion)."""
        if self._rt_priority is not None:
            set_thread_realtime(self._rt_priority - 1)

    def receive_from(self, node_id: int, cob_ids: tuple[int, ...] = ()) -> None:
        """Also accept another node's EMCY, SDO answers, heartbeat and ``cob_ids`` (its TPDOs)."""
        self._extra_receive_ids += [c.COB_EMCY + node_id, c.COB_SDO_TX + node_id, c.COB_HEARTBEAT + node_id, *cob_ids]
        self.filter_received()

    def record_traffic(self, path: str | Path | None) -> None:
        """Record every frame into ``path`` from now on (candump .log, .asc, ... by extension),
        closing the previous file; None stops recording."""
        if self._traffic_log is None:
            raise FieldbusError("record_traffic: connect() first")
        if path is None:
            self.traffic = None
            self._traffic_log.switch(None)
        else:
            self._traffic_log.switch(path)
            self.traffic = self._traffic_log
        self.filter_received()

    def log_cycle(self, msgs: list[can.Message]) -> None:
        """The loop writer's frames of one cycle into the traffic record (while it records)."""
        traffic = self.traffic
        if traffic is not None:
            for msg in msgs:
                traffic.sent(msg)

    def filter_received(self) -> None:
        """With the kernel queue our own SYNC and RPDOs come back to our raw socket (the BCM is
        another socket): 4 frames a cycle of receive work for nothing. Accept only what the
        drives send (EMCY, TPDO1/2, SDO answers, heartbeat) unless the traffic is recorded."""
        if self.bus is None or not self.kernel_queue():
            return
        if self.traffic is not None:
            self.bus.set_filters(None)
            return
        ids = [base + node for node in self.node_ids for base in (c.COB_EMCY, c.COB_SDO_TX, c.COB_HEARTBEAT)]
        ids += [frame.cob_id for plan in self.plans for frame in plan.layout.tpdos] + self._extra_receive_ids
        self.bus.set_filters([{"can_id": can_id, "can_mask": 0x7FF, "extended": False} for can_id in ids])

    def close(self) -> None:
        """NMT STOP to every axis, the notifier and the traffic record stopped, the bus closed (if ours)."""
        network = self.network
        if network is not None:
            for node_id in self.node_ids:
                try:
                    network[node_id].nmt.send_command(c.NmtCommand.STOP)
                except (can.CanError, OSError, KeyError):
                    pass
            if network.notifier is not None:
                network.notifier.stop(2.0)
                self._log_reception(network.notifier)
            self.network = None
        self.traffic = None
        if self._traffic_log is not None:
            self._traffic_log.stop()
            self._traffic_log = None
        if self.own_bus and self.bus is not None:
            self.bus.shutdown()
            self.bus = None


    def _log_reception(self, notifier: object) -> None:
        """One line on how the receive thread read the bus (batched SocketCAN only)."""
        bus = self.bus
        if isinstance(bus, BatchedSocketcanBus) and isinstance(notifier, BatchNotifier) and bus.lag.wakeups:
            log.info(kv("master.rx", **bus.lag.figures(), thread_cpu_s=round(notifier.thread_cpu_s, 3)))


def send_quick_stop(bus: can.BusABC | None, rpdos: list[RpdoSlot], setpoints: list[int]) -> None:
    """Quick-stop controlword in every axis' RPDO, sent now (the cycle loop failed)."""
    if bus is None:
        return
    for can_id, dlc, i, pack in rpdos:
        try:
            data = bytearray(dlc)
            pack(data, CW_QUICK_STOP, setpoints[i])
            bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        except (can.CanError, OSError):
            pass
