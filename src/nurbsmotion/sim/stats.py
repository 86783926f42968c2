"""Counters of a simulated drive, for tests and the log."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class DriveStats:
    """Counts since the drive was created."""

    syncs: int = 0  # SYNCs taken in OPERATIONAL (counted once the SYNC's TPDOs are out)
    syncs_ignored: int = 0
    rpdos_received: int = 0
    rpdos_dropped: int = 0
    rpdos_overwritten: int = 0  # a synchronous RPDO replaced by a newer one before the SYNC
    rpdo_length_errors: int = 0
    pdo_values_refused: int = 0  # e.g. an unsupported mode written by RPDO
    setpoints_applied: int = 0
    setpoints_ignored: int = 0  # received while not enabled / not in the mode
    setpoints_refused: int = 0  # outside the software position limits
    tpdos_sent: int = 0
    emcys_sent: int = 0
    heartbeats_sent: int = 0
