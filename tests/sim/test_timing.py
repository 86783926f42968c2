"""Drives that feel time: SYNC timestamps, cycles without SYNC, hold or extrapolate, sync
lock (statusword bit 8), sync loss, RPDO event timers, and the stream report that shows a
stop-and-go. Every time is injected (the bench's SYNC stamps or a ManualClock), so the
results do not depend on how loaded the machine is."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from nurbsmotion.can.cia402 import State
from nurbsmotion.sim import MissingSetpoint, SetpointSource, SyncSettings, stream_report
from nurbsmotion.sim.timing import SyncMonitor, missed_ticks

from conftest import Bench, ManualClock, rpdo, wait_for

T = 1e-3
SW_SYNC = 1 << 8


def emcy_codes(bench: Bench, node_id: int) -> list[int]:
    return [struct.unpack_from("<H", data)[0] for data in bench.frames.of(0x80 + node_id)]


def stream(bench: Bench, node_id: int, values: list[int | None], gap_after: int | None = None, gap_s: float = 0.0) -> None:
    """One CSP set-point per SYNC (None: no RPDO before that SYNC); the SYNC after index
    ``gap_after`` comes ``gap_s`` later than due."""
    for k, value in enumerate(values):
        if value is not None:
            bench.send(0x200 + node_id, rpdo(0x0F, value))
        at_s = bench.sync_time_s + T + (gap_s if k == gap_after else 0.0)
        bench.sync(at_s=at_s)


# ------------------------------------------------------------------ pure arithmetic
@pytest.mark.parametrize("interval_t,missed", [(1.0, 0), (1.2, 0), (1.25, 0), (1.3, 1), (2.0, 1), (3.0, 2), (0.1, 0)])
def test_cycles_that_ran_without_sync(interval_t: float, missed: int) -> None:
    assert missed_ticks(interval_t * T, T, 0.25) == missed


def test_sync_monitor_locks_after_two_on_time_intervals_and_loses_sync_after_n_periods() -> None:
    monitor = SyncMonitor(SyncSettings(own_cycle=True, loss_periods=3))
    times = [0.0, 0.001, 0.00203, 0.003]
    assert [monitor.on_sync(t, T).missed_ticks for t in times] == [0, 0, 0, 0]
    assert monitor.locked
    timing = monitor.on_sync(0.0052, T)  # 2.2 T: one cycle ran without SYNC
    assert (timing.missed_ticks, timing.interval_s) == (1, pytest.approx(2.2 * T)) and not monitor.locked
    assert monitor.loss_deadline(T) == pytest.approx(0.0082)
    assert not monitor.lost(0.0081, T) and monitor.lost(0.0083, T) and not monitor.lost(0.0099, T)  # reported once


def test_a_sync_triggered_drive_runs_one_cycle_per_sync_whenever_it_comes() -> None:
    monitor = SyncMonitor(SyncSettings())
    monitor.on_sync(0.0, T)
    timing = monitor.on_sync(0.0052, T)
    assert (timing.missed_ticks, timing.interval_s) == (0, pytest.approx(5.2 * T))


def test_sync_loss_can_be_off() -> None:
    monitor = SyncMonitor(SyncSettings())
    monitor.on_sync(0.0, T)
    assert monitor.loss_deadline(T) == math.inf and not monitor.lost(100.0, T)


def test_bad_settings_are_refused() -> None:
    with pytest.raises(ValueError):
        SyncSettings(loss_periods=0.5)
    with pytest.raises(ValueError):
        SyncSettings(lock_tolerance=0)


# ------------------------------------------------------------------ on the bus
def test_every_sync_and_setpoint_is_stamped_and_a_regular_stream_is_clean(bench: Bench) -> None:
    drive, _ = bench.add_enabled(2)
    bench.sync()
    stream(bench, 2, [10 * k for k in range(1, 21)])
    times = np.array([r.sync_time_ns for r in drive.recorder.records()])
    assert np.allclose(np.diff(times), T * 1e9, atol=1e3)  # the bench's stamps, to 1 µs
    report = stream_report(drive.timeline.as_array(), drive.period_s)
    assert report.clean, report.problems()
    assert report.syncs == 21 and report.interval_max_s == pytest.approx(T, abs=1e-6)
    assert drive.sync_locked and drive.statusword & SW_SYNC


def test_a_late_sync_shows_as_a_cycle_without_sync_and_costs_the_lock(bench: Bench) -> None:
    drive, _ = bench.add_enabled(2, lag_cycles=0, sync=SyncSettings(own_cycle=True))
    bench.sync()
    stream(bench, 2, [10 * k for k in range(1, 11)], gap_after=4, gap_s=T)  # SYNC 6 comes 2 T after SYNC 5
    rows = drive.timeline.records()
    late = [r for r in rows if r.missed_ticks]
    assert len(late) == 1 and late[0].sync_index == 6 and late[0].interval_ns == pytest.approx(2e6, abs=1e3)
    assert drive.stats.syncs_late == 1 and drive.stats.ticks_missed == 1
    report = stream_report(drive.timeline.as_array(), drive.period_s)
    assert (report.late_syncs, report.missed_cycles, report.missing_setpoints) == (1, 1, 0)
    assert not report.clean and "1 x late SYNC" in report.problems()
    # the motor stood still for the cycle without SYNC: at SYNC 6 it had moved one step in 2 T
    actual = np.array([r.position_actual_counts for r in rows], dtype=float)
    times_s = np.array([r.sync_time_ns for r in rows]) * 1e-9
    velocity = np.diff(actual) / np.diff(times_s)
    assert velocity[2:6] == pytest.approx([10_000, 10_000, 5_000, 10_000], rel=1e-3)


def test_the_lock_bit_returns_after_two_regular_intervals(bench: Bench) -> None:
    drive, _ = bench.add_enabled(2)
    for _ in range(3):
        bench.sync()
    assert drive.sync_locked
    bench.sync(at_s=bench.sync_time_s + 3 * T)
    assert not drive.sync_locked and not drive.statusword & SW_SYNC
    bench.sync()
    assert not drive.sync_locked
    bench.sync()
    assert drive.sync_locked


@pytest.mark.parametrize("own_cycle,moved", [(False, 100), (True, 300)])
def test_an_own_cycle_drive_moves_for_the_cycles_that_passed(bench: Bench, own_cycle: bool, moved: int) -> None:
    # 100 counts per 1 ms cycle at most: after a SYNC 3 ms late an own-cycle drive has run 3 cycles,
    # a SYNC-triggered drive one (it waited for the SYNC)
    drive, _ = bench.add_enabled(2, lag_cycles=0, max_velocity_counts_s=100_000, sync=SyncSettings(own_cycle=own_cycle))
    bench.sync()
    bench.send(0x202, rpdo(0x0F, 1000))
    bench.sync()
    assert drive.position_actual == 100
    bench.sync(at_s=bench.sync_time_s + 3 * T)
    assert drive.position_actual == 100 + moved


def test_an_early_sync_is_reported(bench: Bench) -> None:
    drive, _ = bench.add_enabled(2)
    bench.sync()
    stream(bench, 2, [1, 2, 3, 4], gap_after=2, gap_s=-0.9 * T)
    report = stream_report(drive.timeline.as_array(), drive.period_s)
    assert report.early_syncs == 1 and report.missed_cycles == 0


def test_a_sync_triggered_drive_sees_a_late_sync_in_its_timeline_but_runs_no_cycle_without_it(bench: Bench) -> None:
    drive, _ = bench.add_enabled(2)
    bench.sync()
    stream(bench, 2, [10 * k for k in range(1, 11)], gap_after=4, gap_s=T)
    report = stream_report(drive.timeline.as_array(), drive.period_s)
    assert (report.late_syncs, report.missed_cycles, report.missing_setpoints) == (1, 0, 0)
    assert [r.setpoint_counts for r in drive.recorder.records()] == [10 * k for k in range(1, 11)]


@pytest.mark.parametrize("policy,expected_demand", [(MissingSetpoint.HOLD, [10, 20, 30, 30, 50]),
                                                    (MissingSetpoint.EXTRAPOLATE, [10, 20, 30, 40, 50])])
def test_a_sync_without_a_fresh_setpoint_holds_or_extrapolates(bench: Bench, policy: MissingSetpoint,
                                                                 expected_demand: list[int]) -> None:
    drive, _ = bench.add_enabled(2, sync=SyncSettings(missing_setpoint=policy))
    bench.sync()
    stream(bench, 2, [10, 20, 30, None, 50])
    rows = drive.timeline.records()[-5:]
    assert [r.demand_counts for r in rows] == expected_demand
    missing = SetpointSource.HELD if policy is MissingSetpoint.HOLD else SetpointSource.EXTRAPOLATED
    assert [r.source for r in rows] == [1, 1, 1, int(missing), 1]
    assert stream_report(drive.timeline.as_array(), T).missing_setpoints == 1
    assert drive.stats.setpoints_missing >= 1


def test_extrapolating_overshoots_when_the_stream_stops(bench: Bench) -> None:
    drive, _ = bench.add_enabled(2, sync=SyncSettings(missing_setpoint=MissingSetpoint.EXTRAPOLATE))
    bench.sync()
    stream(bench, 2, [10, 20, 30, None, None])
    assert [r.demand_counts for r in drive.timeline.records()[-2:]] == [40, 50]


def test_a_repeated_setpoint_inside_a_motion_is_reported(bench: Bench) -> None:
    drive, _ = bench.add_enabled(2)
    bench.sync()
    stream(bench, 2, [10, 20, 30, 30, 50, 60, 60, 60])  # one stale set-point at speed; the stop at 60 is fine
    report = stream_report(drive.timeline.as_array(), drive.period_s)
    assert report.repeated_setpoints == 1 and report.missing_setpoints == 0


# ------------------------------------------------------------------ deadlines (manual clock)
def enabled_with_clock(bench: Bench, clock: ManualClock, **kwargs: object):
    drive, node = bench.add(2, clock=clock, **kwargs)
    bench.operational(2)
    bench.enable(2)
    return drive, node


def test_sync_loss_faults_with_emcy_8700_after_n_periods(bench: Bench) -> None:
    clock = ManualClock()
    drive, _ = enabled_with_clock(bench, clock, sync=SyncSettings(loss_periods=3))
    for _ in range(3):
        clock.advance(T)
        bench.sync()
    clock.advance(2.9 * T)
    drive.tick()
    assert drive.state is State.OPERATION_ENABLED
    clock.advance(0.2 * T)
    drive.tick()
    assert drive.state is State.FAULT and drive.axis.error_code == 0x8700 and drive.stats.sync_losses == 1
    wait_for(lambda: 0x8700 in emcy_codes(bench, 2), what="EMCY 0x8700")


def test_without_loss_periods_a_drive_waits_for_sync_forever(bench: Bench) -> None:
    clock = ManualClock()
    drive, _ = enabled_with_clock(bench, clock)
    clock.advance(T)
    bench.sync()
    clock.advance(10.0)
    drive.tick()
    assert drive.state is State.OPERATION_ENABLED


def test_a_disabled_drive_does_not_fault_on_sync_loss(bench: Bench) -> None:
    clock = ManualClock()
    drive, _ = bench.add(2, clock=clock, sync=SyncSettings(loss_periods=2))
    bench.operational(2)
    for _ in range(3):
        clock.advance(T)
        bench.sync()
    clock.advance(5 * T)
    drive.tick()
    assert drive.state is State.SWITCH_ON_DISABLED and not drive.sync_locked


def test_rpdo_event_timer_expiry_sends_emcy_8250_and_faults(bench: Bench) -> None:
    clock = ManualClock()
    drive, node = enabled_with_clock(bench, clock)
    node.sdo[0x1400][5].raw = 10  # ms
    drive.tick()
    clock.advance(1.0)
    drive.tick()
    assert drive.state is State.OPERATION_ENABLED  # monitoring starts with the first RPDO
    bench.send(0x202, rpdo(0x0F, 0))
    wait_for(lambda: drive.stats.rpdos_received == 1, what="RPDO")
    clock.advance(0.0099)
    drive.tick()
    assert drive.state is State.OPERATION_ENABLED
    clock.advance(0.0002)
    drive.tick()
    assert drive.state is State.FAULT and drive.axis.error_code == 0x8250 and drive.stats.rpdo_timeouts == 1
    wait_for(lambda: 0x8250 in emcy_codes(bench, 2), what="EMCY 0x8250")
