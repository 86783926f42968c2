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
import re
import socket
import struct
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


def socket_server_pid(path: str) -> int | None:
    """The pid of the process that accepts connections on the Unix socket ``path`` (its
    SO_PEERCRED, taken when it listened); None when nobody does. 0: it listens, pid unknown."""
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(1.0)
    try:
        probe.connect(path)
        pid, _, _ = struct.unpack("3i", probe.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i")))
        return int(pid)
    except OSError:
        return None
    finally:
        probe.close()


def socket_in_use(path: str) -> bool:
    """A process accepts connections on the Unix socket ``path``."""
    return socket_server_pid(path) is not None


def stop_advice(pid: int | None) -> str:
    """How to end the daemon ``pid`` (SIGTERM: it stops a running job along the path, disables
    the drives and exits, docs/daemon.md); ``nurbsmotion stop`` only stops its job."""
    target = str(pid) if pid else "its pid"
    return f"to end that daemon: kill -TERM {target}, or systemctl stop nurbsmotion where systemd runs it"


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
        pid = socket_server_pid(cfg.control.socket)
        if pid is not None:
            raise BusTaken(f"another daemon (pid {pid or 'unknown'}) serves {cfg.control.socket}{self._owner_text()}; "
                           f"this one touches nothing ({stop_advice(pid)})")
        if cfg.bus.interface in IN_PROCESS_INTERFACES:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            owner = self._owner_text()
            named = re.search(r"pid=(\d+)", owner)
            raise BusTaken(f"bus {where} is owned by another daemon{owner} (lock {self.path}); this one touches "
                           f"nothing ({stop_advice(int(named.group(1)) if named else None)})") from None
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
