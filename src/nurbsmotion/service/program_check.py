"""Checking a program for the library (``programs.add``) in a process of its own.

A program added to the library is read and checked as a job of it would be
(service.planner_worker.read_and_check: syntax, geometry, devices, machine axes, soft limits,
count range), and the checked program is written to the checked-program store
(service.checked_store) under the key a start of it from here would have, so that the start
loads it instead. The planner worker cannot do it while it plans a running job, and the
daemon's own process must not (the check would hold its interpreter lock for seconds while
the cycle thread runs): a second spawned process does, started at the first ``programs.add``
and kept (its imports take about a second), off the realtime CPU as the planner worker is.
A control-client thread waits for its answer; nothing else does.
"""

from __future__ import annotations

import concurrent.futures
import logging
import multiprocessing
import os
import threading
from dataclasses import dataclass
from typing import Any

from nurbsmotion.errors import InputError
from nurbsmotion.log import kv
from nurbsmotion.service.planner_worker import PlanRequest, as_error

log = logging.getLogger(__name__)

CHECK_TIMEOUT_S = 900.0  # a 10^6-line program today takes minutes (issue 25)


@dataclass(frozen=True)
class CheckReport:
    """What the check found: the figures of a checked program, or its errors (where, message)."""

    blocks: int = 0
    reading: dict[str, Any] | None = None
    extent: dict[str, Any] | None = None
    errors: tuple[tuple[str, str], ...] = ()
    from_store: bool = False

    def as_dict(self) -> dict[str, Any]:
        return {"ok": not self.errors, "blocks": self.blocks, "lines": self.reading, "extent": self.extent,
                "errors": [f"{where}: {message}" if where else message for where, message in self.errors]}


def check_in_process(request: PlanRequest, axis_names: tuple[str, ...]) -> CheckReport:
    """The checker process' work: load or read and check, store, summarise."""
    from nurbsmotion.errors import InputErrors
    from nurbsmotion.program.summary import reading_dict
    from nurbsmotion.service.path_bounds import path_box
    from nurbsmotion.service.planner_worker import read_or_load, store_checked

    try:
        program, from_store = read_or_load(request)
    except InputError as err:
        found = err.errors if isinstance(err, InputErrors) else [err]
        return CheckReport(errors=tuple((e.where, e.message) for e in found))
    if not from_store:
        store_checked(request, program)
    low, high = path_box(program, request.columns)
    extent = {"axes": list(axis_names), "min_mm": [round(float(v), 6) for v in low],
              "max_mm": [round(float(v), 6) for v in high]}
    return CheckReport(len(program.blocks), reading_dict(program), extent, from_store=from_store)


def _off_realtime_cpu() -> None:
    from nurbsmotion.runtime import keep_off_realtime_cpu

    keep_off_realtime_cpu(os.getpid())


class ProgramChecker:
    """The checker process (module docstring); one check at a time, in arrival order."""

    def __init__(self) -> None:
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def check(self, request: PlanRequest, axis_names: tuple[str, ...]) -> CheckReport:
        """The check's report (InputError when the checker process cannot be had or ended)."""
        future = self._executor().submit(check_in_process, request, axis_names)
        try:
            return future.result(CHECK_TIMEOUT_S)
        except concurrent.futures.TimeoutError:
            future.cancel()
            raise InputError(request.name, f"checking took more than {CHECK_TIMEOUT_S:g} s") from None
        except concurrent.futures.process.BrokenProcessPool as err:
            self.close()  # the next check starts a new process
            raise InputError(request.name, f"the checker process ended unexpectedly ({err})") from None

    def _executor(self) -> concurrent.futures.ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                self._pool = concurrent.futures.ProcessPoolExecutor(
                    max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_off_realtime_cpu)
                log.debug(kv("program_checker_started"))
            return self._pool

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)


__all__ = ["CheckReport", "ProgramChecker", "check_in_process", "as_error"]
