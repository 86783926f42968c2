"""The daemon's program library: DATA_DIR/programs/NAME (the text as uploaded) and
NAME.json beside it (its SHA-256, size, when it was added and its check's report).

One library for the CLI (``nurbsmotion programs``) and the web gateway (``/api/v1/programs``):
the gateway keeps no state. Names are file names of 1-128 letters, digits, ``.``, ``_``,
``-`` beginning with a letter or digit (protocol.PROGRAM_NAME: no path, no hidden file);
the size is limited by ``web.max_upload_mb`` (default 64 MB). A program is added only after
its check passed (service.program_check); both files are written atomically. A file changed
on disk after it was added is still started from what it holds now: its check's key is
its content (service.checked_store), so it is read and checked again. A start never reads the
text in the daemon: the file is linked into the spool (service.program_file.snapshot) and its
SHA-256 taken from NAME.json while the file is the one recorded there (device, inode, size,
modification time: ``stamp``), hashed again otherwise.
"""

from __future__ import annotations

import json
import os
import re
import threading
from pathlib import Path
from typing import Any, Callable

from nurbsmotion.errors import InputError
from nurbsmotion.service.program_file import ProgramFile, file_stamp, snapshot
from nurbsmotion.service.protocol import PROGRAM_NAME
from nurbsmotion.service.records import now_iso, write_atomic

NAME_RE = re.compile(PROGRAM_NAME)
META_SUFFIX = ".json"


def write_atomically(path: Path, data: bytes) -> None:
    """``data`` into ``path`` (its folder made if need be) as records.write_atomic writes."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, data)


def check_library_name(name: str) -> str:
    """``name`` if it is a library name, else InputError naming the field."""
    if not NAME_RE.match(name):
        raise InputError("field 'name'", f"program name {name[:140]!r}: 1-128 letters, digits, '.', '_' or '-', "
                                         "beginning with a letter or digit (no path), e.g. part.nc")
    return name


class ProgramLibrary:
    """DATA_DIR/programs (module docstring). Thread-safe: one lock around each change."""

    def __init__(self, data_dir: str | Path, max_mb: float) -> None:
        self.folder = Path(data_dir) / "programs"
        self.max_mb = max_mb
        self.max_bytes = int(max_mb * 1024 * 1024)
        self._lock = threading.Lock()

    def check_size(self, name: str, text: str) -> int:
        size = len(text.encode("utf-8"))
        if size > self.max_bytes:
            raise InputError(f"program {name!r}", f"{size:,} bytes is larger than the {self.max_mb:g} MB limit "
                                                  "(web.max_upload_mb)")
        return size

    def add(self, name: str, text: str, sha256: str, check: dict[str, Any]) -> dict[str, Any]:
        """Keep ``text`` as ``name`` (replacing a program of that name) with its check's report."""
        size = self.check_size(name, text)
        return self._keep(name, lambda path: write_atomically(path, text.encode("utf-8")), size, sha256, check)

    def add_file(self, name: str, program: ProgramFile, check: dict[str, Any]) -> dict[str, Any]:
        """Keep the spooled ``program`` as ``name`` (moved into the library, not copied)."""
        return self._keep(name, lambda path: os.replace(program.path, path), program.size_bytes, program.sha256, check)

    def _keep(self, name: str, write: Callable[[Path], None], size: int, sha256: str,
              check: dict[str, Any]) -> dict[str, Any]:
        meta = {"name": name, "size_bytes": size, "sha256": sha256, "added_at": now_iso(), "check": check}
        with self._lock:
            try:
                self.folder.mkdir(parents=True, exist_ok=True)
                write(self.folder / name)
                meta["stamp"] = file_stamp(self.folder / name)
                write_atomically(self._meta_path(name), json.dumps(meta, indent=1).encode())
            except OSError as err:
                raise InputError("data_dir", f"cannot write {name} into {self.folder}: {err.strerror or err}") from None
        return meta

    def program_file(self, name: str, data_dir: str | Path) -> ProgramFile:
        """The program ``name`` as a file of the spool in ``data_dir`` (module docstring);
        InputError when the library has no such program."""
        meta = self._meta(check_library_name(name))
        try:
            if meta is None:
                raise FileNotFoundError(name)
            return snapshot(self.folder / name, data_dir, meta.get("stamp"), str(meta.get("sha256", "")))
        except OSError:
            raise InputError(f"program {name!r}", "not in the library (nurbsmotion programs list)") from None

    def listing(self) -> list[dict[str, Any]]:
        """Every program's record (no text), by name."""
        found = []
        for path in sorted(self.folder.glob(f"*{META_SUFFIX}")) if self.folder.is_dir() else []:
            name = path.name[:-len(META_SUFFIX)]
            if NAME_RE.match(name) and (self.folder / name).is_file():
                meta = self._meta(name)
                if meta is not None:
                    found.append(meta)
        return found

    def get(self, name: str) -> dict[str, Any]:
        """The program's record and ``text``; InputError when the library has no such program."""
        meta = self._meta(check_library_name(name))
        try:
            text = (self.folder / name).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            meta = None
        if meta is None:
            raise InputError(f"program {name!r}", "not in the library (nurbsmotion programs list)")
        return {**meta, "text": text}

    def remove(self, name: str) -> None:
        check_library_name(name)
        with self._lock:
            if not (self.folder / name).is_file():
                raise InputError(f"program {name!r}", "not in the library (nurbsmotion programs list)")
            (self.folder / name).unlink()
            self._meta_path(name).unlink(missing_ok=True)

    def _meta_path(self, name: str) -> Path:
        return self.folder / f"{name}{META_SUFFIX}"

    def _meta(self, name: str) -> dict[str, Any] | None:
        try:
            meta = json.loads(self._meta_path(name).read_text())
        except (OSError, ValueError):
            return None
        return meta if isinstance(meta, dict) else None
