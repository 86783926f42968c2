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
    setpoints_missing: int = 0  # cycles in IP/CSP without a fresh set-point (held or extrapolated)
    syncs_late: int = 0  # SYNCs after which the drive's cycle had run without a SYNC
    ticks_missed: int = 0  # drive cycles that ran without a SYNC
    sync_losses: int = 0  # sync-loss faults (no SYNC for loss_periods)
    sync_length_errors: int = 0  # SYNC with a length that does not fit 0x1019 (EMCY 0x8240)
    sync_counter_jumps: int = 0  # SYNC counter not the previous + 1 (0x1019 > 0)
    rpdos_outside_window: int = 0  # synchronous RPDOs after the 0x1007 window: discarded
    rpdo_timeouts: int = 0  # RPDO event timer (0x14xx:05) expiries (EMCY 0x8250)
    tpdos_sent: int = 0
    emcys_sent: int = 0
    heartbeats_sent: int = 0
