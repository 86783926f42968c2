"""Jog one axis: incremental (``X+10``), absolute (``X 25``) or continuous (``X+`` until
``jog stop``, Ctrl-C, or the client's lease runs out).

A jog is a job named ``<jog>``: one straight G53 move of one axis in machine coordinates,
``G53 G90 G01 X<target> F<speed·60>``, parsed, planned (the configured look-ahead planner:
jerk-limited with the axis' and the machine's limits), soft-limit checked, recorded and
streamed exactly like a program, so it stops with the same controlled ramp as ``stop``. A
continuous jog plans the move to the soft limit in its direction at the speed given; it
lives while the client renews its lease (``jog_renew``, every ~0.2 s by the CLI): when
:data:`LEASE_S` passes without one (client killed, connection lost), the job is stopped.

Checked before anything is planned, each one line: the axis exists; the speed is positive
and within the axis' ``max_velocity_mm_s``; the target within the soft limits; a continuous
jog needs a soft limit in its direction; an absolute jog needs the axes homed when
``require_homing`` is on (service.homing). While a limit input is active, only a jog of its
axis away from it starts (service.machine_io).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from nurbsmotion.config import AxisConfig, MachineConfig
from nurbsmotion.errors import InputError, Refused
from nurbsmotion.log import kv
from nurbsmotion.service.machine_io import AxisMotion
from nurbsmotion.service.job_common import JOG_NAME, RunningJob, running_job_id


log = logging.getLogger(__name__)

LEASE_S = 0.5  # a continuous jog stops when no jog_renew came for this long
WATCH_S = 0.05  # how often the lease is looked at
DEFAULT_SPEED_MM_S = 10.0
LEASE_REASON = f"stopped: the jog's client did not renew its lease within {LEASE_S:g} s"


@dataclass(frozen=True)
class JogRequest:
    """One jog, as the API gives it: exactly one of ``distance_mm``, ``position_mm``, ``direction``."""

    axis: str
    distance_mm: float | None = None
    position_mm: float | None = None
    direction: int = 0  # +1 / -1: continuous
    speed_mm_s: float = DEFAULT_SPEED_MM_S

    @property
    def continuous(self) -> bool:
        return self.direction != 0

    @property
    def absolute(self) -> bool:
        return self.position_mm is not None

    def text(self) -> str:
        if self.continuous:
            return f"{self.axis}{'+' if self.direction > 0 else '-'}"
        if self.absolute:
            return f"{self.axis} {self.position_mm:g}"
        return f"{self.axis}{self.distance_mm:+g}"


def jog_request(fields: dict[str, Any]) -> JogRequest:
    """The request fields (protocol: axis, distance, position, direction, speed) -> JogRequest."""
    given = [k for k in ("distance", "position", "direction") if k in fields]
    if len(given) != 1:
        raise InputError("field 'distance'", "give exactly one of distance (incremental), position (absolute) "
                         "or direction ('+' / '-': continuous)")
    direction = 0
    if "direction" in fields:
        if fields["direction"] not in ("+", "-"):
            raise InputError("field 'direction'", f"must be '+' or '-', got {fields['direction']!r}")
        direction = 1 if fields["direction"] == "+" else -1
    speed = float(fields.get("speed", DEFAULT_SPEED_MM_S))
    if not speed > 0:
        raise InputError("field 'speed'", f"must be a positive speed in mm/s, got {speed:g}")
    return JogRequest(str(fields["axis"]).upper(), fields.get("distance"), fields.get("position"), direction, speed)


def jog_target_mm(request: JogRequest, axis: AxisConfig, held_mm: float) -> float:
    """Machine position the jog moves to; InputError (one line, ``jog X+700: ...``) when it
    would leave the soft limits or the speed exceeds the axis' limit."""
    where = f"jog {request.text()}"
    if axis.max_velocity_mm_s is not None and request.speed_mm_s > axis.max_velocity_mm_s:
        raise InputError(where, f"speed {request.speed_mm_s:g} mm/s is above axis {axis.name}'s max_velocity_mm_s "
                         f"{axis.max_velocity_mm_s:g}")
    limits = axis.soft_limits_mm
    if request.continuous:
        if limits is None:
            raise InputError(where, f"axis {axis.name} has no soft_limits_mm: a continuous jog needs an end")
        end = limits[1] if request.direction > 0 else limits[0]
        if (end - held_mm) * request.direction <= 1e-9:
            raise InputError(where, f"axis {axis.name} is at its soft limit {end:g} mm already")
        return end
    if request.position_mm is not None:
        target = float(request.position_mm)
    else:
        target = held_mm + float(request.distance_mm or 0.0)
    if limits is not None and not limits[0] <= target <= limits[1]:
        raise InputError(where, f"axis {axis.name} would reach {target:.6g} mm, beyond the soft limit "
                         f"{limits[1] if target > limits[1] else limits[0]:g} mm")
    if abs(target - held_mm) < 1e-9:
        raise InputError(where, f"axis {axis.name} is at {target:.6g} mm already: nothing to move")
    return target


def jog_gcode(axis: str, target_mm: float, speed_mm_s: float) -> str:
    """The one line of a jog: a straight move in machine coordinates (G53 needs G90 and G1)."""
    return f"G21 G53 G90 G01 {axis}{target_mm:.6f} F{speed_mm_s * 60.0:.6f}\n"


def find_axis(config: MachineConfig, name: str) -> tuple[int, AxisConfig]:
    for i, axis in enumerate(config.axes):
        if axis.name.upper() == name:
            return i, axis
    raise InputError("field 'axis'", f"no axis {name!r}; the axes are {', '.join(a.name for a in config.axes)}")


class JogHost(Protocol):
    """What jogging needs of the daemon's controller (service.controller.Controller)."""

    config: MachineConfig

    def held_position_mm(self) -> np.ndarray: ...
    def submit(self, name: str, text: str, keep_override: bool = False, block_delete: bool = True,
               optional_stop: bool = True, needs_homing: bool = True, jog: AxisMotion | None = None,
               start_line: int | None = None) -> dict[str, Any]: ...
    def running_job(self) -> RunningJob | None: ...
    def stop(self, reason: str = "stop") -> dict[str, Any]: ...


class Jogging:
    """Starts jogs through the controller and keeps the continuous jog's lease."""

    def __init__(self, controller: JogHost) -> None:
        self.controller = controller
        self._lease_until = 0.0
        self._job_id: str | None = None  # the continuous jog whose lease is kept
        self._lock = threading.Lock()
        self._watcher: threading.Thread | None = None

    def jog(self, fields: dict[str, Any]) -> dict[str, Any]:
        request = jog_request(fields)
        controller = self.controller
        i, axis = find_axis(controller.config, request.axis)
        held_mm = float(controller.held_position_mm()[i])
        target = jog_target_mm(request, axis, held_mm)
        try:
            response = controller.submit(JOG_NAME, jog_gcode(axis.name, target, request.speed_mm_s),
                                         keep_override=True, needs_homing=request.absolute,
                                         jog=AxisMotion(axis.name, 1 if target > held_mm else -1))
        except Refused as err:
            raise Refused("jog", err.message) from None
        job_id = response["job"]["id"]
        log.info(kv("jog_started", job=job_id, jog=request.text(), target_mm=round(target, 6),
                    speed_mm_s=request.speed_mm_s))
        if request.continuous:
            with self._lock:
                self._job_id, self._lease_until = job_id, time.monotonic() + LEASE_S
            self._watcher = threading.Thread(target=self._watch_lease, args=(job_id,), name=f"jog-lease-{job_id}",
                                             daemon=True)
            self._watcher.start()
        response["jog"] = {"axis": axis.name, "target_mm": round(target, 6), "speed_mm_s": request.speed_mm_s,
                           "continuous": request.continuous, "lease_s": LEASE_S if request.continuous else None}
        return response

    def renew(self) -> dict[str, Any]:
        """Extend the continuous jog's lease by LEASE_S from now."""
        with self._lock:
            if self._job_id is None or running_job_id(self.controller.running_job()) != self._job_id:
                raise Refused("jog_renew", "no continuous jog is running")
            self._lease_until = time.monotonic() + LEASE_S
            return {"ok": True, "job": self._job_id}

    def stop(self) -> dict[str, Any]:
        """``jog stop``: the running jog (any kind) decelerates with the stop ramp."""
        running = self.controller.running_job()
        job = running.name if running is not None else None
        if job != JOG_NAME:
            raise Refused("jog stop", "no jog is running" if job is None else f"the running job is {job}, not a jog "
                          f"(use stop)")
        with self._lock:
            self._job_id = None
        return self.controller.stop()

    def _watch_lease(self, job_id: str) -> None:
        while True:
            time.sleep(WATCH_S)
            with self._lock:
                if self._job_id != job_id or running_job_id(self.controller.running_job()) != job_id:
                    return
                expired = time.monotonic() > self._lease_until
                if expired:
                    self._job_id = None
            if expired:
                log.warning(kv("jog_lease_expired", job=job_id, lease_s=LEASE_S))
                try:
                    self.controller.stop(reason="jog_lease")
                except Refused:
                    pass  # the jog ended by itself meanwhile
                return

