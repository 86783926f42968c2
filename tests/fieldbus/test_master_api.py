"""Master checks its inputs before touching the bus: bad arrays, wrong state, overload."""

import numpy as np
import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus import Master
from nurbsmotion.fieldbus.master import LATENESS_QUANTILES_EVERY_CYCLES


def _config(period_ms: float = 4, n_axes: int = 2):
    axes = "".join(f"  - {{name: A{i}, node_id: {i + 1}}}\n" for i in range(n_axes))
    return parse_config(f"cycle_period_ms: {period_ms}\naxes:\n{axes}", "m.yaml")


def test_overloaded_bus_is_refused_at_construction():
    with pytest.raises(InputError, match="bus load .* exceeds 80%"):
        Master(_config(period_ms=1, n_axes=6))


@pytest.mark.parametrize("counts, message", [
    (np.zeros((5, 3), dtype=np.int32), r"shape \(N >= 1, 2\)"),
    (np.zeros((0, 2), dtype=np.int32), r"shape \(N >= 1, 2\)"),
    (np.zeros((5, 2)), "must be integers"),
    (np.full((5, 2), 2**40), "int32 range"),
])
def test_bad_set_point_arrays_are_refused(counts, message):
    with pytest.raises(InputError, match=message):
        Master(_config()).stream(counts)


def test_streaming_before_bring_up_is_refused():
    with pytest.raises(FieldbusError, match="call bring_up"):
        Master(_config()).stream(np.zeros((5, 2), dtype=np.int32))


def test_unknown_options_are_refused():
    with pytest.raises(InputError, match="sync_source"):
        Master(_config(), sync_source="magic")
    with pytest.raises(InputError, match="gc_mode"):
        Master(_config(), gc_mode="off")


def _socketcan_bus_without_socket():
    """An instance of the master's own SocketCAN bus class, never opened (no AF_CAN here)."""
    from nurbsmotion.can.socketcan_batch import BatchedSocketcanBus
    return BatchedSocketcanBus.__new__(BatchedSocketcanBus)


def test_auto_sync_source_queues_in_the_kernel_on_the_masters_own_socketcan_bus():
    # the daemon's bus on socketcan is the batched subclass: 'auto' once compared the class
    # name with "SocketcanBus" and sent every daemon on socketcan to the loop writer
    from nurbsmotion.fieldbus.bcm_queue import BcmQueueWriter
    from nurbsmotion.fieldbus.writer import LoopWriter

    bus = _socketcan_bus_without_socket()
    assert isinstance(Master(_config(), bus=bus, sync_source="auto")._make_writer(), BcmQueueWriter)
    assert isinstance(Master(_config(), bus=bus, sync_source="loop")._make_writer(), LoopWriter)
    assert isinstance(Master(_config(), bus=object(), sync_source="auto")._make_writer(), LoopWriter)


def test_kernel_timer_threads_below_the_cycle_thread_are_named_with_the_fix(monkeypatch, caplog):
    from nurbsmotion.fieldbus import master as master_module
    from nurbsmotion.runtime import KernelThread

    asked = []
    threads = [KernelThread("ksoftirqd/0", 14, "SCHED_OTHER", 0), KernelThread("ktimers/1", 30, "SCHED_FIFO", 1)]
    monkeypatch.setattr(master_module, "timer_threads_below", lambda priority: asked.append(priority) or threads)
    with caplog.at_level("WARNING", logger="nurbsmotion.fieldbus.master"):
        Master(_config(), rt_priority=20)._warn_timer_threads_below()
    assert asked == [20]
    line = caplog.records[-1].getMessage()
    assert line.startswith("kernel_timers_below_cycle_thread cycle_thread_priority=20")
    assert "threads=ksoftirqd/0:SCHED_OTHER:0,ktimers/1:SCHED_FIFO:1" in line
    assert 'fix="chrt -f -p 21 14; chrt -f -p 21 30"' in line


def test_no_warning_when_the_timer_threads_are_above(monkeypatch, caplog):
    from nurbsmotion.fieldbus import master as master_module

    monkeypatch.setattr(master_module, "timer_threads_below", lambda priority: [])
    with caplog.at_level("WARNING", logger="nurbsmotion.fieldbus.master"):
        Master(_config(), rt_priority=20)._warn_timer_threads_below()
    assert not caplog.records


def test_the_lateness_quantiles_are_computed_anew_by_whole_reads_only_and_at_most_every_so_many_cycles():
    master = Master(_config())
    stats = master._loop.stats()
    for _ in range(100):
        stats.add(20e-6, False)
    whole = master.status().timing
    for _ in range(LATENESS_QUANTILES_EVERY_CYCLES + 100):
        stats.add(900e-6, True)
    fast = master.status(percentiles=False).timing
    again = master.status().timing
    assert (fast.cycles, fast.missed_cycles) == (again.cycles, again.missed_cycles) == (700, 600)
    assert (fast.lateness_p50_s, fast.lateness_p99_s) == (whole.lateness_p50_s, whole.lateness_p99_s)
    assert again.lateness_p50_s > whole.lateness_p99_s  # enough cycles counted: computed anew
    for _ in range(LATENESS_QUANTILES_EVERY_CYCLES - 100):
        stats.add(5e-3, True)  # a third of the cycles: they would move the p99
    soon = master.status().timing
    assert soon.cycles == 1100 and (soon.lateness_p50_s, soon.lateness_p99_s) == (again.lateness_p50_s,
                                                                                     again.lateness_p99_s)
