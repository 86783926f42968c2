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

SYNC_DLC = 0
RPDO_DLC = 6  # controlword u16 + set-point i32
TPDO1_DLC = 6  # statusword u16 + position actual i32
TPDO2_DLC = 4  # following error actual i32
HEARTBEAT_DLC = 1


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


def cyclic_bus_load(n_axes: int, cycle_period_s: float, bitrate: int, following_error_tpdo: bool = False,
                    heartbeat_period_s: float | None = None) -> BusLoad:
    """Load = (SYNC + n·(RPDO + TPDO1 [+ TPDO2]) + heartbeats per cycle) bits / (bitrate · T)."""
    per_axis = frame_bits(RPDO_DLC) + frame_bits(TPDO1_DLC)
    if following_error_tpdo:
        per_axis += frame_bits(TPDO2_DLC)
    bits: float = frame_bits(SYNC_DLC) + n_axes * per_axis
    if heartbeat_period_s:
        bits += n_axes * frame_bits(HEARTBEAT_DLC) * cycle_period_s / heartbeat_period_s
    return BusLoad(bits, bits / (bitrate * cycle_period_s), n_axes, cycle_period_s, bitrate, following_error_tpdo)


def config_bus_load(config: MachineConfig, following_error_tpdo: bool = False) -> BusLoad:
    return cyclic_bus_load(len(config.axes), config.cycle_period_s, config.bus.bitrate, following_error_tpdo,
                           config.monitoring.heartbeat_producer_ms / 1000.0)


def check_bus_load(config: MachineConfig) -> BusLoad:
    """Refuse a configuration whose cyclic traffic exceeds ``monitoring.max_bus_load``.

    Returns the load without the optional following-error TPDO (the master maps that TPDO
    only when :func:`fits_following_error_tpdo` says it fits).
    """
    load = config_bus_load(config)
    limit = config.monitoring.max_bus_load
    if load.load > limit:
        raise InputError(config.where("cycle_period_ms"),
                         f"bus load {load.load:.0%} at {config.cycle_period_s * 1000:g} ms with {load.n_axes} axes "
                         f"exceeds {limit:.0%} (monitoring.max_bus_load) at {config.bus.bitrate / 1000:g} kbit/s: "
                         f"use a longer cycle, fewer axes on this bus or a higher bitrate")
    return load


def fits_following_error_tpdo(config: MachineConfig) -> bool:
    """True if a second TPDO per axis (0x60F4 following error) still fits under the limit."""
    return config_bus_load(config, following_error_tpdo=True).load <= config.monitoring.max_bus_load
