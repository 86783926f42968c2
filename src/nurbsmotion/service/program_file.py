"""A program the daemon holds as a file, never as text: what ``start NAME`` and a ``run FILE``
or ``programs add FILE`` whose client passed the file itself start from (issue 25 item 7: the
daemon under 150 MB with a 10^6-line program; each whole-text copy was 17.5 MB, and glibc
keeps freed copies in the daemon's heap).

- A client on this host sends the open file with its request (``program_fd``: SCM_RIGHTS over
  the control socket, service.server): the daemon needs no permission on its path (another
  user's home, another mount namespace: the kernel hands over what the client opened). It is
  copied into DATA_DIR/spool a megabyte at a time (:func:`spool`): checked as UTF-8 (a
  leading byte-order mark dropped, as ``run`` and ``check`` read a file), hashed and limited
  in size on the way.
- ``start NAME``: the library's file, hard-linked into the spool (:func:`snapshot`): the
  library replaces a file atomically (a new inode), so the link keeps what was started.

The spool file then is the program: its SHA-256 gives the checked-program store's key, the
planner worker or the checker reads it only when the store has no entry (planner_worker's
PlanRequest.text_file), and the job record links it (records.JobRecord.write_program). The
daemon removes it once the job has started or was refused (:meth:`ProgramFile.discard`).
"""

from __future__ import annotations

import codecs
import contextlib
import hashlib
import os
import shutil
import stat
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from nurbsmotion.errors import InputError
from nurbsmotion.text_files import Utf8Check

CHUNK_BYTES = 1 << 20
BOM = codecs.BOM_UTF8
SPOOL = "spool"


@dataclass(frozen=True)
class ProgramFile:
    """A daemon-owned file holding a program's UTF-8 text (no byte-order mark), its SHA-256
    (of those bytes: checked_store.text_digest of the text) and size."""

    path: Path
    sha256: str
    size_bytes: int

    def read_text(self) -> str:
        """The text (a planner that plans in the daemon's process: not the lookahead's)."""
        return self.path.read_text(encoding="utf-8")

    def link_to(self, destination: Path) -> None:
        """``destination`` holds the same bytes: a hard link, or a copy where links fail."""
        try:
            os.link(self.path, destination)
        except OSError:
            shutil.copyfile(self.path, destination)

    def discard(self) -> None:
        """Remove the spool file (the job record and the library keep their own links)."""
        self.path.unlink(missing_ok=True)


def spool_folder(data_dir: str | Path) -> Path:
    folder = Path(data_dir) / SPOOL
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def clear_spool(data_dir: str | Path) -> None:
    """Remove what a daemon that ended mid-start left in the spool (no start is under way)."""
    folder = Path(data_dir) / SPOOL
    for left in folder.glob("*.program") if folder.is_dir() else ():
        left.unlink(missing_ok=True)


def spool_path(data_dir: str | Path) -> Path:
    return spool_folder(data_dir) / f"{uuid.uuid4().hex}.program"


def spool(fd: int, data_dir: str | Path, where: str, max_bytes: int, limit: str = "web.max_upload_mb") -> ProgramFile:
    """Copy the regular file open as ``fd`` (read from its start) into the spool: a
    ProgramFile; InputError naming ``where`` for a descriptor that is not a regular file, a
    file larger than ``max_bytes`` (the ``limit``'s) or one that is not UTF-8 (nothing is
    left behind)."""
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        raise InputError(where, "the descriptor sent is not a regular file")
    path = spool_path(data_dir)
    digest, size, offset = hashlib.sha256(), 0, 0
    check = Utf8Check()
    try:
        with open(path, "xb") as out:
            first = True
            while True:
                chunk = os.pread(fd, CHUNK_BYTES, offset)
                offset += len(chunk)
                if first and chunk.startswith(BOM):
                    chunk = chunk[len(BOM):]
                first = False
                size += len(chunk)
                if size > max_bytes:
                    raise InputError(where, f"larger than the {max_bytes / (1024 * 1024):g} MB limit ({limit})")
                check.feed(chunk, where, final=not chunk)
                if not chunk:
                    break
                digest.update(chunk)
                out.write(chunk)
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    return ProgramFile(path, digest.hexdigest(), size)


def file_digest(path: Path) -> str:
    """SHA-256 of the file's bytes, a megabyte at a time."""
    digest = hashlib.sha256()
    with open(path, "rb") as src:
        for chunk in iter(lambda: src.read(CHUNK_BYTES), b""):
            digest.update(chunk)
    return digest.hexdigest()


def snapshot(path: Path, data_dir: str | Path, recorded_stamp: list[int] | None = None,
             recorded_sha256: str = "") -> ProgramFile:
    """``path`` (a library program) linked into the spool (copied where links fail); its
    SHA-256 the library's record of it when the link is that very file unchanged since
    (``recorded_stamp``: file_stamp; no read at all), else hashed now."""
    target = spool_path(data_dir)
    ProgramFile(path, "", 0).link_to(target)
    try:
        stamp = file_stamp(target)
        sha256 = recorded_sha256 if recorded_sha256 and stamp == recorded_stamp else file_digest(target)
        return ProgramFile(target, sha256, stamp[2])
    except BaseException:
        target.unlink(missing_ok=True)
        raise


def file_stamp(path: Path) -> list[int]:
    """What tells a file changed without reading it: device, inode, size and mtime (ns)."""
    st = path.stat()
    return [st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns]


@contextlib.contextmanager
def requested_program(fields: dict[str, Any], files: tuple[int, ...], data_dir: str | Path,
                      max_bytes: int, limit: str) -> Iterator[str | ProgramFile]:
    """The program of a ``submit`` or ``programs.add`` request (protocol: ``program``, its
    text, or ``program_fd``, the index of a descriptor in ``files``), spooled while the
    request is served and discarded after (a program the library kept was moved out)."""
    if "program_fd" not in fields:
        yield str(fields["program"])
        return
    index = fields["program_fd"]
    if float(index) != int(index) or not 0 <= int(index) < len(files):
        raise InputError("field 'program_fd'", f"no file descriptor {index!r} came with the request "
                                               f"({len(files)} did)")
    program = spool(files[int(index)], data_dir, f"program {fields.get('name', '')!r}", max_bytes, limit)
    try:
        yield program
    finally:
        program.discard()
