"""The daemon's homing: which axes are homed, ``home [AXIS...]`` in the configured order,
and the refusal of jobs, MDI and absolute jogs until every axis is homed.

Each axis' ``homing:`` (config.homing) is either a drive method (CiA-402 mode 6, run by
the master: fieldbus.Master.home, planned and checked against the drive's EDS by
fieldbus.homing_check) or ``here`` (no motion: the held position becomes
``offset_mm`` by moving the axis map's offset: counts = sign·mm·counts_per_mm + offset).
Homing runs on its own thread (a homing may take a minute); ``status`` shows each axis'
state and the last error.

The homed state is lost when the axis' drive reports a fault (EMCY, fault bit, heartbeat
or boot-up: power loss) and when the daemon restarts: incremental encoders have no
trustworthy zero after either.

``require_homing`` (config): unset means required on a real bus (``socketcan`` without
``simulate: true``), not on the virtual bus or with simulated drives.
"""

from __future__ import annotations

import enum
import logging
import threading
from typing import Any

import numpy as np

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import FieldbusError, InputError
from nurbsmotion.fieldbus.homing import HomingProcedure, here_offset_counts
from nurbsmotion.fieldbus.homing_check import plan_homing
from nurbsmotion.config.homing import homing_method_name
from nurbsmotion.log import kv
from nurbsmotion.service.motion import MotionLink

log = logging.getLogger(__name__)


class AxisHomed(enum.Enum):
    NOT_HOMED = "not homed"
    HOMING = "homing"
    HOMED = "homed"


def homing_required(config: MachineConfig) -> bool:
    """``require_homing``, else true on socketcan with real drives (module docstring)."""
    if config.require_homing is not None:
        return config.require_homing
    return config.bus.interface == "socketcan" and not config.simulate


def homing_order(config: MachineConfig, names: list[str] | tuple[str, ...] = ()) -> list[int]:
    """Axis indices to home: ``names`` (default every axis with ``homing:``), sorted by their
    ``homing.order`` (axes without one after, in list order). InputError names the axis."""
    axes = config.axes
    if names:
        known = {a.name.upper(): i for i, a in enumerate(axes)}
        chosen = []
        for name in names:
            i = known.get(name.upper())
            if i is None:
                raise InputError("field 'axes'", f"no axis {name!r}; the axes are {', '.join(a.name for a in axes)}")
            if axes[i].homing is None:
                raise InputError("field 'axes'", f"axis {axes[i].name} has no homing: section in "
                                 f"{config.source} (axes[{i}].homing)")
            if i not in chosen:
                chosen.append(i)
    else:
        chosen = [i for i, a in enumerate(axes) if a.homing is not None]
        if not chosen:
            raise InputError("home", f"no axis has a homing: section in {config.source}")

    def key(i: int) -> tuple[int, int]:
        order = axes[i].homing.order  # type: ignore[union-attr]
        return (order if order is not None else 1 << 30, i)
    return sorted(chosen, key=key)


class Homing:
    """Per-axis homed state and the homing thread (one at a time)."""

    def __init__(self, config: MachineConfig, link: MotionLink) -> None:
        self.config = config
        self.link = link
        self.required = homing_required(config)
        n = len(config.axes)
        self.state = [AxisHomed.NOT_HOMED] * n
        self.error: str | None = None  # the last homing's error line
        self._faults_seen = 0  # master fault reports already looked at
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._tripped: str | None = None  # the limit input that stopped the homing under way

    # ------------------------------------------------------------------ state
    @property
    def busy(self) -> bool:
        thread = self._thread
        return thread is not None and thread.is_alive()

    def forget_faulted(self, faults: tuple[Any, ...]) -> None:
        """An axis whose drive reported a fault since last looked is no longer homed."""
        with self._lock:
            new, self._faults_seen = faults[self._faults_seen:], len(faults)
            for fault in new:
                for i, axis in enumerate(self.config.axes):
                    if fault.node_id == axis.node_id and self.state[i] is AxisHomed.HOMED:
                        self.state[i] = AxisHomed.NOT_HOMED
                        log.warning(kv("homed_state_lost", axis=axis.name, node=axis.node_id, fault=fault.kind))

    def not_homed(self) -> list[str]:
        return [a.name for a, s in zip(self.config.axes, self.state) if s is not AxisHomed.HOMED]

    def refusal(self, needs_homing: bool) -> str | None:
        """Why a job may not start now (None: it may): homing under way, or (``needs_homing``)
        homing required and an axis not homed."""
        if self.busy:
            return "homing is under way"
        missing = self.not_homed()
        if needs_homing and self.required and missing:
            return (f"axis {', '.join(missing)} not homed (require_homing is on): run nurbsmotion home first")
        return None

    def status(self) -> dict[str, Any]:
        return {"required": self.required, "busy": self.busy, "error": self.error,
                "axes": {a.name: s.value for a, s in zip(self.config.axes, self.state)}}

    def ignoring_limits(self, names: list[str]) -> frozenset[str]:
        """Of the axes ``home`` would home now, those whose homing ignores their limit inputs."""
        axes = self.config.axes
        return frozenset(axes[i].name for i in homing_order(self.config, names)
                         if (h := axes[i].homing) is not None and h.ignore_limits)

    def limit_tripped(self, axis: str, message: str) -> None:
        """A limit input of ``axis`` became active: a homing under way stops with a quick stop
        of every axis (as a job would be aborted), unless ``axis`` is the one homing and its
        homing ignores its limits (its limit switch is its home switch)."""
        homing = [i for i, s in enumerate(self.state) if s is AxisHomed.HOMING]
        if not self.busy or not homing:
            return
        current = self.config.axes[homing[0]]
        if current.name == axis and current.homing is not None and current.homing.ignore_limits:
            log.info(kv("homing_limit_ignored", axis=axis, reason=message))
            return
        with self._lock:
            self._tripped = message
        self.link.stop_homing(quick=True)

    # ------------------------------------------------------------------ homing
    def start(self, names: list[str], faults: tuple[Any, ...]) -> list[str]:
        """Start homing ``names`` (all with homing: when empty) in order on a thread; the names."""
        order = homing_order(self.config, names)
        self.forget_faulted(faults)
        with self._lock:
            self.error = None
            self._tripped = None
            for i in order:
                self.state[i] = AxisHomed.NOT_HOMED
            self._thread = threading.Thread(target=self._home_all, args=(order,), name="homing", daemon=True)
            self._thread.start()
        return [self.config.axes[i].name for i in order]

    def wait(self, timeout_s: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _home_all(self, order: list[int]) -> None:
        for i in order:
            if not self._home_one(i):
                return  # later axes stay not homed: the operator sees the first error

    def _home_one(self, i: int) -> bool:
        axis = self.config.axes[i]
        homing = axis.homing
        assert homing is not None
        self.state[i] = AxisHomed.HOMING
        log.info(kv("homing_started", axis=axis.name, node=axis.node_id, method=homing_method_name(homing.method)))
        try:
            if homing.on_drive:
                ok, reason = self._home_on_drive(i)
            else:
                ok, reason = self._home_here(i), ""
        except (FieldbusError, InputError) as err:
            ok, reason = False, str(err)
        with self._lock:
            self.state[i] = AxisHomed.HOMED if ok else AxisHomed.NOT_HOMED
            if not ok and self._tripped is not None:
                reason = f"homing stopped: {self._tripped}; the axes were quick-stopped: send reset"
            if not ok:
                self.error = reason if reason.startswith("axis ") else f"axis {axis.name}: {reason}"
        if ok:
            position = self.link.axis_map.to_mm(np.array([[a.setpoint_counts for a in self.link.status().axes]]))[0][i]
            log.info(kv("homing_done", axis=axis.name, node=axis.node_id, position_mm=round(float(position), 6)))
        else:
            log.warning(kv("homing_failed", axis=axis.name, node=axis.node_id, error=self.error))
        return ok

    def _home_on_drive(self, i: int) -> tuple[bool, str]:
        """The drive homes (the plan checked against its EDS at load: fieldbus.homing_check);
        when it completes, the axis map takes the offset the plan's route gives (the master's
        own home offset on a drive without 0x607C)."""
        axis = self.config.axes[i]
        homing = axis.homing
        drive_homing = plan_homing(self.config, i)
        assert homing is not None and drive_homing is not None
        procedure = HomingProcedure(axis.node_id, drive_homing.method, self.config.cycle_period_s, homing.timeout_s)
        outcome = self.link.home(i, drive_homing.plan, procedure)
        if outcome.homed:
            self.link.axis_map.offset_counts[i] = drive_homing.offset_counts_after
            log.info(kv("homing_offset", axis=axis.name, route=drive_homing.route.name.lower(),
                        offset_counts=drive_homing.offset_counts_after))
        return outcome.homed, outcome.reason

    def _home_here(self, i: int) -> bool:
        """``method: here``: the held position reads offset_mm from now on (axis map offset)."""
        axis = self.config.axes[i]
        homing = axis.homing
        assert homing is not None
        held = self.link.status().axes[i].setpoint_counts
        offset = here_offset_counts(held, homing.offset_mm, axis.counts_per_mm, axis.invert)
        self.link.axis_map.offset_counts[i] = offset
        return True

    def shift_counts(self, counts: np.ndarray) -> None:
        """Planned counts (computed with the configured offsets) onto the offsets in force
        (``method: here`` moved them): counts += offset_now - offset_configured, in place."""
        delta = self.link.axis_map.offset_counts - np.array([a.offset_counts for a in self.config.axes])
        if delta.any():
            counts += delta.astype(counts.dtype)
