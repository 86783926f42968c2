"""CAN bus load of the cyclic traffic, checked before any frame is sent.

Worst-case length of a standard (11-bit id) data frame with ``n`` data bytes (ISO 11898-1):
47 + 8n fixed bits (SOF, id, RTR, IDE, r0, DLC, data, CRC, delimiters, ACK, EOF, 3 bits
inter-frame space) plus one stuff bit per 4 bits of the 34 + 8n stuffed bits after the
first: ``floor((33 + 8n) / 4)``. n = 8 gives 135 bits, n = 0 gives 55 bits.
"""

from __future__ import annotations

from dataclasses import dataclass

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import InputError
from nurbsmotion.config.spindle import MONITOR_POLL_S, SpindleConfig, SpindleMode

SYNC_DLC = 0
RPDO_DLC = 6  # controlword u16 + set-point i32
TPDO1_DLC = 6  # statusword u16 + position actual i32
TPDO2_DLC = 4  # following error actual i32
HEARTBEAT_DLC = 1
CSV_VELOCITY_DLC = 4  # the csv spindle's 0x60FF i32 in its RPDO, every SYNC (fieldbus.cyclic_velocity)
SDO_DLC = 8
SPINDLE_POLL_FRAMES = 4  # fieldbus.spindle's monitor: 0x6041 and 0x606C read by SDO (request + answer each)


def frame_bits(dlc: int) -> int:
    """Worst-case bits on the wire of a standard data frame with ``dlc`` data bytes."""
    if not 0 <= dlc <= 8:
        raise ValueError(f"dlc must be 0..8, got {dlc}")
    return 47 + 8 * dlc + (33 + 8 * dlc) // 4


@dataclass(frozen=True)
class BusLoad:
    """Bits per cycle of the cyclic traffic and the resulting fraction of the bitrate."""

    bits_per_cycle: float
    load: float  # 0..1 (may exceed 1)
    n_axes: int
    cycle_period_s: float
    bitrate: int
    following_error_tpdo: bool
    other_nodes: int = 0  # spindle drive, I/O node


@dataclass(frozen=True)
class OtherNodesTraffic:
    """What a spindle drive and an I/O node add to the axes' cyclic traffic."""

    nodes: int = 0  # each produces a heartbeat
    rpdo_dlcs: tuple[int, ...] = ()  # frames every SYNC (the csv spindle's 0x60FF)
    sdo_frames_per_s: float = 0.0  # the spindle's SDO monitor


def cyclic_bus_load(n_axes: int, cycle_period_s: float, bitrate: int, following_error_tpdo: bool = False,
                    heartbeat_period_s: float | None = None, others: OtherNodesTraffic = OtherNodesTraffic()) -> BusLoad:
    """Load = (SYNC + n·(RPDO + TPDO1 [+ TPDO2]) + the other nodes' RPDOs + heartbeats and the
    spindle's SDO monitor per cycle) bits / (bitrate · T)."""
    per_axis = frame_bits(RPDO_DLC) + frame_bits(TPDO1_DLC)
    if following_error_tpdo:
        per_axis += frame_bits(TPDO2_DLC)
    bits: float = frame_bits(SYNC_DLC) + n_axes * per_axis + sum(frame_bits(dlc) for dlc in others.rpdo_dlcs)
    if heartbeat_period_s:
        bits += (n_axes + others.nodes) * frame_bits(HEARTBEAT_DLC) * cycle_period_s / heartbeat_period_s
    bits += others.sdo_frames_per_s * frame_bits(SDO_DLC) * cycle_period_s
    return BusLoad(bits, bits / (bitrate * cycle_period_s), n_axes, cycle_period_s, bitrate, following_error_tpdo,
                   others.nodes)


def other_nodes_traffic(config: MachineConfig) -> OtherNodesTraffic:
    """The spindle drive (its 0x60FF RPDO every SYNC in csv, its SDO monitor) and the I/O node
    (event-driven TPDO, not counted), each with a heartbeat."""
    spindle = config.spindle if isinstance(config.spindle, SpindleConfig) else None
    nodes = (spindle is not None) + (config.io is not None)
    if spindle is None:
        return OtherNodesTraffic(nodes)
    csv = (CSV_VELOCITY_DLC,) if spindle.mode is SpindleMode.CSV else ()
    return OtherNodesTraffic(nodes, csv, SPINDLE_POLL_FRAMES / MONITOR_POLL_S)


def config_bus_load(config: MachineConfig, following_error_tpdo: bool = False) -> BusLoad:
    return cyclic_bus_load(len(config.axes), config.cycle_period_s, config.bus.bitrate, following_error_tpdo,
                           config.monitoring.heartbeat_producer_ms / 1000.0, other_nodes_traffic(config))


def check_bus_load(config: MachineConfig) -> BusLoad:
    """Refuse a configuration whose cyclic traffic exceeds ``monitoring.max_bus_load``.

    Returns the load without the optional following-error TPDO (the master maps that TPDO
    only when :func:`fits_following_error_tpdo` says it fits).
    """
    load = config_bus_load(config)
    limit = config.monitoring.max_bus_load
    if load.load > limit:
        raise InputError(config.where("cycle_period_ms"),
                         f"bus load {load.load:.0%} at {config.cycle_period_s * 1000:g} ms with {load.n_axes} axes"
                         f"{_others_text(load.other_nodes)} "
                         f"exceeds {limit:.0%} (monitoring.max_bus_load) at {config.bus.bitrate / 1000:g} kbit/s: "
                         f"use a longer cycle, fewer axes on this bus or a higher bitrate")
    return load


def fits_following_error_tpdo(config: MachineConfig) -> bool:
    """True if a second TPDO per axis (0x60F4 following error) still fits under the limit."""
    return config_bus_load(config, following_error_tpdo=True).load <= config.monitoring.max_bus_load


def _others_text(nodes: int) -> str:
    return f" and {nodes} other node{'s' if nodes > 1 else ''} (spindle, I/O)" if nodes else ""
