"""Checked programs kept in DATA_DIR/checked/: a program read and checked once is not read
again while nothing its check depends on has changed (issue 25 item 1).

The key (:func:`check_key`) is a SHA-256 over everything the reader and the checks before
motion (service.streamed_job.check_before_motion) depend on: the program's name (its errors
and sources name it) and text, the machine configuration (:func:`config_fingerprint`), where
the axes start (the first move starts there) and the reader's options (offsets, tool,
switches, start line), with the entry format and the package version. A changed file or
configuration is a new key: rechecked, never trusted.

An entry is one file ``KEY.checked``, laid out so that a process maps it instead of loading
it (issue 25 item 4: the checked program reaches the planner worker and the daemon without
copies): a header line (:data:`MAGIC`, format, package version, key), the length of the
layout (8 bytes, little-endian), the :class:`EntryLayout` (a small pickle: the Program without
its blocks, the records' NURBS curves, source overrides, and where each array lies), then,
each at a multiple of :data:`ALIGN` bytes, the raw bytes of the block records' arrays
(program.records.BlockRecords.columns) and of the program's text (its SourceText).
:func:`load_checked` maps the file once (mmap, read-only) and gives arrays that are views of
it: loading a 10^6-block entry costs the same as a 10-block one, and only the pages a process
reads are ever in its memory (file-backed, shared by every process mapping the entry).

:func:`save_checked` and :func:`load_checked` are the only functions that know how a Program
is stored. An entry that is unreadable, of another format or version, of another key, or
shorter or longer than its layout says (a truncated write) loads as None (one log line): the
program is read and checked again. Writes are atomic (a temporary file renamed over the
entry); a hit touches the entry (pruning removes the least recently used).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import mmap
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
from nurbsmotion.program.records import BlockRecords, SourceText
from nurbsmotion.service.record_config import config_dict

log = logging.getLogger(__name__)

MAGIC = b"nurbsmotion-checked-program"
FORMAT_VERSION = 2  # 1: a pickle of the whole Program
ALIGN = 64  # every array starts at a multiple of this many bytes from the data's start
SUFFIX = ".checked"
MAX_ENTRIES = 32  # the newest kept; older ones are removed when a new one is written
IRRELEVANT_CONFIG = ("monitoring", "web", "notify", "control", "data_dir", "source", "bus", "simulate")  # no check reads them


def config_fingerprint(config: MachineConfig) -> str:
    """SHA-256 of the configuration as a job records it (config.json), without the sections
    no check reads (IRRELEVANT_CONFIG): axes, limits, interpolation, spindle, io, tools..."""
    relevant = {k: v for k, v in config_dict(config).items() if k not in IRRELEVANT_CONFIG}
    return hashlib.sha256(json.dumps(relevant, sort_keys=True, default=repr).encode()).hexdigest()


DIGEST_CHUNK = 1 << 20  # characters encoded at a time: a 30 MB program is never held twice for its hash


def text_digest(text: str) -> str:
    """SHA-256 of ``text`` in UTF-8, encoded a chunk at a time."""
    h = hashlib.sha256()
    for first in range(0, len(text), DIGEST_CHUNK):
        h.update(text[first:first + DIGEST_CHUNK].encode("utf-8"))
    return h.hexdigest()


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


@dataclass(frozen=True)
class ArraySpan:
    """Where one array's bytes lie, from the data's start."""

    name: str
    dtype: str  # numpy's dtype.str, e.g. '<f8'
    shape: tuple[int, ...]
    offset: int


@dataclass(frozen=True, eq=False)
class EntryLayout:
    """Everything of an entry but its arrays' bytes (module docstring)."""

    outline: Program  # blocks=()
    file: str
    curves: tuple[Any, ...]  # the records' NurbsCurves (NURBS blocks only)
    source_overrides: dict[int, Any]
    arrays: tuple[ArraySpan, ...]
    text_first_line: int | None  # None: the records have no SourceText
    data_bytes: int  # the data's length: the file ends there


class EntryError(ValueError):
    """An entry's bytes do not match its layout (cut short, or grown)."""


def aligned(offset: int) -> int:
    return -(-offset // ALIGN) * ALIGN


def entry_arrays(records: BlockRecords) -> dict[str, np.ndarray]:
    """The arrays an entry keeps: the records' columns and, if any, the text and its line starts."""
    arrays = {name: np.ascontiguousarray(values) for name, values in records.columns().items()}
    if records.text is not None:
        arrays["text_data"] = np.frombuffer(records.text.data, dtype=np.uint8)
        arrays["text_starts"] = np.ascontiguousarray(records.text.starts)
    return arrays


def save_checked(path: Path, key: str, program: Program) -> None:
    """Write ``program`` as the entry ``key`` at ``path`` (atomically; OSError if it cannot)."""
    records = BlockRecords.of_blocks(program.blocks)
    arrays = entry_arrays(records)
    spans, offset = [], 0
    for name, values in arrays.items():
        spans.append(ArraySpan(name, values.dtype.str, tuple(values.shape), offset))
        offset = aligned(offset + values.nbytes)
    layout = EntryLayout(dataclasses.replace(program, blocks=()), records.file, records.curves,
                         records.source_overrides, tuple(spans),
                         None if records.text is None else records.text.first_line, offset)
    layout_bytes = pickle.dumps(layout, protocol=pickle.HIGHEST_PROTOCOL)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=SUFFIX)
    try:
        with os.fdopen(fd, "wb") as out:
            head = header(key) + len(layout_bytes).to_bytes(8, "little") + layout_bytes
            out.write(head + bytes(aligned(len(head)) - len(head)))
            written = 0
            for span in spans:
                out.write(bytes(span.offset - written))
                out.write(arrays[span.name].reshape(-1).view(np.uint8).data)
                written = span.offset + arrays[span.name].nbytes
            out.write(bytes(layout.data_bytes - written))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def mapped_program(src: Any, layout: EntryLayout) -> Program:
    """The Program of an open entry whose layout was just read: arrays are views of the file."""
    data_start = aligned(src.tell())
    size = os.fstat(src.fileno()).st_size
    if size != data_start + layout.data_bytes:
        raise EntryError(f"{size} bytes, its layout says {data_start + layout.data_bytes}")
    view = mmap.mmap(src.fileno(), 0, access=mmap.ACCESS_READ)
    arrays = {}
    for span in layout.arrays:
        dtype = np.dtype(span.dtype)
        count = int(np.prod(span.shape, dtype=np.int64))
        arrays[span.name] = np.frombuffer(view, dtype, count, data_start + span.offset).reshape(span.shape)
    text = None
    if layout.text_first_line is not None:
        text = SourceText(arrays.pop("text_data"), arrays.pop("text_starts"), layout.text_first_line)
    records = BlockRecords.from_columns(arrays, layout.curves, layout.file, text, layout.source_overrides)
    return dataclasses.replace(layout.outline, blocks=records)


def load_checked(path: Path, key: str) -> Program | None:
    """The Program of entry ``key`` at ``path``, mapped (module docstring); None when there is
    none, or it is of another format, version or key, or unreadable: rechecked, not trusted."""
    try:
        with open(path, "rb") as src:
            if src.readline() != header(key):
                log.info(kv("checked_entry_stale", file=path.name))
                return None
            layout = pickle.loads(src.read(int.from_bytes(src.read(8), "little")))
            if not isinstance(layout, EntryLayout) or not isinstance(layout.outline, Program):
                raise EntryError(f"no layout but {type(layout).__name__}")
            return mapped_program(src, layout)
    except FileNotFoundError:
        return None
    except Exception as err:  # noqa: BLE001 - a corrupt entry (any unpickling or layout error) is rechecked
        log.warning(kv("checked_entry_unreadable", file=path.name, error=repr(err)[:200]))
        return None


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

    def key(self, name: str, text_sha256: str, start_xyz: np.ndarray, options: ReadOptions) -> str:
        """The key of a program whose text's SHA-256 (text_digest, or its file's:
        service.program_file) is ``text_sha256``."""
        return check_key(name, text_sha256, self.config_sha256, start_xyz, options)

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
