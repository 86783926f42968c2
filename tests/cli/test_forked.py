"""cli._forked: items computed in a forked child reach the parent in order with the child's
result; the child's errors are raised in the parent; a parent that stops early leaves no
child behind; the idle CPUs that decide whether ``plan`` forks at all."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest

from nurbsmotion.cli._forked import MIN_IDLE_WINDOW_S, IdleWatch, forked_iteration, idle_ticks
from nurbsmotion.steps import drained
from nurbsmotion.errors import InputError, InputErrors


def arrays(n: int) -> Iterator[np.ndarray]:
    for k in range(n):
        yield np.arange(k * 1000, (k + 1) * 1000, dtype=np.float64) / 3.0


def test_items_arrive_in_order_to_the_bit_and_then_the_childs_result():
    done: list[int] = []  # appended in the child only: the parent's list stays empty

    def result() -> tuple[int, int]:
        return os.getpid(), len(done)

    def items() -> Iterator[np.ndarray]:
        for a in arrays(40):  # 40 x 8 kB: more than the pipe holds, so the child waits for the parent
            done.append(1)
            yield a

    got: list[np.ndarray] = []
    child_pid, child_count = drained(forked_iteration(items, result), got.append)
    assert child_pid != os.getpid() and child_count == 40 and done == []
    assert len(got) == 40
    for a, b in zip(got, arrays(40)):
        assert np.array_equal(a, b)


def failing(err: BaseException) -> Iterator[int]:
    yield 1
    raise err


class BlockError(InputError):
    def __init__(self, where: str, message: str, block: int | None = None) -> None:
        super().__init__(where, message)
        self.block = block


@pytest.mark.parametrize("err", [InputError("p.nc:7", "bad word"), BlockError("p.nc:9", "cannot hold", block=4),
                                 InputErrors([InputError("p.nc:1", "one"), BlockError("p.nc:2", "two", 1)])])
def test_an_input_error_in_the_child_is_raised_of_its_class_with_its_places_and_messages(err):
    got: list[int] = []
    with pytest.raises(InputError) as raised:
        drained(forked_iteration(lambda: failing(err), lambda: None), got.append)
    assert got == [1]
    assert type(raised.value) is type(err) and str(raised.value) == str(err)
    assert vars(raised.value).keys() == vars(err).keys()
    assert (raised.value.where, raised.value.message, getattr(raised.value, "block", None)) == \
        (err.where, err.message, getattr(err, "block", None))
    if isinstance(err, InputErrors):
        assert [(type(e), str(e)) for e in raised.value.errors] == [(type(e), str(e)) for e in err.errors]
        assert raised.value.errors[1].block == 1


class Unpicklable(Exception):
    def __init__(self, a: int) -> None:
        super().__init__(f"{a} and a lock")
        self.lock = threading.Lock()


def test_other_errors_keep_their_type_or_their_type_name_and_text():
    with pytest.raises(ValueError, match="plain"):
        drained(forked_iteration(lambda: failing(ValueError("plain")), lambda: None), lambda item: None)
    with pytest.raises(RuntimeError, match="Unpicklable: 1 and a lock"):
        drained(forked_iteration(lambda: failing(Unpicklable(1)), lambda: None), lambda item: None)


def test_a_consumer_that_stops_ends_and_reaps_the_child(tmp_path: Path):
    pid_file = tmp_path / "pid"

    def endless() -> Iterator[int]:
        pid_file.write_text(str(os.getpid()))
        k = 0
        while True:
            k += 1
            yield k

    def consume(k: int) -> None:
        if k == 3:
            raise KeyError("stop here")

    with pytest.raises(KeyError):
        drained(forked_iteration(endless, lambda: None), consume)
    child = int(pid_file.read_text())
    assert child != os.getpid()
    with pytest.raises(ProcessLookupError):  # killed and reaped: no such process, not even a zombie
        os.kill(child, 0)


@pytest.mark.skipif(idle_ticks() is None, reason="no /proc/stat")
def test_idle_cores_are_measured_over_a_window_long_enough_to_tell():
    watch = IdleWatch()
    assert watch.idle_cores() is None  # no window yet: a few clock ticks tell nothing
    time.sleep(MIN_IDLE_WINDOW_S * 1.5)
    idle = watch.idle_cores()
    assert idle is not None and 0.0 <= idle <= (os.cpu_count() or 1) + 0.5  # 0.5: clock ticks of 10 ms over 75 ms
    earlier = IdleWatch()
    assert earlier.idle_ticks is not None
    earlier.started_s -= 1.0  # as if made a second ago, one CPU idle all that second
    earlier.idle_ticks -= os.sysconf("SC_CLK_TCK")
    assert earlier.idle_cores() == pytest.approx(1.0, abs=0.2)


class Watch:
    def __init__(self, idle: float | None) -> None:
        self.idle = idle

    def idle_cores(self) -> float | None:
        return self.idle


@pytest.mark.parametrize("cores, idle, forked", [(2, 0.9, True), (2, None, True), (2, 0.6, False), (1, 0.9, False)])
def test_the_planner_gets_a_second_process_only_with_a_core_to_run_on(monkeypatch, cores, idle, forked):
    import nurbsmotion.cli.plan as plan_command

    monkeypatch.setattr(plan_command, "cores_available", lambda: cores)
    assert plan_command.second_process_helps(Watch(idle)) is forked
