"""Iterate in a forked child process, consume here: the two cores of a small controller used
for one command (``plan``: the planner computes chunk k + 1 while this process measures chunk k).

The child pickles every item through a pipe as soon as it has it (protocol 5: numpy arrays
as raw buffers, about 1 ms per MB), then the ``result`` it computes after the last one. The
pipe holds little (64 KB), so the child is at most about one item ahead: memory stays
bounded by an item, as in one process. An exception in the child is raised here, of its
class and with its attributes (an InputError with its place and message; one that cannot
be pickled as a RuntimeError with its type and text); the child
ends with ``os._exit`` (no atexit handlers, no second flush of output buffered before the
fork). If this side stops early (an error while consuming, Ctrl-C), the child is ended and
reaped: nothing is left running, and its CPU time counts in this process's children.

Without ``os.fork`` (not POSIX) the items are iterated in this process.
"""

from __future__ import annotations

import io
import logging
import os
import pickle
import signal
import sys
import time
from typing import Any, BinaryIO, Callable, Generator, Iterable, TypeVar

Item = TypeVar("Item")
Result = TypeVar("Result")

ITEM, DONE, FAILED = 0, 1, 2
PROTOCOL = 5

log = logging.getLogger(__name__)


def forked_iteration(items: Callable[[], Iterable[Item]],
                     result: Callable[[], Result]) -> Generator[Item, None, Result]:
    """Yield the items ``items()`` gives in a forked child, in order, as they arrive; return
    the child's ``result()`` (computed after the last item). ``items`` is called in the child."""
    if not hasattr(os, "fork"):
        yield from items()
        return result()
    sys.stdout.flush()
    sys.stderr.flush()
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child: measured by its effect in the parent
        os.close(read_fd)
        os._exit(_child(os.fdopen(write_fd, "wb"), items, result))
    os.close(write_fd)
    finished = False
    try:
        with os.fdopen(read_fd, "rb") as incoming:
            while True:
                kind, value = pickle.load(incoming)
                if kind == ITEM:
                    yield value
                elif kind == DONE:
                    finished = True
                    return value
                else:
                    finished = True
                    raise pickle.loads(value)
    except EOFError:
        raise RuntimeError("the forked process ended without a result") from None
    finally:
        _end_child(pid, finished)


def _child(out: BinaryIO, items: Callable[[], Iterable[Item]], result: Callable[[], Result]) -> int:
    """Send every item, then the result or the error; the exit code."""
    try:
        with out:
            try:
                for item in items():
                    pickle.dump((ITEM, item), out, PROTOCOL)
                    out.flush()
                pickle.dump((DONE, result()), out, PROTOCOL)
            except BrokenPipeError:
                return 1  # the parent stopped reading
            except BaseException as err:  # noqa: BLE001 - every error is the parent's to report
                log.debug("in the forked process", exc_info=err)
                pickle.dump((FAILED, _portable(err)), out, PROTOCOL)
        return 0
    except BaseException:  # noqa: BLE001 - the parent sees the pipe end and reports it
        return 1


class _ExceptionPickler(pickle.Pickler):
    """Pickles exceptions by class, args and attributes (``__dict__``), not through their
    constructors: InputError(where, message) and its kind (PlanningError's ``block``,
    InputErrors' list) take other arguments than ``args`` holds, which plain pickle passes."""

    def reducer_override(self, obj: object) -> Any:  # a reduce tuple, or NotImplemented: pickle as usual
        if isinstance(obj, BaseException):
            return _exception, (type(obj), obj.args, dict(vars(obj)))
        return NotImplemented


def _exception(cls: type[BaseException], args: tuple[object, ...], state: dict[str, object]) -> BaseException:
    err = cls.__new__(cls)
    err.args = args
    err.__dict__.update(state)
    return err


def _portable(err: BaseException) -> bytes:
    """``err`` pickled with its class and attributes; if it cannot be, a RuntimeError with its
    type and text."""
    out = io.BytesIO()
    try:
        _ExceptionPickler(out, PROTOCOL).dump(err)
        pickle.loads(out.getvalue())
        return out.getvalue()
    except Exception:  # noqa: BLE001 - any failure to pickle or rebuild: send the text
        return pickle.dumps(RuntimeError(f"{type(err).__name__}: {err}"), PROTOCOL)


def _end_child(pid: int, finished: bool) -> None:
    """Reap the child; one still running (this side stopped early) is killed first. The pid
    is ours until reaped, so the signal cannot reach another process."""
    if not finished:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    os.waitpid(pid, 0)


def cores_available() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


MIN_IDLE_WINDOW_S = 0.05  # shorter: a few clock ticks (10 ms each), too coarse to tell


class IdleWatch:
    """How many CPUs of the machine stood idle, on average, since this was made: the idle
    and iowait clock ticks of all CPUs (/proc/stat's first line) over the wall time. A second
    process only helps when a core is free: under other work at normal priority a forked
    planner shares our one core with us and the command gets slower (bench_plan_command)."""

    def __init__(self) -> None:
        self.started_s = time.monotonic()
        self.idle_ticks = idle_ticks()

    def idle_cores(self) -> float | None:
        """Idle CPUs on average since this was made; None where /proc/stat is missing or the
        window is shorter than MIN_IDLE_WINDOW_S."""
        now, elapsed_s = idle_ticks(), time.monotonic() - self.started_s
        if now is None or self.idle_ticks is None or elapsed_s < MIN_IDLE_WINDOW_S:
            return None
        return (now - self.idle_ticks) / os.sysconf("SC_CLK_TCK") / elapsed_s


def idle_ticks() -> int | None:
    """Idle + iowait clock ticks of all CPUs since boot (Linux /proc/stat), None elsewhere."""
    try:
        with open("/proc/stat", "rb") as stat:
            fields = stat.readline().split()
        return int(fields[4]) + int(fields[5])
    except (OSError, IndexError, ValueError):
        return None
