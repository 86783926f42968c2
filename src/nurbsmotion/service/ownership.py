"""One daemon per bus: an exclusive lock per bus channel, taken before the first frame.

A second daemon started by mistake must not touch the bus: an NMT reset from it resets the
running daemon's drives. So before anything else (job records, drives, socket) the daemon
checks that nobody serves its control socket and takes an exclusive ``flock`` on
``/run/lock/nurbsmotion-<interface>-<channel>.lock`` (the data directory when /run/lock is
not writable). The lock file names the owner (pid and control socket); the kernel drops the
lock when the owner's process ends, however it ends. python-can's virtual bus lives inside
one process, so it is not locked.
"""

from __future__ import annotations

import fcntl
import os
import socket
from pathlib import Path

from nurbsmotion.config import MachineConfig
from nurbsmotion.errors import NurbsmotionError

LOCK_DIRS = (Path("/run/lock"),)
IN_PROCESS_INTERFACES = ("virtual",)


class BusTaken(NurbsmotionError):
    """Another daemon owns the bus or the control socket."""


def lock_path(config: MachineConfig, lock_dirs: tuple[Path, ...] = LOCK_DIRS) -> Path:
    """Lock file of the configured bus channel: the first writable of ``lock_dirs``, else the data directory."""
    name = f"nurbsmotion-{config.bus.interface}-{str(config.bus.channel).replace('/', '_')}.lock"
    for folder in lock_dirs:
        if folder.is_dir() and os.access(folder, os.W_OK):
            return folder / name
    return Path(config.data_dir) / name


def socket_in_use(path: str) -> bool:
    """A process accepts connections on the Unix socket ``path``."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(1.0)
    try:
        probe.connect(path)
    except OSError:
        return False
    finally:
        probe.close()
    return True


class BusOwnership:
    """The lock of one bus channel, held from :meth:`acquire` to :meth:`release` (or exit)."""

    def __init__(self, config: MachineConfig, lock_dirs: tuple[Path, ...] = LOCK_DIRS) -> None:
        self.config = config
        self.path = lock_path(config, lock_dirs)
        self._file: int | None = None

    def acquire(self) -> None:
        """Take the bus or raise BusTaken naming the owner (pid and socket); changes nothing then."""
        cfg = self.config
        where = f"{cfg.bus.interface}:{cfg.bus.channel}"
        if socket_in_use(cfg.control.socket):
            raise BusTaken(f"another daemon serves {cfg.control.socket}{self._owner_text()}; this one touches "
                           f"nothing (stop it first: nurbsmotion stop / kill)")
        if cfg.bus.interface in IN_PROCESS_INTERFACES:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise BusTaken(f"bus {where} is owned by another daemon{self._owner_text()} (lock {self.path}); "
                           f"this one touches nothing") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"pid={os.getpid()} socket={cfg.control.socket}\n".encode())
        self._file = fd

    def _owner_text(self) -> str:
        try:
            owner = self.path.read_text().strip()
        except OSError:
            return ""
        return f" ({owner})" if owner else ""

    def release(self) -> None:
        if self._file is not None:
            os.close(self._file)  # closing drops the flock; the file stays (a later owner rewrites it)
            self._file = None
