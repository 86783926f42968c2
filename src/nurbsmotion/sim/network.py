"""Simulated drives on one python-can bus: the canopen Network (receive thread) and the
ticker thread (heartbeats, timed fault injections) they share."""

from __future__ import annotations

import logging
import math
import threading
import time
from pathlib import Path
from typing import Any

import canopen

from nurbsmotion.errors import InputError
from nurbsmotion.log import kv
from nurbsmotion.sim.drive import SimDrive
from nurbsmotion.sim.faults import FaultInjection
from nurbsmotion.sim.timing import SyncSettings

log = logging.getLogger(__name__)

# The receive thread's read timeout: how long stop() waits for it at most (canopen: 1 s).
NOTIFIER_CYCLE_S = 0.1


UNLIMITED_VELOCITY_COUNTS_S = math.inf


class DriveSetupError(ValueError):
    """A drive of axis ``axis_index`` could not be built (e.g. its EDS does not load)."""

    def __init__(self, axis_index: int, message: str) -> None:
        super().__init__(message)
        self.axis_index = axis_index
        self.message = message


class SimNetwork:
    """Any number of :class:`SimDrive` on one bus (``interface``/``channel`` as python-can).

    Use as a context manager or call :meth:`start` / :meth:`stop`. Drives added after start
    boot at once.
    """

    def __init__(self, interface: str = "virtual", channel: str = "nurbsmotion", bitrate: int = 1_000_000, **bus_kwargs: Any) -> None:
        self.interface = interface
        self.channel = channel
        self.bitrate = bitrate
        self.bus_kwargs = bus_kwargs
        self.drives: dict[int, SimDrive] = {}
        self.network: canopen.Network | None = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._ticker: threading.Thread | None = None
        self.started_at = time.monotonic()

    def add_drive(self, node_id: int, eds: str | Path | None = None, **drive_kwargs: Any) -> SimDrive:
        """Create drive ``node_id`` (keyword arguments as :class:`SimDrive`)."""
        if node_id in self.drives:
            raise ValueError(f"node {node_id} is already simulated")
        drive = SimDrive(node_id, eds, **drive_kwargs)
        self.drives[node_id] = drive
        if self.network is not None:
            drive.attach(self.network)
            self._wake.set()
        return drive

    @classmethod
    def for_machine(
        cls, machine: Any, *, lag_cycles: int = 1, max_velocity_counts_s: float | None = None, record: bool = True,
        sync: SyncSettings | None = None,
    ) -> "SimNetwork":
        """One drive per axis of a ``nurbsmotion.config.MachineConfig`` (read by attribute:
        bus.interface/channel/bitrate, axes[].name/node_id/eds/identity).

        Each drive is its EDS straight out of the box (plus the axis identity in 0x1018):
        mode, cycle period and everything else are what the master writes, so a missing
        write shows. ``sync`` sets hold/extrapolate and the sync-loss fault of every drive.
        """
        bus = machine.bus
        net = cls(interface=bus.interface, channel=bus.channel, bitrate=bus.bitrate)
        for axis_index, axis in enumerate(machine.axes):
            identity = (axis.identity.vendor_id, axis.identity.product_code) if axis.identity else None
            try:
                net.add_drive(
                    axis.node_id,
                    axis.eds,
                    lag_cycles=lag_cycles,
                    max_velocity_counts_s=max_velocity_counts_s or UNLIMITED_VELOCITY_COUNTS_S,
                    identity=identity,
                    record=record,
                    name=f"{axis.name}/node{axis.node_id}",
                    sync=sync,
                )
            except Exception as err:  # noqa: BLE001 - canopen raises many kinds for a bad EDS
                raise DriveSetupError(axis_index, f"cannot simulate axis {axis.name}: {type(err).__name__}: {err}") from err
        return net

    def __getitem__(self, node_id: int) -> SimDrive:
        return self.drives[node_id]

    def start(self) -> "SimNetwork":
        """Open the bus, boot every drive (boot-up messages) and start the heartbeats.
        A bus that cannot be opened raises OSError or can.CanError and starts nothing."""
        if self.network is not None:
            return self
        network = canopen.Network()
        network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        network.connect(interface=self.interface, channel=self.channel, bitrate=self.bitrate, **self.bus_kwargs)
        self.network = network
        self.started_at = time.monotonic()
        for drive in self.drives.values():
            drive.attach(network)
        self._stop.clear()
        self._ticker = threading.Thread(target=self._tick_loop, name="sim-ticker", daemon=True)
        self._ticker.start()
        log.info(kv("sim.start", interface=self.interface, channel=self.channel, nodes=sorted(self.drives)))
        return self

    def stop(self) -> None:
        """Stop heartbeats and timers, detach the drives, close the bus."""
        self._stop.set()
        self._wake.set()
        if self._ticker is not None:
            self._ticker.join(timeout=2.0)
            self._ticker = None
        for drive in self.drives.values():
            drive.detach()
        if self.network is not None:
            self.network.disconnect()
            self.network = None
        log.info(kv("sim.stop", channel=self.channel))

    def __enter__(self) -> "SimNetwork":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def inject(self, fault: FaultInjection) -> None:
        """Route ``fault`` to the drive ``fault.node_id``."""
        drive = self.drives.get(fault.node_id) if fault.node_id is not None else None
        if drive is None:
            raise InputError(f"node {fault.node_id}", f"no simulated drive with this node id (have {sorted(self.drives)})")
        drive.inject(fault)
        self._wake.set()

    def write_recordings(self, directory: str | Path, timelines: bool = False) -> list[Path]:
        """Write ``<dir>/node<id>.csv`` (applied set-points) for every drive, and with
        ``timelines`` ``<dir>/node<id>.sync.csv`` (every SYNC); returns the paths."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        paths = []
        for node_id, drive in sorted(self.drives.items()):
            paths.append(drive.write_recording(directory / f"node{node_id}.csv"))
            if timelines:
                paths.append(drive.write_timeline(directory / f"node{node_id}.sync.csv"))
        return paths

    def _tick_loop(self) -> None:
        while not self._stop.is_set():
            wait_s = 0.05
            for drive in list(self.drives.values()):
                try:
                    wait_s = min(wait_s, drive.tick() - drive.now())  # each drive on its own clock
                except Exception:  # noqa: BLE001 - one drive's error must not stop the others' heartbeat
                    log.exception("sim ticker: node %d", drive.node_id)
            self._wake.wait(max(wait_s, 0.0))
            self._wake.clear()
