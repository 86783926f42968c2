"""Checked programs kept in DATA_DIR/checked/: a program read and checked once is not read
again while nothing its check depends on has changed (issue 25 item 1).

The key (:func:`check_key`) is a SHA-256 over everything the reader and the checks before
motion (service.streamed_job.check_before_motion) depend on: the program's name (its errors
and sources name it) and text, the machine configuration (:func:`config_fingerprint`), where
the axes start (the first move starts there) and the reader's options (offsets, tool,
switches, start line), with the entry format and the package version. A changed file or
configuration is a new key: rechecked, never trusted.

An entry is one file ``KEY.checked``: a header line (:data:`MAGIC`, format, package version,
key), then a pickle of the checked :class:`Program`. :func:`save_checked` and
:func:`load_checked` are the only functions that know how a Program is stored (the
``records`` work changes Program's insides: only these two follow). An entry that is
unreadable, of another format or version, or of another key loads as None: the program is
read and checked again. Writes are atomic (a temporary file renamed over the entry).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import pickle
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nurbsmotion import __version__
from nurbsmotion.config import MachineConfig
from nurbsmotion.log import kv
from nurbsmotion.program import Program, ReadOptions
from nurbsmotion.service.record_config import config_dict

log = logging.getLogger(__name__)

MAGIC = b"nurbsmotion-checked-program"
FORMAT_VERSION = 1
SUFFIX = ".checked"
MAX_ENTRIES = 32  # the newest kept; older ones are removed when a new one is written
IRRELEVANT_CONFIG = ("monitoring", "web", "notify", "control", "data_dir", "source", "bus", "simulate")  # no check reads them


def config_fingerprint(config: MachineConfig) -> str:
    """SHA-256 of the configuration as a job records it (config.json), without the sections
    no check reads (IRRELEVANT_CONFIG): axes, limits, interpolation, spindle, io, tools..."""
    relevant = {k: v for k, v in config_dict(config).items() if k not in IRRELEVANT_CONFIG}
    return hashlib.sha256(json.dumps(relevant, sort_keys=True, default=repr).encode()).hexdigest()


def text_digest(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def check_key(name: str, text_sha256: str, config_sha256: str, start_xyz: np.ndarray, options: ReadOptions) -> str:
    """The entry's key (module docstring)."""
    h = hashlib.sha256()
    for part in (MAGIC, str(FORMAT_VERSION).encode(), __version__.encode(), name.encode(), text_sha256.encode(),
                 config_sha256.encode(), np.asarray(start_xyz, dtype=np.float64).tobytes(),
                 pickle.dumps(options, protocol=pickle.HIGHEST_PROTOCOL)):
        h.update(len(part).to_bytes(8, "little"))
        h.update(part)
    return h.hexdigest()


def header(key: str) -> bytes:
    return b"%s %d %s %s\n" % (MAGIC, FORMAT_VERSION, __version__.encode(), key.encode())


def save_checked(path: Path, key: str, program: Program) -> None:
    """Write ``program`` as the entry ``key`` at ``path`` (atomically; OSError if it cannot)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=SUFFIX)
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(header(key))
            pickle.dump(program, out, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_checked(path: Path, key: str) -> Program | None:
    """The Program of entry ``key`` at ``path``; None when there is none, or it is of another
    format, version or key, or unreadable (module docstring: rechecked, not trusted)."""
    try:
        with open(path, "rb") as src:
            if src.readline() != header(key):
                log.info(kv("checked_entry_stale", file=path.name))
                return None
            program = pickle.load(src)
    except FileNotFoundError:
        return None
    except Exception as err:  # noqa: BLE001 - a corrupt entry (any unpickling error) is rechecked
        log.warning(kv("checked_entry_unreadable", file=path.name, error=repr(err)[:200]))
        return None
    return program if isinstance(program, Program) else None


@dataclass
class CheckedStore:
    """DATA_DIR/checked/: where entries are, and how often they served (hits) or not (misses)."""

    folder: Path
    config_sha256: str
    hits: int = 0
    misses: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @classmethod
    def for_config(cls, config: MachineConfig) -> "CheckedStore":
        return cls(Path(config.data_dir) / "checked", config_fingerprint(config))

    def key(self, name: str, text: str, start_xyz: np.ndarray, options: ReadOptions) -> str:
        return check_key(name, text_digest(text), self.config_sha256, start_xyz, options)

    def path(self, key: str) -> Path:
        return self.folder / f"{key}{SUFFIX}"

    def note(self, hit: bool, name: str) -> None:
        """Count a use of the store; one log line (checked_program source=store|read); a miss
        prunes the folder (a new entry will be written)."""
        with self._lock:
            if hit:
                self.hits += 1
            else:
                self.misses += 1
        log.info(kv("checked_program", name=name, source="store" if hit else "read", hits=self.hits,
                    misses=self.misses))
        if not hit:
            self.prune()  # a new entry is on its way: the folder never holds more than MAX_ENTRIES + 1

    def prune(self, keep: int = MAX_ENTRIES) -> None:
        """Remove all but the ``keep`` newest entries."""
        try:
            entries = sorted((p for p in self.folder.glob(f"*{SUFFIX}") if not p.name.startswith(".tmp-")),
                             key=lambda p: p.stat().st_mtime, reverse=True)
        except OSError:
            return
        for old in entries[keep:]:
            old.unlink(missing_ok=True)

    def counters(self) -> dict[str, Any]:
        return {"hits": self.hits, "misses": self.misses, "folder": str(self.folder)}
