"""Who may use the control socket: SO_PEERCRED of the connecting process.

Allowed: the daemon's own uid, root, and (when ``control.group`` is configured) any process
whose primary or supplementary groups include that group. The socket file is mode 0660 as
well, so the file system already keeps others out; this check holds even if the mode or the
group of the file is changed by hand.
"""

from __future__ import annotations

import grp
import socket
import struct
from dataclasses import dataclass

_UCRED = struct.Struct("3i")  # pid, uid, gid (struct ucred)


@dataclass(frozen=True)
class PeerCredentials:
    pid: int
    uid: int
    gid: int
    groups: frozenset[int]


def peer_credentials(conn: socket.socket) -> PeerCredentials:
    """pid/uid/gid of the peer (kernel-checked) and its supplementary groups (from /proc)."""
    pid, uid, gid = _UCRED.unpack(conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _UCRED.size))
    return PeerCredentials(pid, uid, gid, frozenset(_supplementary_groups(pid)))


def _supplementary_groups(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Groups:"):
                    return [int(g) for g in line.split()[1:]]
    except (OSError, ValueError):
        pass
    return []


def group_id(name: str | None) -> int | None:
    """gid of the configured control group (None if not configured); KeyError if unknown."""
    if name is None:
        return None
    return int(name) if name.isdigit() else grp.getgrnam(name).gr_gid


def peer_allowed(peer: PeerCredentials, daemon_uid: int, control_gid: int | None) -> bool:
    """The access rule of the module docstring."""
    if peer.uid in (daemon_uid, 0):
        return True
    return control_gid is not None and (peer.gid == control_gid or control_gid in peer.groups)


def refusal(peer: PeerCredentials, control_group: str | None) -> str:
    """The one-line error sent to a refused peer."""
    needed = f" and not in group {control_group!r}" if control_group else " (no control.group configured)"
    return f"permission denied: uid {peer.uid} is not the daemon's user or root{needed}"

